"""Unbiased adaptive sampling with the most efficient configuration found (layer 6).

On the Cornell box at 64 x 64 most of a uniform render's error sits in a few
dozen pixels: those that see the light's edge and the bright ceiling next to
it. :func:`render_adaptive` is :func:`mcvar.integrators.render` with
``allocation=Adaptive(...)`` (the two-stage allocation of
:mod:`mcvar.integrators.allocation`: a pilot ranks the pixels by their
standard deviation, Neyman's allocation in powers of two spends the rest, the
second stage's samples alone make the image, so it is unbiased) and the
defaults ``mcvar render`` uses (docs/performance.md): the Sobol' sampler, the
lights seen directly integrated exactly (``visible_lights='exact'``),
Russian roulette as a weight window (``rr_threshold=0.2`` from 3 segments)
and caustic paths by light tracing (``caustics='light'``, where the scene allows it).
The same driver runs it: workers, executors, progress, Ctrl-C and the memory
guard are those of :func:`~mcvar.integrators.render`.
"""
from __future__ import annotations

from .integrators import Render, render
from .integrators.allocation import (ADAPTIVE_DIM, PILOT_MAX_DEPTH, PILOT_PATHS_PER_BATCH, Adaptive,
                                     AdaptiveRender, allocate)
from .integrators.registry import get_method, pop_method_name
from .integrators.reuse import REUSE_SIZE
from .scene import Scene

__all__ = ["render_adaptive", "allocate", "AdaptiveRender", "ADAPTIVE_SETTINGS", "adaptive_settings"]

#: Russian roulette start of adaptive renders (the integrators' default 3).
ADAPTIVE_RR_DEPTH = 3
#: Weight-window lower bound of adaptive renders' Russian roulette
#: (:func:`mcvar.integrators.state.roulette`; 1 is pbrt's rule). pbrt's rule
#: from 3 segments on put a large share of a 256-spp Cornell render's MSE
#: into roulette (a path of throughput 0.04 survives with q = 0.04 and is
#: weighted 25x); starting it later (7 segments) halved that for +30% time,
#: the window 0.2 from 3 segments gives a lower MSE for less time
#: (docs/performance.md).
ADAPTIVE_RR_THRESHOLD = 0.2

#: The path settings of adaptive renders (and ``mcvar render``'s default), for
#: the methods that take them (the path methods). ``caustics='light'``: caustic
#: paths by light tracing where the scene allows it (:mod:`mcvar.integrators.caustics`;
#: on ``cornell-spheres`` MSE 1.28e-4 -> 5.0e-5 at the same time); ``glass_splits=1``:
#: a camera ray that meets glass follows both lobes (MSE 4.8e-5 -> 3.3e-5 for +8%
#: CPU time; docs/performance.md); ``reuse``: path reuse over 2 x 2 pixel tiles in
#: the Lambertian kernel (:mod:`mcvar.integrators.reuse`; 128 x 128 box: per-pixel
#: variance 4.97e-6 -> 1.51e-6 for 1.56x the time, the tiles' noise correlated).
ADAPTIVE_SETTINGS = {"rr_depth": ADAPTIVE_RR_DEPTH, "visible_lights": "exact",
                     "rr_threshold": ADAPTIVE_RR_THRESHOLD, "caustics": "light", "glass_splits": 1,
                     "reuse": REUSE_SIZE}

#: The fields of :class:`~mcvar.integrators.allocation.Adaptive` render_adaptive takes as keywords.
_ALLOCATION_KEYS = ("pilot_spp", "min_spp", "max_spp", "exponent")

__all__ += ["ADAPTIVE_DIM", "PILOT_MAX_DEPTH", "PILOT_PATHS_PER_BATCH", "ADAPTIVE_RR_DEPTH",
            "ADAPTIVE_RR_THRESHOLD"]


def adaptive_settings(method) -> dict:
    """:data:`ADAPTIVE_SETTINGS` restricted to the options ``method`` takes."""
    m = get_method(method)
    return {k: v for k, v in ADAPTIVE_SETTINGS.items() if k in m.options}


def render_adaptive(scene: Scene, *, method: str | None = None, spp: int = 256, res=64, sampler: str = "sobol",
                    rng=None, **options) -> Render:
    """Render with the same total work as ``spp`` samples per pixel, spent where a pilot saw variance.

    ``render(scene, method=method, spp=spp, res=res, sampler=sampler, rng=rng,
    allocation=Adaptive(pilot_spp, min_spp, max_spp, exponent), **options)``
    with :data:`ADAPTIVE_SETTINGS` as defaults for the path methods.

    Parameters
    ----------
    scene : Scene
    method : str
        Any camera-kind method of :data:`mcvar.integrators.METHODS` (``path``,
        the default, ``path_bsdf``, ``direct*``, ``photon``); ``integrator=``
        is an accepted alias.
    spp : int
        Average samples per pixel of the whole render, pilot included.
    res : int or (int, int)
    sampler : str
        A sampler of :data:`mcvar.samplers.SAMPLERS` (pilot and second stage;
        not ``grid`` / ``jittered``, which need square counts).
    rng : None, int, SeedSequence or Generator
        The same seed gives the same image for any ``workers``.
    **options
        ``pilot_spp`` (default ``max(4, spp // 32)``; 0: no pilot, every pixel
        ``spp``, rendered as pixel tiles), ``min_spp`` (default ``max(1, spp //
        8)``), ``max_spp`` (default ``64 spp``), ``exponent`` (``n_i ~
        sigma_i^exponent``; default 1 for ``random``, 0.5 otherwise): the
        fields of :class:`~mcvar.integrators.allocation.Adaptive`; and every
        keyword of :func:`~mcvar.integrators.render` (``max_depth``,
        ``heuristic``, ``workers`` (default 1), ``executor``, ``progress`` (a
        callable gets ``(paths_done, paths_total)``), ``precision``,
        ``light_sampling``, ``rr_depth`` (default 3), ``visible_lights``
        (default ``'exact'``), ``rr_threshold`` (default 0.2), ``reuse``
        (default :data:`~mcvar.integrators.reuse.REUSE_SIZE`: path reuse over
        2 x 2 pixel tiles, whose noise is then correlated; 1 turns it off), ...).

    Returns
    -------
    AdaptiveRender
        ``image`` is the second stage's per-pixel mean; ``spp`` the average
        samples per pixel spent (pilot included); ``variance`` is scaled so
        that ``variance / spp`` is each pixel's variance of the mean
        (``s_i^2 / n_i``): :attr:`Render.standard_error` stays per pixel;
        ``spp_map`` holds the second stage's samples per pixel, (H, W).

    Notes
    -----
    Unbiased: :mod:`mcvar.integrators.allocation` (the pilot's samples are
    not in the image). Ctrl-C (``KeyboardInterrupt``, also from a
    ``progress`` callback) returns ``interrupted=True`` with the finished
    batches; pixels whose second stage did not finish show their pilot mean.

    Examples
    --------
    >>> from mcvar.scene import load_scene
    >>> r = render_adaptive(load_scene("cornell"), spp=16, res=8, rng=1)
    >>> r.spp_map.shape, r.pilot_spp
    ((8, 8), 4)
    """
    kw = dict(options)
    name = pop_method_name(kw, method, "render_adaptive")
    allocation = Adaptive(**{k: kw.pop(k) for k in _ALLOCATION_KEYS if k in kw})
    if "settings" not in kw:
        kw = {**adaptive_settings(name), **kw}
    return render(scene, method=name, spp=spp, res=res, sampler=sampler, rng=rng, allocation=allocation, **kw)
