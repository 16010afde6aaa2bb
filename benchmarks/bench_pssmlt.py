"""PSSMLT vs path tracing: MSE x time on cornell-door and cornell (prints tables; not a test).

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/bench_pssmlt.py [--quick] [--res 32]``

For each scene: a path-traced reference (``--ref-spp``, default 8192 at 32 x 32),
then ``path`` and ``pssmlt`` (``render(..., integrator="pssmlt")`` defaults) at a ladder of spp,
interleaved, ``--reps`` independent runs each. Prints the median wall time, the
mean MSE against the reference (the reference's own variance, ``variance /
spp`` per pixel, subtracted) with its standard error over the runs, the
median MSE (MSE is heavy-tailed: fireflies), and mean MSE x median time
(lower is better; ``1 / efficiency``). ``pssmlt-1k`` is PSSMLT with 1024
chains (4x longer chains, 4x smaller wavefronts per step). ``bdpt`` is added when the integrator exists.
Timings are wall clock on whatever machine runs this: on a shared, loaded
machine compare medians, not single runs.
"""
from __future__ import annotations

import argparse
import os

import numpy as np

from mcvar.integrators import INTEGRATORS, render
from mcvar.scene import load_scene


def _run(method, scene, spp, res, rng):
    if method == "pssmlt-1k":                                   # longer chains, smaller wavefronts
        return render(scene, integrator="pssmlt", spp=spp, res=res, rng=rng, chains=1024)
    return render(scene, integrator=method, spp=spp, res=res, rng=rng)


def table(name, res, ref_spp, ladder, reps, methods):
    scene = load_scene(name)
    ref = render(scene, spp=ref_spp, res=res, rng=np.random.SeedSequence(99))
    ref_var = float((ref.variance / ref.spp).mean())
    print(f"\n== {name} {res}x{res}: reference path {ref_spp} spp ({ref.seconds:.1f} s), "
          f"its own variance per pixel {ref_var:.3g} (subtracted)")
    print(f"{'method':>9} {'spp':>5} {'time s':>8} {'MSE mean':>10} {'+- SE':>9} {'MSE median':>10} "
          f"{'MSE x time':>11} {'runs':>4}")
    rows = []
    for spp in ladder:
        stats = {m: [] for m in methods}
        for k, seed in enumerate(np.random.SeedSequence(spp).spawn(reps)):
            for m in methods:                                   # interleaved
                r = _run(m, scene, spp, res, seed)
                err = float(np.mean((r.image - ref.image) ** 2)) - ref_var
                stats[m].append((r.seconds, err))
        for m in methods:
            t = np.array([s for s, _ in stats[m]])
            e = np.array([x for _, x in stats[m]])
            row = (m, spp, float(np.median(t)), float(e.mean()), float(e.std(ddof=1) / np.sqrt(reps)),
                   float(np.median(e)), float(np.median(t) * e.mean()), reps)
            rows.append(row)
            print(f"{row[0]:>9} {row[1]:>5} {row[2]:>8.3f} {row[3]:>10.3g} {row[4]:>9.2g} {row[5]:>10.3g} "
                  f"{row[6]:>11.3g} {row[7]:>4}")
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--res", type=int, default=32)
    ap.add_argument("--ref-spp", type=int, default=8192)
    ap.add_argument("--reps", type=int, default=4)
    args = ap.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.2f} (1 min) on {os.cpu_count()} CPUs")
    methods = ["path", "pssmlt", "pssmlt-1k"] + (["bdpt"] if "bdpt" in INTEGRATORS else [])
    ladder = (16, 64) if args.quick else (16, 64, 256)
    ref_spp = 1024 if args.quick else args.ref_spp
    for name in ("cornell-door", "cornell"):
        table(name, args.res, ref_spp, ladder, args.reps, methods)


if __name__ == "__main__":
    main()
