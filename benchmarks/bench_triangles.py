"""How the cost of a path grows with the number of triangles (prints figures; not a test).

Run: ``python benchmarks/bench_triangles.py [--quick]``

The Cornell box with every non-emitting triangle cut into ``k^2`` pieces
(:func:`mcvar.tessellate.subdivide`: the same surfaces, so the same image)
from 32 to ~94,000 triangles, rendered with ``path`` (sampler sobol, 1
worker) with the tracer's automatic choice (brute force over triangle groups
up to :data:`mcvar.tracer.BVH_MIN_TRIANGLES`, the BVH above) and, where it
is affordable, with brute force forced (``accel='groups'``). Prints paths per
second (best of the repeats, after a warm-up render that also builds the
tracer), the BVH build time and size, the ratio to the coarse box and the
log-log slope of seconds per path against triangles. Interleaved: every
round renders every case once, so a change of the machine's load touches
all cases alike.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from mcvar.integrators import render
from mcvar.scene import load_scene
from mcvar.tessellate import subdivide
from mcvar.tracer import Tracer

KS = (1, 2, 4, 8, 16, 32, 56)
BRUTE_UP_TO = 2000      # brute force costs O(T) per ray: 482 triangles already take 25x the box's time


def main(quick: bool = False):
    res, spp, rounds = (32, 16, 2) if quick else (64, 32, 3)
    print(f"load average before: {os.getloadavg()[0]:.2f} (1 min) on {os.cpu_count()} CPUs; "
          f"{res}x{res}, {spp} spp, best of {rounds} interleaved rounds")
    coarse = load_scene("cornell")
    cases = []
    for k in KS:
        scene = subdivide(coarse, k)
        t0 = time.perf_counter()
        tr = Tracer(scene)
        build = time.perf_counter() - t0
        cases.append((scene, "auto", tr.accel, build, tr))
        if scene.n_triangles <= BRUTE_UP_TO and tr.accel != "groups":
            cases.append((scene, "groups", "groups", 0.0, None))
    best = {i: np.inf for i in range(len(cases))}
    means = {}
    for _ in range(rounds):
        for i, (scene, accel, _, _, _) in enumerate(cases):
            import mcvar.tracer as T
            keep = T.BVH_MIN_TRIANGLES
            if accel == "groups":
                T.BVH_MIN_TRIANGLES = 10 ** 9
            try:
                render(scene, integrator="path", spp=1, res=8, sampler="sobol", rng=0)
                r = render(scene, integrator="path", spp=spp, res=res, sampler="sobol", rng=1)
            finally:
                T.BVH_MIN_TRIANGLES = keep
            best[i] = min(best[i], r.seconds)
            means[i] = float(r.image.mean())
    base = best[0]
    print(f"{'triangles':>9} {'tracer':>7} {'build s':>8} {'M paths/s':>10} {'vs box':>7} {'image mean':>11}")
    xs, ys = [], []
    for i, (scene, accel, used, build, _) in enumerate(cases):
        rate = res * res * spp / best[i] / 1e6
        print(f"{scene.n_triangles:>9} {used:>7} {build:>8.3f} {rate:>10.3f} {base / best[i]:>7.2f} {means[i]:>11.5f}")
        if used == "bvh":
            xs.append(np.log(scene.n_triangles))
            ys.append(np.log(best[i]))
    if len(xs) > 1:
        slope = np.polyfit(xs, ys, 1)[0]
        print(f"log-log slope of seconds per path against triangles (BVH cases): {slope:.3f}")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true")
    main(**vars(p.parse_args()))
