"""Two workers on this machine: what the hardware gives, and where a two-worker render idles.

``python benchmarks/bench_two_workers.py hw``: fixed-work loops (NumPy on arrays of
16 kB, 4 MB and 32 MB, fresh temporaries, a gather, pure Python), each run alone
and then as two processes at once, twice; prints wall and CPU seconds per process
(docs/performance.md, 'Two workers: the end of a stage').

``python benchmarks/bench_two_workers.py render --res 128 --spp 256 [--tree PATH]``:
``render_adaptive(cornell, sampler='sobol', workers=2)`` after a warm-up, with every
batch's start and end recorded in both processes; prints per render the wall and CPU
seconds (``getrusage`` of the process and its pool), the idle time of the process
that finished first (end of its last batch to the end of the render) and the time
both spent outside batches. ``--tree`` runs another checkout (a detached worktree of
main) for old/new comparisons in alternating processes.
"""
from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

LOOPS = {"numpy 16 kB": ("np", 4096), "numpy 4 MB": ("np", 1 << 20), "numpy 32 MB": ("np", 1 << 23),
         "fresh temporaries 4 MB": ("alloc", 1 << 20), "take (6, 65536)": ("take", 1 << 16), "python": ("py", 0)}


def _cpu(who=resource.RUSAGE_SELF) -> float:
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


def _loop(kind: str, n: int) -> None:
    import numpy as np

    rng = np.random.default_rng(0)
    if kind == "py":
        s = 0
        for i in range(12_000_000):
            s += i * i
        return
    a, b = rng.random(n, dtype=np.float32), rng.random(n, dtype=np.float32)
    reps = int(3e9 / n / 8)
    if kind == "np":
        c, d = np.empty_like(a), np.empty_like(a)
        for _ in range(reps):
            np.multiply(a, b, out=c); c += a; np.sqrt(c, out=d); d *= b; np.minimum(c, d, out=c)
            np.add(c, a, out=d); d -= b; np.maximum(d, a, out=d)
    elif kind == "alloc":
        for _ in range(reps):
            c = a * b + a; d = np.sqrt(c) * b; c = np.minimum(c, d); d = c + a - b; d = np.maximum(d, a)
    elif kind == "take":
        x = rng.random((6, n), dtype=np.float32)
        idx = np.sort(rng.choice(n, n * 3 // 4, replace=False))
        for _ in range(int(1e9 / n / 6)):
            np.take(x, idx, axis=1)


def hw() -> None:
    me = [sys.executable, __file__, "_loop"]
    for name, (kind, n) in LOOPS.items():
        for _ in range(2):
            alone = subprocess.run(me + [kind, str(n)], capture_output=True, text=True).stdout.split()
            pair = [subprocess.Popen(me + [kind, str(n)], stdout=subprocess.PIPE, text=True) for _ in range(2)]
            both = [p.communicate()[0].split() for p in pair]
            print(f"{name:24s} load {os.getloadavg()[0]:.2f}  alone wall {alone[0]} cpu {alone[1]}  "
                  f"pair wall {both[0][0]}, {both[1][0]} cpu {both[0][1]}, {both[1][1]}", flush=True)


def render(a) -> None:
    sys.path.insert(0, str(Path(a.tree).resolve()))
    import mcvar.integrators.driver as drv
    from mcvar.adaptive import render_adaptive
    from mcvar.scene import load_scene

    log = Path(tempfile.mkdtemp()) / "batches.txt"
    orig = drv._run_batch

    def _run_batch(batch):                       # pickled by name: the pool process runs it too
        t0 = time.time()
        r = orig(batch)
        with open(log, "a") as f:
            f.write(f"{os.getpid()} {t0:.4f} {time.time():.4f}\n")
        return r
    _run_batch.__qualname__ = _run_batch.__name__ = "_run_batch"
    _run_batch.__module__ = drv.__name__
    drv._run_batch = _run_batch
    scene = load_scene("cornell")
    render_adaptive(scene, spp=min(a.spp, 16), res=a.res, sampler="sobol", rng=10 ** 6, workers=2)
    for seed in range(1, a.renders + 1):
        log.write_text("")
        c0 = _cpu() + _cpu(resource.RUSAGE_CHILDREN)
        t0 = time.time()
        render_adaptive(scene, spp=a.spp, res=a.res, sampler="sobol", rng=seed, workers=2)
        end = time.time()
        cpu = _cpu() + _cpu(resource.RUSAGE_CHILDREN) - c0
        rows = [line.split() for line in log.read_text().splitlines()]
        rows = [(int(p), float(s), float(e)) for p, s, e in rows]
        pids = sorted({r[0] for r in rows})
        idle = max(end - max(r[2] for r in rows if r[0] == p) for p in pids)
        outside = sum(end - t0 - sum(r[2] - r[1] for r in rows if r[0] == p) for p in pids)
        print(f"{Path(a.tree).resolve().name} {a.res}x{a.res} {a.spp} spp seed {seed}: wall {end - t0:.3f} s, "
              f"cpu {cpu:.3f} s, {len(rows)} batches, idle at the end {idle:.3f} s, outside batches "
              f"{outside:.2f} s ({100 * outside / (len(pids) * (end - t0)):.0f}%), load {os.getloadavg()[0]:.2f}",
              flush=True)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "_loop":
        t0, c0 = time.perf_counter(), _cpu()
        _loop(argv[1], int(argv[2]))
        print(f"{time.perf_counter() - t0:.3f} {_cpu() - c0:.3f}")
        return 0
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    sub.add_parser("hw", help="loops alone and in pairs")
    r = sub.add_parser("render", help="a two-worker render's batches, per process")
    r.add_argument("--res", type=int, default=128)
    r.add_argument("--spp", type=int, default=256)
    r.add_argument("--renders", type=int, default=2)
    r.add_argument("--tree", default=str(ROOT), help="the checkout to run (default this one)")
    a = ap.parse_args(argv)
    hw() if a.what == "hw" else render(a)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
