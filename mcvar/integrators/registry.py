"""The registry of rendering methods: one :class:`Method` per name.

A method is one module that builds a :class:`Method` and calls
:func:`register` once at import; :func:`mcvar.integrators.render`, the CLI
and the contract suite (``tests/test_integrator_contract.py``) find it in
:data:`METHODS`. See docs/integrators.md, 'Adding a method'.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable, Mapping

__all__ = ["KINDS", "METHODS", "Method", "register", "get_method", "pop_method_name"]

#: The kinds of work a method does (how its batches reach the film).
KINDS = ("camera", "splat", "chain", "first_hit")


@dataclass(frozen=True)
class Method:
    """A rendering method: what :func:`~mcvar.integrators.render` needs to run it.

    Attributes
    ----------
    name : str
        What ``render(..., method=name)`` and ``mcvar render --method`` take.
    kind : {'camera', 'splat', 'chain', 'first_hit'}
        ``camera``: samples per pixel through the camera (per-sample variance
        per pixel); ``splat``: contributions land at arbitrary pixels (light
        tracing, BDPT's t = 1), variance from independent batches; ``chain``:
        Markov chains (PSSMLT), variance from independent batches;
        ``first_hit``: one ray per sample, no transport (AOVs, raster).
    run_batch : callable
        ``run_batch(job: BatchJob) -> BatchResult``; a module-level function
        (picklable, so that process pools and Dask can run it).
    summary : str
        One line for the docs and the CLI help.
    options : mapping
        Extra keyword options the method takes, with their defaults:
        ``render(scene, method=name, **options)``. Any other option is a
        ``ValueError`` naming it and the accepted ones.
    prepare : callable or None
        ``prepare(scene, options, rng) -> object`` run once per render in the
        parent (a photon map, a radiosity solve); the result (picklable) is
        handed to every batch as ``job.prepared``.
    warm : callable or None
        ``warm(scene, tracer, settings)`` run once per render in the parent,
        once the tracer is built and before any batch or worker process: it
        fills the tracer's caches that every batch reads (the shading tables
        of :meth:`mcvar.integrators.state.SceneTables.of`), so that the
        render's forked workers inherit them instead of each building its own
        in its first batch (scene set-up, like the tracer's build: 35 ms a
        process at 100,922 triangles).
    check_scene : callable or None
        ``check_scene(scene, options)`` raises ``ValueError`` naming what the
        method cannot handle in ``scene`` (the contract suite accepts exactly
        that as a documented skip).
    uses_max_depth : bool
        False: ``max_depth`` does not apply (a ``ValueError`` if given).
    lecture : tuple or None
        The lecture's 'Rendering Algorithm Chart' claim ``(consistent, unbiased)``,
        e.g. ``("yes", "yes")``.
    fixed_depth : int or None
        The method's own depth (the ``direct*`` methods: 2); ``max_depth``
        must then be None or equal to it. (An addition to the API of
        /work/status/API.md, default None.)
    chart_row : str or None
        The row of the lecture's 'Rendering Algorithm Chart' the method
        answers (``'Path Tracing'``, ``'Photon Mapping'`` ...): ``mcvar chart``
        measures it. None: not in the chart, unless it has a ``knob`` and a
        ``lecture`` claim (then it is a row of its own).
    knob : Knob or None
        Its accuracy knob for the chart (:class:`mcvar.integrators.knobs.Knob`);
        None: samples per pixel.
    theory : tuple or None
        ``(consistent, unbiased, why)`` theory says, measured with its knob;
        ``why`` is the chart's note where the measurement differs from the lecture.
    chart_depths : mapping
        Fixed depths also measured as chart rows ``'name:depth'``, each with
        its theory tuple (``path``: ``{3: ('no', 'no', ...)}``).
    stream_dims : int, callable or None
        Columns of the per-path sample stream the render's ``sampler`` feeds
        (:mod:`mcvar.integrators.stream`; the rest a method draws from
        ``job.rng``): an int (0: the method reads no sampler column and
        ``job.u`` is None, as for ``light`` and ``pssmlt``; 2: the pixel
        position only, as for ``photon``), ``stream_dims(options) -> int``, or
        None: camera-kind methods read the camera columns and six per path
        vertex up to their depth (:func:`~mcvar.integrators.stream.stream_dim`,
        at most ``render(sampler_dim=...)``), every other kind the camera
        columns only.
    """

    name: str
    kind: str
    run_batch: Callable
    summary: str
    options: Mapping = field(default_factory=dict)
    prepare: Callable | None = None
    check_scene: Callable | None = None
    warm: Callable | None = None
    uses_max_depth: bool = True
    lecture: tuple | None = None
    fixed_depth: int | None = None
    chart_row: str | None = None
    knob: object | None = None
    theory: tuple | None = None
    chart_depths: Mapping = field(default_factory=dict)
    stream_dims: Callable | int | None = None

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name.isidentifier():
            raise ValueError(f"Method.name must be an identifier-like string; got {self.name!r}")
        if self.kind not in KINDS:
            raise ValueError(f"Method.kind must be one of {KINDS}; got {self.kind!r}")
        if not callable(self.run_batch):
            raise TypeError(f"Method.run_batch must be callable; got {type(self.run_batch).__name__}")
        for key in ("prepare", "check_scene", "warm"):
            value = getattr(self, key)
            if value is not None and not callable(value):
                raise TypeError(f"Method.{key} must be callable or None; got {type(value).__name__}")
        dims = self.stream_dims
        if not (dims is None or callable(dims)):
            if isinstance(dims, bool) or not isinstance(dims, int) or dims < 0:
                raise TypeError(f"Method.stream_dims must be None, an int >= 0 or a callable; got {dims!r}")
        object.__setattr__(self, "options", dict(self.options))
        object.__setattr__(self, "chart_depths", dict(self.chart_depths))
        if self.theory is not None and len(self.theory) != 3:
            raise ValueError(f"Method.theory must be (consistent, unbiased, why); got {self.theory!r}")

    def replace(self, **changes) -> "Method":
        """A copy with ``changes`` (:func:`dataclasses.replace`), e.g. chart fields added."""
        return replace(self, **changes)

    def sampler_columns(self, options: Mapping) -> int | None:
        """:attr:`stream_dims` for ``options`` (None: the kind's default)."""
        dims = self.stream_dims(options) if callable(self.stream_dims) else self.stream_dims
        if dims is not None and (isinstance(dims, bool) or not isinstance(dims, int) or dims < 0):
            raise TypeError(f"{self.name}: stream_dims(options) must return an int >= 0; got {dims!r}")
        return dims

    def resolve_options(self, given: Mapping) -> dict:
        """The method's options: defaults updated with ``given``; an unknown key is a ValueError."""
        unknown = [k for k in given if k not in self.options]
        if unknown:
            accepted = ", ".join(self.options) if self.options else "none"
            raise ValueError(f"method {self.name!r} does not take the option(s) "
                             f"{', '.join(map(repr, unknown))}; it accepts: {accepted}")
        return {**self.options, **given}


#: Registered methods by name, in registration order.
METHODS: dict[str, Method] = {}


def register(method: Method) -> Method:
    """Add ``method`` to :data:`METHODS` (a duplicate name is a ``ValueError``); return it."""
    if not isinstance(method, Method):
        raise TypeError(f"register takes a Method; got {type(method).__name__}")
    if method.name in METHODS:
        raise ValueError(f"a method named {method.name!r} is already registered")
    METHODS[method.name] = method
    return method


def get_method(name) -> Method:
    """The registered method called ``name`` (ValueError listing the known ones otherwise)."""
    if isinstance(name, Method):
        return name
    if not isinstance(name, str) or name not in METHODS:
        raise ValueError(f"method must be one of {tuple(METHODS)}; got {name!r}")
    return METHODS[name]


def pop_method_name(keywords: dict, method=None, where: str = "render", default: str = "path"):
    """The method a call names: ``method``, or the alias ``integrator`` popped from
    ``keywords`` (the name before issue 20); both given is a ``ValueError``."""
    alias = keywords.pop("integrator", None)
    if method is not None and alias is not None:
        raise ValueError(f"{where}: give method= or its alias integrator=, not both "
                         f"(got method={method!r}, integrator={alias!r})")
    if method is not None:
        return method
    return default if alias is None else alias
