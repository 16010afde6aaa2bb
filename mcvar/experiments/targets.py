"""What a sweep estimates: ``Target`` and its makers for integrands, the
lecture's estimators and scenes (layer 6, module 1 of :mod:`mcvar.experiments`)."""
from __future__ import annotations

import re
from dataclasses import dataclass
from functools import partial
from typing import Callable

import numpy as np

from .._validation import check_count


# --------------------------------------------------------------------------
# Targets
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class Target:
    """Something to estimate, with the methods and samplers that estimate it.

    Parameters
    ----------
    name : str
        Shown in reports.
    evaluate : callable
        ``evaluate(method, sampler, spp, rng) -> ndarray``: one independent
        estimate (a scalar integral as shape ``(1,)``, or an image
        ``(H, W, 3)``) from ``spp`` samples (per pixel) drawn with the named
        sampler from the Generator ``rng``. Must be picklable (a module-level
        function or a :func:`functools.partial` of one) to run in other
        processes.
    key : str
        A stable description of everything ``evaluate`` depends on besides its
        arguments (scene, resolution, ...); hashed into cache file names.
    methods, samplers, spp : tuple
        Defaults of a sweep when the caller gives none.
    exact : ndarray, optional
        The known exact value (for integrands); then no reference is rendered.
    reference_task : callable, optional
        ``reference_task(rng) -> ndarray``: one chunk of a high-sample
        reference; :func:`compute_reference` averages ``reference_chunks`` of
        them from independent streams.
    reference_chunks : int
        Number of independent reference chunks (their spread gives the
        reference's own variance).
    reference_settings : str
        Description of ``reference_task`` (integrator, spp ...), part of the
        reference's cache key.
    """

    name: str
    evaluate: Callable
    key: str
    methods: tuple = ()
    samplers: tuple = ("random",)
    spp: tuple = (1, 4, 16, 64, 256)
    exact: np.ndarray | None = None
    reference_task: Callable | None = None
    reference_chunks: int = 8
    reference_settings: str = ""


def _integrand_evaluate(problem: str, method: str, sampler: str, spp: int, rng) -> np.ndarray:
    from ..examples import PROBLEMS
    from ..samplers import DETERMINISTIC, digital_shift, get_sampler

    points = get_sampler(sampler)(spp, rng=rng)
    if sampler in DETERMINISTIC:
        # the same points for every replicate would make the replicate spread
        # zero and the error bars meaningless: shift each replicate randomly
        points = np.minimum(digital_shift(points, rng=rng), np.nextafter(1.0, 0.0))
    contributions = np.asarray(PROBLEMS[problem].methods[method](points), dtype=np.float64)
    return np.array([contributions.mean()])


def integrand_target(name: str) -> Target:
    """A :class:`Target` for the integrand ``mcvar.examples.PROBLEMS[name]``.

    Its methods are the problem's estimators (the contribution functions
    ``f(X) / p(X)``); one estimate is their mean over ``spp`` points of the
    sampler. The reference is the problem's exact value (variance 0).
    Default samplers: random, jittered, sobol; default N: 4^0 ... 4^6 (powers
    of 4 are perfect squares, as jittered needs, and powers of 2, as Sobol
    needs for its balance properties).
    """
    from ..examples import PROBLEMS

    if not isinstance(name, str):
        raise TypeError(f"name must be a string naming a problem; got {type(name).__name__}")
    if name not in PROBLEMS:
        raise ValueError(f"name must be one of {tuple(PROBLEMS)}; got {name!r}")
    problem = PROBLEMS[name]
    return Target(name=name, evaluate=partial(_integrand_evaluate, name),
                  key=f"integrand={name};exact={float(problem.exact)!r}",
                  methods=tuple(problem.methods), samplers=("random", "jittered", "sobol"),
                  spp=tuple(4 ** k for k in range(7)), exact=np.array([float(problem.exact)]))


def _to_board(u):
    """[0, 1)^2 -> the lecture's [0, 2)^2 board (uniform, pdf 1/4)."""
    return 2.0 * u


_BOARD = dict(lower=(0.0, 0.0), upper=(2.0, 2.0))


def _lecture_evaluate(method: str, sampler: str, spp: int, rng) -> np.ndarray:
    from ..examples import PROBLEMS, checkerboard, fixed_grid_estimate, single_sample_estimate, \
        undivided_estimate
    from ..samplers import get_sampler

    if method == "uniform":
        points = get_sampler(sampler)(spp, rng=rng)
        return np.array([PROBLEMS["checkerboard"].methods["uniform"](points).mean()])
    if method == "grid":
        m = int(np.sqrt(spp))
        if m * m != spp:
            raise ValueError(f"spp must be a perfect square for the 'grid' estimator; got {spp}")
        return np.array([fixed_grid_estimate(checkerboard, m, **_BOARD)])
    if method == "single":
        return np.array([single_sample_estimate(checkerboard, rng=rng, **_BOARD)])
    if method == "undivided":
        return np.array([undivided_estimate(checkerboard, sample=_to_board, n=spp, sampler=sampler,
                                            rng=rng).mean])
    raise ValueError(f"method must be one of ('uniform', 'grid', 'single', 'undivided'); got {method!r}")


def lecture_target() -> Target:
    """The lecture's estimators of the checkerboard integral (exact value 2).

    Methods, one per cell of the 'Bias & Consistency' / 'Consistent Or
    Unbiased?' / 'Biased vs. Unbiased Example' slides:

    * ``'uniform'``: plain Monte Carlo, ``4 f(2u)`` averaged over N points of
      the sampler: unbiased and consistent;
    * ``'grid'``: the fixed ``m x m`` grid, ``m = sqrt(N)``
      (:func:`mcvar.examples.fixed_grid_estimate`): consistent but biased
      (by ``2 / m^2`` for odd ``m``), deterministic;
    * ``'single'``: one random sample times the area, whatever N
      (:func:`mcvar.examples.single_sample_estimate`): unbiased, not
      consistent;
    * ``'undivided'``: the mean of ``f(X)`` without dividing by the pdf
      (:func:`mcvar.examples.undivided_estimate`): converges to 1/2, not 2,
      neither unbiased nor consistent.

    Default N: odd squares 1, 9, 49, 225, 961 (so the grid's bias is not 0).
    The name for :func:`make_target` is ``'lecture'``.
    """
    from ..examples import CHECKERBOARD_INTEGRAL

    return Target(name="lecture", evaluate=_lecture_evaluate, key="lecture-checkerboard-v1",
                  methods=("uniform", "grid", "single", "undivided"), samplers=("random",),
                  spp=(1, 9, 49, 225, 961), exact=np.array([float(CHECKERBOARD_INTEGRAL)]))


_METHOD = re.compile(r"^([a-z_]+)(?::(\d+))?$")
_DEPTH_ALIAS = re.compile(r"^([a-z_]+?)_depth(\d+)$")   # 'path_depth3' -> 'path:3'



def parse_method(method: str) -> tuple[str, int | None]:
    """Split a scene method ``'integrator[:max_depth]'``.

    ``'path'`` is path tracing with Russian roulette (unbiased), ``'path:3'``
    the same integrator stopped after 3 bounces (``max_depth=3``: biased,
    light carried by longer paths is missing). ``'path:3'`` is the one
    spelling of a fixed depth; ``'path_depth3'`` (the chart's former
    spelling) is accepted as an alias of it.

    Examples
    --------
    >>> parse_method("path:3")
    ('path', 3)
    >>> parse_method("direct")
    ('direct', None)
    >>> parse_method("path_depth3")
    ('path', 3)
    """
    if not isinstance(method, str):
        raise TypeError(f"method must be a string 'integrator[:max_depth]'; got {type(method).__name__}")
    m = _METHOD.match(_DEPTH_ALIAS.sub(r"\1:\2", method))
    if m is None or (m.group(2) is not None and int(m.group(2)) < 1):
        raise ValueError(f"method must look like 'path' or 'path:3' (integrator[:max_depth >= 1]); "
                         f"got {method!r}")
    return m.group(1), (int(m.group(2)) if m.group(2) is not None else None)


def _scene(scene):
    """The :class:`~mcvar.scene.Scene` called ``scene`` (a Scene is returned as is). Loading
    takes well under a millisecond: a target loads its scene once and keeps it (no cache)."""
    from ..scene import Scene, load_scene

    return scene if isinstance(scene, Scene) else load_scene(scene)


def _scene_evaluate(scene, res: int, method: str, sampler: str, spp: int, rng) -> np.ndarray:
    from ..integrators import render

    integrator, max_depth = parse_method(method)
    result = render(_scene(scene), integrator=integrator, spp=spp, res=res, sampler=sampler,
                    rng=rng, max_depth=max_depth, progress=False, workers=1)
    return np.asarray(result.image, dtype=np.float64)


def _scene_reference(scene, res: int, integrator: str, spp: int, sampler: str, rng) -> np.ndarray:
    return _scene_evaluate(scene, res, integrator, sampler, spp, rng)


def _check_reference_settings(reference_spp, reference_chunks) -> tuple[int, int]:
    """``reference_spp`` and ``reference_chunks`` checked: counts, and at least two chunks
    (their spread is the reference's variance)."""
    reference_spp = check_count(reference_spp, "reference_spp")
    reference_chunks = check_count(reference_chunks, "reference_chunks")
    if reference_chunks < 2:
        raise ValueError(f"reference_chunks must be >= 2 (their spread is the reference's "
                         f"variance); got {reference_chunks}")
    return reference_spp, reference_chunks


def scene_target(name: str, *, res: int = 32, reference_spp: int = 1024, reference_chunks: int = 8,
                 reference_integrator: str = "path") -> Target:
    """A :class:`Target` rendering the scene ``name`` at ``res x res`` pixels.

    Methods are integrator names of :func:`mcvar.integrators.render`, with an
    optional fixed depth (:func:`parse_method`). The reference is rendered by
    the unbiased ``reference_integrator`` (path tracing with Russian roulette)
    with ``reference_spp`` spp per chunk, ``reference_chunks`` chunks from
    independent streams, sampler ``random``.
    """
    if not isinstance(name, str):
        raise TypeError(f"name must be a scene name string; got {type(name).__name__}")
    res = check_count(res, "res")
    reference_spp, reference_chunks = _check_reference_settings(reference_spp, reference_chunks)
    parse_method(reference_integrator)
    scene = _scene(name)  # fails early on an unknown scene; the target owns the loaded scene
    return Target(name=name, evaluate=partial(_scene_evaluate, scene, res),
                  key=f"scene={name};res={res}",
                  methods=("path", "path:2", "direct"), samplers=("random", "jittered", "sobol"),
                  spp=(1, 4, 16, 64),
                  reference_task=partial(_scene_reference, scene, res, reference_integrator,
                                         reference_spp, "random"),
                  reference_chunks=reference_chunks,
                  reference_settings=f"integrator={reference_integrator};spp={reference_spp};"
                                     f"sampler=random")


_SPEC = re.compile(r"^([A-Za-z_][\w]*(?:\.[A-Za-z_][\w]*)*):([A-Za-z_]\w*)$")


def load_target(spec: str) -> Target:
    """A :class:`Target` from ``'module:name'``: your own renderer, measured.

    ``module`` is imported (the current folder first on ``sys.path``, as
    ``python -m`` does) and ``name`` looked up in it:

    * a :class:`Target`: used as is;
    * a function ``evaluate(method, sampler, spp, rng) -> ndarray`` (an image
      ``(H, W, 3)`` or an estimate ``(1,)``, from the numpy Generator
      ``rng``): wrapped in a Target whose defaults come from the module's
      optional constants ``METHODS``, ``SAMPLERS`` (default ``('random',)``),
      ``SPP`` (default ``(1, 4, 16, 64)``) and ``EXACT`` (the exact value),
      or its function ``reference(rng) -> ndarray`` (one chunk of a
      high-sample reference; 8 chunks are averaged). Without ``EXACT`` or
      ``reference``, pass a reference file (``--reference ref.npy``).

    The cache key holds a hash of the module's source file, so editing the
    renderer invalidates cached runs.

    Examples
    --------
    ``mcvar converge --target myrenderer:evaluate --methods path,path_fixed
    --reference ref.npy`` (see docs/guide-any-renderer.md).
    """
    import hashlib
    import importlib
    import os
    import sys

    if not isinstance(spec, str) or _SPEC.match(spec) is None:
        raise ValueError(f"target must look like 'module:function' (e.g. 'myrenderer:evaluate'); got {spec!r}")
    module_name, attr = spec.split(":")
    if os.getcwd() not in sys.path:
        sys.path.insert(0, os.getcwd())
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        raise ValueError(f"target {spec!r}: cannot import module {module_name!r} ({exc}); run from its "
                         "folder or put it on PYTHONPATH") from exc
    obj = getattr(module, attr, None)
    if isinstance(obj, Target):
        return obj
    if not callable(obj):
        raise ValueError(f"target {spec!r}: {module_name} has no function or Target named {attr!r}")
    source = getattr(module, "__file__", None)
    digest = hashlib.sha256(open(source, "rb").read()).hexdigest()[:16] if source else "nofile"
    exact = getattr(module, "EXACT", None)
    reference = getattr(module, "reference", None)
    return Target(name=spec, evaluate=obj, key=f"user={spec};source={digest}",
                  methods=tuple(getattr(module, "METHODS", ())),
                  samplers=tuple(getattr(module, "SAMPLERS", ("random",))),
                  spp=tuple(getattr(module, "SPP", (1, 4, 16, 64))),
                  exact=None if exact is None else np.asarray(exact, dtype=np.float64),
                  reference_task=reference if callable(reference) else None,
                  reference_settings=f"{module_name}.reference" if callable(reference) else "")


def make_target(name, *, res: int = 32) -> Target:
    """A :class:`Target` from a name: ``'lecture'`` (:func:`lecture_target`), an
    integrand of ``mcvar.examples.PROBLEMS``, ``'module:function'``
    (:func:`load_target`: your own renderer), otherwise a scene of
    ``mcvar.scene.load_scene``; a :class:`Target` is returned as is."""
    if isinstance(name, Target):
        return name
    if not isinstance(name, str):
        raise TypeError(f"target must be a Target or a name string; got {type(name).__name__}")
    if ":" in name:
        return load_target(name)
    from ..examples import PROBLEMS

    if name == "lecture":
        return lecture_target()
    if name in PROBLEMS:
        return integrand_target(name)
    try:
        return scene_target(name, res=res)
    except (KeyError, ValueError) as exc:
        raise ValueError(f"target must be an integrand {tuple(PROBLEMS)} or a scene name; "
                         f"got {name!r} ({exc})") from exc
