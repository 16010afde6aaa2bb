"""One method on one scene for a given wall time: rounds of samples per pixel (issue 21).

A method renders in *rounds*: independent renders of ``b`` samples per pixel (fresh random streams),
combined as the spp-weighted mean, until the time spent reaches ``seconds``. The first round has 1
spp; each next round is sized from the measured rate to take ``min(remaining, seconds / 4)``. Two
exceptions, because their estimate is not a mean of independent rounds: :data:`PROGRESSIVE`
methods (SPPM: one run, a pilot iteration to time it) and :data:`REUSE_PREPARED` ones (radiosity:
one solve, looked up by every round).
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from . import compare_args as _args

__all__ = ["PROGRESSIVE", "REUSE_PREPARED", "TimedRender", "equal_time_render"]

#: Methods whose estimate is one progressive run (its bias falls with the iterations of that run).
PROGRESSIVE = frozenset({"sppm"})
#: Methods whose ``prepare`` is solved once and reused by every round (view-independent solves).
REUSE_PREPARED = frozenset({"radiosity"})


@dataclass(frozen=True)
class TimedRender:
    """One equal-time render: the combined image, the spp and the wall time actually used."""

    image: np.ndarray = field(repr=False)
    spp: int
    seconds: float
    rounds: int
    max_round_seconds: float
    prepare_seconds: float = 0.0


def _prepared(value, scene, options, rng):
    """``Method.prepare`` that hands out a solve made earlier (:data:`REUSE_PREPARED`)."""
    return value


def equal_time_render(scene, method: str, *, seconds: float, res: int, rng, options=None) -> TimedRender:
    """Render ``scene`` with ``method`` for ``seconds`` of wall time (rounds of spp; module docstring).

    ``scene`` is a :class:`mcvar.scene.Scene`; ``options`` the method's
    options. Raises ValueError when the method refuses the scene (before any
    work) and KeyboardInterrupt when a round was interrupted.
    """
    entry = _args._registered()[method]
    options = dict(options or {})
    resolved = entry.resolve_options(options)
    if entry.check_scene is not None:
        entry.check_scene(scene, resolved)
    streams = rng if isinstance(rng, np.random.SeedSequence) else np.random.SeedSequence(rng)
    start = time.perf_counter()
    integrator, prepare_seconds = method, 0.0
    if method in REUSE_PREPARED and entry.prepare is not None:
        solve = entry.prepare(scene, resolved, np.random.default_rng(
            np.random.SeedSequence(streams.entropy, spawn_key=streams.spawn_key + (2**31,))))
        prepare_seconds = time.perf_counter() - start
        integrator = dataclasses.replace(entry, prepare=partial(_prepared, solve))

    one = partial(_round, scene, integrator, res, streams, options)
    if method in PROGRESSIVE:
        _, _, pilot = one(1, 0)
        left = seconds - (time.perf_counter() - start)
        n = max(1, int(0.9 * left / pilot)) if left > 0 else 1
        image, spp, t = one(n, 1)
        return TimedRender(image, spp, time.perf_counter() - start, 2, max(pilot, t))
    total = np.zeros((res, res, 3))
    done, rounds, longest, size = 0, 0, 0.0, 1
    while True:
        image, spp, t = one(size, rounds)
        total += image * spp
        done += spp
        rounds += 1
        longest = max(longest, t)
        elapsed = time.perf_counter() - start
        if elapsed >= seconds:
            break
        target = min(seconds - elapsed, seconds / 4)
        size = int(np.clip(np.floor(spp / max(t, 1e-9) * target), 1, 4 * spp))
    return TimedRender(total / done, done, elapsed, rounds, longest, prepare_seconds)


def _round(scene, integrator, res, streams, options, spp, k):
    """One round: ``spp`` samples per pixel of ``integrator`` in one render (one batch for
    progressive methods, so the radius keeps shrinking); (image, spp, seconds)."""
    t0 = time.perf_counter()
    name = integrator if isinstance(integrator, str) else integrator.name
    batch = {"batch_spp": spp} if name in PROGRESSIVE else {}
    r = _args._render(scene, integrator=integrator, spp=spp, res=res, rng=np.random.SeedSequence(streams.entropy, spawn_key=streams.spawn_key + (k,)),
                progress=False, **batch, **options)
    if r.interrupted:
        raise KeyboardInterrupt
    return np.asarray(r.image, dtype=np.float64), r.spp, time.perf_counter() - t0

