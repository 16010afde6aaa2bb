"""The general loop's cost per path, old tree against new, interleaved (issue 27).

Run: ``python benchmarks/bench_general_loop.py --old /path/to/old/tree [--rounds 5] [--scenes ...]``

Each measurement is its own process with the given tree first on
``sys.path``: it builds the scene, warms up (a 16-spp 32 x 32 render), then
renders ``render_adaptive(scene, spp, res, rng=seed, workers=W)`` (the
``mcvar render`` default but for ``workers``) and prints its wall and CPU
seconds, paths and rays. Rounds alternate old and new for every scene, so a
busy machine slows both alike; the table gives medians, seconds per
million paths (wall and, for one worker, the process's CPU time, which
moves less with the load), and the load average before and after.

``--mse R``: also render ``R`` seeds of each (tree, scene) at the same
settings and report the MSE as the variance across seeds (the estimators are
unbiased, so the MSE is their variance; per pixel and channel, averaged over
the image, with the ``R / (R - 1)`` correction) and MSE x time with the
median wall time.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

_CHILD = r'''
import json, sys, time
import numpy as np
from mcvar.adaptive import render_adaptive
from mcvar.scene import load_scene
scene, spp, res, seed, workers, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]), sys.argv[6]
sc = load_scene(scene)
render_adaptive(sc, spp=16, res=32, rng=0, workers=workers)
w, c = time.perf_counter(), time.process_time()
r = render_adaptive(sc, spp=spp, res=res, rng=seed, workers=workers)
w, c = time.perf_counter() - w, time.process_time() - c
if out != "-":
    np.save(out, r.image)
print(json.dumps(dict(wall=w, cpu=c, rays=int(r.rays), paths=res * res * spp)))
'''


def run(tree: str, scene: str, spp: int, res: int, seed: int, workers: int, image: str = "-") -> dict:
    env = dict(os.environ, PYTHONPATH=tree, OPENBLAS_NUM_THREADS="1")
    p = subprocess.run([sys.executable, "-c", _CHILD, scene, str(spp), str(res), str(seed), str(workers), image],
                       env=env, capture_output=True, text=True, cwd=tree)
    if p.returncode:
        raise RuntimeError(p.stderr)
    return json.loads(p.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", required=True, help="the tree before (e.g. a git worktree of main)")
    ap.add_argument("--new", default=str(Path(__file__).resolve().parents[1]), help="the tree after (default: this one)")
    ap.add_argument("--scenes", nargs="+", default=["cornell", "cornell-spheres", "cornell-point"])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--mse", type=int, default=0, help="seeds per (tree, scene) for the MSE (0: none)")
    args = ap.parse_args(argv)
    trees = {"old": args.old, "new": args.new}
    load0 = os.getloadavg()
    res = {(t, s): [] for t in trees for s in args.scenes}
    for r in range(args.rounds):
        for s in args.scenes:
            for t in (("old", "new") if r % 2 == 0 else ("new", "old")):
                res[t, s].append(run(trees[t], s, args.spp, args.res, 1 + r, args.workers))
    load1 = os.getloadavg()
    print(f"# {args.res}x{args.res}, {args.spp} spp, render_adaptive, workers={args.workers}, "
          f"{args.rounds} interleaved rounds; load average {load0[0]:.2f} before, {load1[0]:.2f} after")
    print("| scene | tree | wall s (median) | s per M paths (wall) | CPU s per M paths | rays per path |")
    print("|---|---|---|---|---|---|")
    for s in args.scenes:
        for t in trees:
            rows = res[t, s]
            wall = float(np.median([x["wall"] for x in rows]))
            cpu = float(np.median([x["cpu"] for x in rows]))
            mp = rows[0]["paths"] / 1e6
            print(f"| {s} | {t} | {wall:.3f} | {wall / mp:.3f} | {cpu / mp:.3f} | "
                  f"{np.mean([x['rays'] for x in rows]) / rows[0]['paths']:.2f} |")
    if args.mse:
        print("\n| scene | tree | MSE (variance over seeds) | median wall s | MSE x time |")
        print("|---|---|---|---|---|")
        with tempfile.TemporaryDirectory() as tmp:
            for s in args.scenes:
                imgs = {t: [] for t in trees}
                walls = {t: [] for t in trees}
                for i in range(args.mse):
                    for t in (("old", "new") if i % 2 == 0 else ("new", "old")):
                        f = str(Path(tmp) / f"{t}-{s}-{i}.npy")
                        walls[t].append(run(trees[t], s, args.spp, args.res, 1000 + i, args.workers, f)["wall"])
                        imgs[t].append(np.load(f))
                for t in trees:
                    a = np.stack(imgs[t])
                    mse = float(a.var(axis=0, ddof=1).mean())
                    w = float(np.median(walls[t]))
                    print(f"| {s} | {t} | {mse:.3e} | {w:.3f} | {mse * w:.3e} |")
        print(f"# load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
