"""Radiosity's view independence, timed: one solve, two camera views (issue 21)."""
from __future__ import annotations

import dataclasses
import time
from functools import partial
from pathlib import Path

import numpy as np

from .._validation import check_count
from . import compare_args as _args
from .chart import emitter_pixels
from .compare_args import _options, _registered, _seed_sequence
from .equal_time import _prepared
from .scene_references import REFERENCES, _reference_key, scene_reference

__all__ = ["radiosity_views"]


def radiosity_views(scene: str = "cornell", *, res: int = 32, spp: int = 4, seed: int = 0, camera=None,
                    options=None, cache_dir=None, reference_spp: int | None = None) -> dict:
    """Radiosity's view independence, timed: one solve, two camera views.

    Solves ``scene`` once (``Method.prepare`` of ``radiosity``, low accuracy:
    :data:`COMPARE_OPTIONS`), renders the scene's camera and a second
    ``camera`` (default: from a corner of the room) from that solve, and
    times the solve, each view, and a full render (solve + view) of the
    second view for comparison. Each view's MSE is against a path-traced
    reference of that view.

    Returns
    -------
    dict
        ``solve_seconds``, ``view1_seconds``, ``view2_seconds``,
        ``full_seconds`` (solve and view 2 from scratch), ``fraction``
        (view2 / full), ``mse1``, ``mse2``, ``mse1_off_emitters`` (view 1
        without the pixels that see the light, whose edges dominate at a few
        spp: :func:`~mcvar.experiments.chart.emitter_pixels`), ``images``
        (view 1, view 2), ``references`` (their references: the scene's
        :func:`scene_reference` and path tracing for view 2).
    """
    from ..scene import Camera, load_scene

    res = check_count(res, "res")
    sc = load_scene(scene)
    if camera is None:
        # from the upper left of the open front, looking down at the right half of the room
        # (the Cornell camera looks along +z from (278, 273, -800))
        camera = Camera((120.0, 420.0, -450.0), (330.0, 160.0, 280.0), (0.0, 1.0, 0.0), 45.0)
    sc2 = dataclasses.replace(sc, camera=camera)
    entry = _registered()["radiosity"]
    opts = entry.resolve_options(_options("radiosity", options))
    entry.check_scene(sc, opts)
    t0 = time.perf_counter()
    solve = entry.prepare(sc, opts, np.random.default_rng(_seed_sequence("radiosity", scene, seed)))
    solve_seconds = time.perf_counter() - t0
    reuse = dataclasses.replace(entry, prepare=partial(_prepared, solve))
    t0 = time.perf_counter()
    v1 = _args._render(sc, integrator=reuse, spp=spp, res=res, rng=_seed_sequence("view1", seed))
    view1 = time.perf_counter() - t0
    t0 = time.perf_counter()
    v2 = _args._render(sc2, integrator=reuse, spp=spp, res=res, rng=_seed_sequence("view2", seed))
    view2 = time.perf_counter() - t0
    t0 = time.perf_counter()
    _args._render(sc2, integrator="radiosity", spp=spp, res=res, rng=_seed_sequence("full", seed),
            **_options("radiosity", options))
    full = time.perf_counter() - t0
    ref1 = scene_reference(scene, res, spp=reference_spp, seed=seed, cache_dir=cache_dir).value
    reference_spp = reference_spp or REFERENCES.get(scene, ("path", 4096))[1]
    # the second view's reference is not a named scene: render it here (path tracing, cached by key)
    key = _reference_key(scene + ":view2:" + repr(np.round(camera.position, 6).tolist())
                         + repr(np.round(camera.look_at, 6).tolist()), res, "path", reference_spp, 1, seed, {})
    path = Path(cache_dir) / f"reference-view2-{key}.npy" if cache_dir is not None else None
    if path is not None and path.exists():
        ref2 = np.load(path)
    else:
        ref2 = np.asarray(_args._render(sc2, integrator="path", spp=reference_spp, res=res,
                                  rng=_seed_sequence("reference-view2", seed)).image, dtype=np.float64)
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            np.save(path, ref2)
    return dict(solve_seconds=solve_seconds, view1_seconds=view1, view2_seconds=view2, full_seconds=full,
                fraction=view2 / full, mse1=float(np.mean((v1.image - ref1) ** 2)),
                mse2=float(np.mean((v2.image - ref2) ** 2)),
                mse1_off_emitters=float(np.mean(((v1.image - ref1) ** 2)[~emitter_pixels(scene, res)])),
                images=(v1.image, v2.image),
                references=(ref1, ref2), camera=camera)

