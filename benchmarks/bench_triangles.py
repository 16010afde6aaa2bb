"""How the cost of a path grows with the number of triangles (prints figures; not a test).

Run: ``python benchmarks/bench_triangles.py [--quick] [--rounds R] [--trees OLD NEW]``
or ``python benchmarks/bench_triangles.py --stages K`` (where the BVH's time goes).

The Cornell box with every non-emitting triangle cut into ``k^2`` pieces
(:func:`mcvar.tessellate.subdivide`: the same surfaces, so the same image)
from 32 to ~94,000 triangles, rendered with ``path`` (sampler sobol, 1
worker), with brute force over triangle groups (``accel='groups'``) where it
is affordable and with the BVH (``accel='bvh'``) from 122 triangles on.
Prints paths per second (best of the rounds, after a warm-up render), both
by the wall clock (``Render.seconds``) and by the process's CPU time over
the same span (which a busy machine disturbs less), the BVH build time and size, the ratio to the
coarse box and the log-log slope of seconds per path against triangles.
Each scene's tracer is built once and reused, so the times exclude the
build (printed apart).

Interleaved: every round renders every case once, so a change of the
machine's load touches all cases alike. With ``--trees OLD NEW`` (two
checkouts of mcvar, e.g. ``git worktree add ../base <commit>``) every round
runs the cases once in a fresh process for each tree in turn, and the table
puts the two side by side.

``--stages K``: the BVH queries of one render of the box subdivided ``K`` times
(64 x 64, 32 spp, ``path``, sobol) are captured and replayed, and the time of
each stage of the wavefront traversal (``mcvar.bvh._Chunk``'s methods, timed by
wrapping them) is printed per (ray, node) pair, with the calls, the rays per
call, the rounds and the pairs per ray: the figures of docs/performance.md,
'Triangle count', 'Where a visit's time goes'.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

KS = (1, 2, 3, 4, 8, 16, 32, 56)
BRUTE_UP_TO = 2000      # brute force costs O(T) per ray: 1,922 triangles already take 30x the box's time
BVH_FROM = 100


def _cases():
    """``(k, accel)`` of every case: brute force up to BRUTE_UP_TO triangles, the BVH from BVH_FROM."""
    from mcvar.scene import load_scene
    from mcvar.tessellate import subdivide

    coarse = load_scene("cornell")
    out = []
    for k in KS:
        n = subdivide(coarse, k).n_triangles
        if n <= BRUTE_UP_TO:
            out.append((k, "groups"))
        if n >= BVH_FROM:
            out.append((k, "bvh"))
    return out


def one_round(res: int, spp: int) -> dict:
    """Render every case once in this process: ``{case: {...}}`` (JSON-able)."""
    import mcvar.integrators.driver as driver
    import mcvar.tracer as T
    from mcvar.integrators import render
    from mcvar.scene import load_scene
    from mcvar.tessellate import subdivide

    coarse = load_scene("cornell")
    built = {}
    real_tracer = driver.Tracer

    def cached(scene, **kw):           # the render's tracer, built once per case (timed apart)
        return built[scene.name]

    # CPU time over the span of the render's own clock (Render.seconds runs from
    # _Render.start to _Render.result; the setup before it is not the tracer's cost)
    cpu_marks = {}
    real_start, real_result = driver._Render.start, driver._Render.result

    def start(self, *, total):
        real_start(self, total=total)
        cpu_marks["start"] = time.process_time()

    def result(self, *args, **fields):
        cpu_marks["end"] = time.process_time()
        return real_result(self, *args, **fields)

    driver._Render.start, driver._Render.result = start, result

    out = {}
    for k, accel in _cases():
        scene = subdivide(coarse, k)
        keep = T.BVH_MIN_TRIANGLES
        # the tracer of this tree for the accel asked (older trees have no accel argument)
        T.BVH_MIN_TRIANGLES = 0 if accel == "bvh" else 10 ** 9
        try:
            t0 = time.perf_counter()
            tr = real_tracer(scene)
            build = time.perf_counter() - t0
        finally:
            T.BVH_MIN_TRIANGLES = keep
        used = getattr(tr, "accel", accel)
        size = tr._bvh.nbytes if used == "bvh" else 0
        built[scene.name] = tr
        driver.Tracer = cached
        try:
            render(scene, integrator="path", spp=1, res=8, sampler="sobol", rng=0)
            r = render(scene, integrator="path", spp=spp, res=res, sampler="sobol", rng=1)
            cpu = cpu_marks["end"] - cpu_marks["start"]
        finally:
            driver.Tracer = real_tracer
        out[f"{k}:{accel}"] = dict(triangles=scene.n_triangles, tracer=used, build=build, bytes=size,
                                   wall=r.seconds, cpu=cpu, mean=float(r.image.mean()))
    return out


def _table(results: dict, res: int, spp: int, label: str):
    """Print one tree's table from ``{case: [round results]}``."""
    paths = res * res * spp
    rows = {c: dict(v[0], wall=min(x["wall"] for x in v), cpu=min(x["cpu"] for x in v),
                    build=min(x["build"] for x in v)) for c, v in results.items()}
    base = rows["1:groups"]
    print(f"\n{label}")
    print(f"{'triangles':>9} {'tracer':>7} {'build s':>8} {'B/tri':>6} {'M paths/s':>10} {'vs box':>7} "
          f"{'cpu M p/s':>10} {'vs box':>7} {'image mean':>11}")
    xs, ys = [], []
    for c, r in rows.items():
        bpt = f"{r['bytes'] / r['triangles']:.0f}" if r["bytes"] else ""
        build = f"{r['build']:.3f}" if r["tracer"] == "bvh" else ""
        print(f"{r['triangles']:>9} {r['tracer']:>7} {build:>8} {bpt:>6} {paths / r['wall'] / 1e6:>10.3f} "
              f"{base['wall'] / r['wall']:>7.2f} {paths / r['cpu'] / 1e6:>10.3f} {base['cpu'] / r['cpu']:>7.2f} "
              f"{r['mean']:>11.5f}")
        if r["tracer"] == "bvh":
            xs.append(np.log(r["triangles"]))
            ys.append(np.log(r["cpu"]))
    if len(xs) > 1:
        print(f"log-log slope of CPU seconds per path against triangles (BVH cases): {np.polyfit(xs, ys, 1)[0]:.3f}")


def stages(k: int, res: int = 64, spp: int = 32, passes: int = 3) -> dict:
    """Capture the BVH queries of one render of the box subdivided ``k`` times, replay
    them ``passes`` times with every stage of the traversal timed; print and return
    ``{query: {stage: seconds (best pass)}}`` and the counts."""
    import mcvar.bvh as B
    from mcvar.integrators import render
    from mcvar.scene import load_scene
    from mcvar.tessellate import subdivide

    scene = subdivide(load_scene("cornell"), k)
    calls, real = [], {"closest": B.closest, "occluded": B.occluded}
    seen = {}

    def capture(name):
        def f(bvh, o, d, tmax, eps, *a, **kw):
            seen["bvh"] = bvh
            keep = kw.get("keep")
            calls.append((name, np.array(o), np.array(d), np.array(np.broadcast_to(tmax, np.shape(o)[1:])), eps,
                          None if keep is None else np.array(keep)))
            return real[name](bvh, o, d, tmax, eps, *a, **kw)
        return f

    B.closest, B.occluded = capture("closest"), capture("occluded")
    try:
        render(scene, method="path", spp=spp, res=res, sampler="sobol", rng=1)
    finally:
        B.closest, B.occluded = real["closest"], real["occluded"]
    bvh = seen["bvh"]
    clock = time.perf_counter
    acc, count = {}, {}
    C = B._Chunk
    wrapped = {"chunk set-up": (C, "__init__"), "boxes": (C, "boxes"), "slab": (B, "_slab"),
               "children": (C, "children"), "leaves": (C, "leaves"), "leaf test": (B, "_leaf_t"),
               "split": (C, "split")}
    originals = {name: getattr(obj, attr) for name, (obj, attr) in wrapped.items()}

    def timed(name, fn):
        def f(*a, **kw):
            t0 = clock()
            try:
                return fn(*a, **kw)
            finally:
                acc[name] = acc.get(name, 0.0) + clock() - t0
                if name in ("children", "leaves"):
                    count[name] = count.get(name, 0) + a[1].size        # pairs entering the stage
                if name == "children":
                    count["rounds"] = count.get("rounds", 0) + 1
        return f

    best: dict = {}
    for _ in range(passes):
        for query in ("closest", "occluded"):
            acc.clear()
            count.clear()
            for name, (obj, attr) in wrapped.items():
                setattr(obj, attr, timed(name, originals[name]))
            try:
                t0 = clock()
                for c in calls:
                    if c[0] == query:
                        fn = B.closest if query == "closest" else B.occluded
                        fn(bvh, c[1], c[2], c[3], c[4], **({} if c[5] is None else {"keep": c[5]}))
                total = clock() - t0
            finally:
                for name, (obj, attr) in wrapped.items():
                    setattr(obj, attr, originals[name])
            # exclusive times: a method's own time minus the stages it calls
            st = {"chunk set-up": acc.get("chunk set-up", 0.0),
                  "box gathers": acc.get("boxes", 0.0) - acc.get("slab", 0.0),
                  "slab test": acc.get("slab", 0.0),
                  "listing the children": acc.get("children", 0.0) - acc.get("boxes", 0.0),
                  "leaf/inner split": acc.get("split", 0.0) - acc.get("leaves", 0.0),
                  "leaf gathers and record": acc.get("leaves", 0.0) - acc.get("leaf test", 0.0),
                  "leaf test": acc.get("leaf test", 0.0)}
            st["rest (calls, chunks, loops)"] = total - sum(st.values())
            st["total"] = total
            if query not in best or total < best[query]["stages"]["total"]:
                best[query] = {"stages": st, "count": dict(count)}
    print(f"{scene.n_triangles:,} triangles, {res}x{res}, {spp} spp; load average {os.getloadavg()[0]:.2f}")
    for query in ("closest", "occluded"):
        rays = [c[1].shape[1] for c in calls if c[0] == query]
        n, cnt, st = sum(rays), best[query]["count"], best[query]["stages"]
        pairs = cnt.get("children", 0)
        print(f"\n{query}: {len(rays)} calls, {n:,} rays (largest call {max(rays):,}, median {int(np.median(rays)):,}), "
              f"{cnt.get('rounds', 0)} rounds, {pairs / n:.2f} node pairs and {cnt.get('leaves', 0) / n:.2f} "
              f"leaf pairs a ray (best of {passes} passes)")
        for name, v in st.items():
            print(f"  {name:28s} {v * 1e3:8.1f} ms  {v / max(pairs, 1) * 1e9:6.1f} ns a node pair")
    return best


def main(quick: bool = False, rounds: int | None = None, trees=None, child: bool = False, stages_k=None):
    if stages_k:
        stages(stages_k)
        return
    res, spp = (32, 16) if quick else (64, 32)
    rounds = rounds or (2 if quick else 3)
    if child:
        print(json.dumps(one_round(res, spp)))
        return
    print(f"load average before: {os.getloadavg()} (1, 5, 15 min) on {os.cpu_count()} CPUs; "
          f"{res}x{res}, {spp} spp, best of {rounds} interleaved rounds")
    trees = trees or [None]
    results = {t: {} for t in trees}
    for _ in range(rounds):
        for t in trees:
            if t is None:
                got = one_round(res, spp)
            else:
                env = dict(os.environ, PYTHONPATH=os.path.abspath(t), OMP_NUM_THREADS="1")
                cmd = [sys.executable, os.path.abspath(__file__), "--child"] + (["--quick"] if quick else [])
                got = json.loads(subprocess.run(cmd, env=env, check=True, capture_output=True,
                                                text=True).stdout.strip().splitlines()[-1])
            for c, v in got.items():
                results[t].setdefault(c, []).append(v)
        print(f"  round done, load {os.getloadavg()[0]:.2f}", flush=True)
    for t in trees:
        _table(results[t], res, spp, "this tree" if t is None else t)
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true")
    p.add_argument("--rounds", type=int, default=None)
    p.add_argument("--trees", nargs=2, default=None, metavar=("OLD", "NEW"))
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--stages", type=int, default=None, metavar="K", dest="stages_k",
                   help="time the BVH traversal's stages on a render of the box subdivided K times (56: 94,082 "
                        "triangles) and print them per node pair")
    main(**vars(p.parse_args()))
