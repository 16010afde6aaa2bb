"""PSSMLT vs path tracing at equal time on cornell-door (prints tables; not a test).

Run: ``PYTHONPATH=. /work/venv/bin/python benchmarks/bench_pssmlt.py [--seconds 1.5] [--seeds 3]``

Every method gets about the same wall time (``--seconds``): its spp is
calibrated by a short run, then ``--seeds`` independent renders are timed,
interleaved method by method. The error is the MSE against one shared
high-spp path-traced reference (``--ref-spp``, cached on disk in
``--cache-dir`` keyed by scene, resolution, spp and seed; its own noise per
pixel, from its independent chunks, is subtracted). Reported per method:
median time, median MSE (MSE is heavy-tailed: fireflies), and the
efficiency ``1 / (median MSE x median time)`` relative to path tracing's;
also with the process's CPU time instead of the wall time (steadier on a
shared machine, where other processes take the cores).

A method is ``path`` or ``pssmlt`` with options, written
``pssmlt:chains=4096,sigma=0.03,batch=whole`` or ``pssmlt:start=weighted,batch=1024``:
``batch=whole`` renders all spp as one PSSMLT run (``batch_spp=spp``: one
bootstrap, chains as long as the whole render) instead of the driver's
batches of 2^16 mutations; ``batch=N``: batches of at most N spp.
``--trade`` measures the chain-count x mutation-size table of
docs/mcmc.md. Timings are wall clock on whatever machine runs this: the load
average is printed before and after; on a shared machine compare ratios
within one run.
"""
from __future__ import annotations

import argparse
import hashlib
import os
import time
from pathlib import Path

import numpy as np

from mcvar.integrators import render
from mcvar.scene import load_scene

DEFAULT_METHODS = ("path", "pssmlt", "pssmlt:start=weighted,batch=1024", "pssmlt:start=weighted,chain_length=32,batch=1024")
TRADE_CHAINS = (4096, 16384, 65536)
TRADE_SIGMAS = (0.003, 0.01, 0.03, 0.1)


def reference(scene_name: str, res: int, spp: int, cache_dir: Path, chunks: int = 8, seed: int = 4242):
    """Path tracing at ``spp`` in ``chunks`` independent renders: ``(mean image, its variance per pixel)``,
    read from ``cache_dir`` when there."""
    key = hashlib.sha256(f"{scene_name}-{res}-{spp}-{chunks}-{seed}".encode()).hexdigest()[:12]
    path = cache_dir / f"bench-pssmlt-reference-{scene_name}-{res}-{spp}-{key}.npz"
    if path.exists():
        with np.load(path) as data:
            return data["value"], data["variance"]
    scene = load_scene(scene_name)
    images = np.array([render(scene, spp=spp // chunks, res=res, rng=s, progress=False).image
                       for s in np.random.SeedSequence(seed).spawn(chunks)])
    value, variance = images.mean(axis=0), images.var(axis=0, ddof=1) / chunks
    cache_dir.mkdir(parents=True, exist_ok=True)
    np.savez(path, value=value, variance=variance)
    return value, variance


def parse_method(spec: str):
    """``'pssmlt:chains=4096,batch=whole'`` -> ``('pssmlt', {'chains': 4096}, whole=True)``."""
    name, _, rest = spec.partition(":")
    options, whole = {}, False
    for item in filter(None, rest.split(",")):
        key, _, value = item.partition("=")
        if key == "batch":
            whole = True if value == "whole" else int(value)
        else:
            options[key] = _value(value)
    return name, options, whole


def _value(text: str):
    """An option's value: int, float or (``start=weighted``) the string itself."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def run(scene, spec: str, spp: int, res: int, rng):
    name, options, whole = parse_method(spec)
    if whole is True:
        kw = dict(batch_spp=spp)
    elif whole:                            # batch=N: N spp per batch at most
        kw = dict(batch_spp=min(spp, whole))
    else:
        kw = {}
    return render(scene, integrator=name, spp=spp, res=res, rng=rng, progress=False, **options, **kw)


def calibrate(scene, spec: str, res: int, seconds: float) -> int:
    """The spp that takes about ``seconds``: from a run of about a tenth of it, then corrected by
    one run at that estimate (a run's fixed cost, e.g. ``start=weighted``'s chain steps, makes
    the first extrapolation short)."""
    spp = 4
    while True:
        t = run(scene, spec, spp, res, 12345).seconds
        if t > 0.1 * seconds or spp >= 1 << 16:
            break
        spp *= 2
    spp = max(1, int(round(spp * seconds / t)))
    t = run(scene, spec, spp, res, 12346).seconds
    return max(1, int(round(spp * seconds / t)))


def equal_time(scene_name, methods, *, res, seconds, seeds, ref_spp, cache_dir):
    scene = load_scene(scene_name)
    ref, ref_var = reference(scene_name, res, ref_spp, cache_dir)
    noise = float(ref_var.mean())
    spps = {m: calibrate(scene, m, res, seconds) for m in methods}
    stats = {m: [] for m in methods}
    for seed in np.random.SeedSequence(2026).spawn(seeds):
        for m in methods:                                   # interleaved
            cpu = time.process_time()
            r = run(scene, m, spps[m], res, seed)
            cpu = time.process_time() - cpu
            stats[m].append((r.seconds, float(np.mean((r.image - ref) ** 2)) - noise, r.extra, cpu))
    rows = []
    for m in methods:
        t = np.median([s[0] for s in stats[m]])
        cpu = np.median([s[3] for s in stats[m]])
        e = np.array([s[1] for s in stats[m]])
        extra = stats[m][0][2]
        rows.append(dict(method=m, spp=spps[m], seconds=float(t), mse=float(np.median(e)),
                         mse_mean=float(e.mean()), mse_se=float(e.std(ddof=1) / np.sqrt(len(e))) if len(e) > 1 else 0.0,
                         efficiency=float(1.0 / (np.median(e) * t)), cpu=float(cpu),
                         cpu_efficiency=float(1.0 / (np.median(e) * cpu)),
                         acceptance=float(np.ravel(extra["acceptance_rate"])[0]) if "acceptance_rate" in extra else None,
                         tau=float(np.ravel(extra["tau"])[0]) if "tau" in extra else None))
    base = next((r["efficiency"] for r in rows if r["method"] == "path"), None)
    base_cpu = next((r["cpu_efficiency"] for r in rows if r["method"] == "path"), None)
    print(f"\n== {scene_name} {res}x{res}, about {seconds:g} s per render, {seeds} seeds; reference path "
          f"{ref_spp} spp (noise {noise:.2g} subtracted)")
    print(f"{'method':<36} {'spp':>6} {'time s':>7} {'MSE median':>11} {'MSE mean +- SE':>20} "
          f"{'efficiency':>11} {'vs path':>8} {'cpu s':>6} {'vs path (cpu)':>13} {'accept':>7} {'tau':>6}")
    for r in rows:
        rel = r["efficiency"] / base if base else float("nan")
        rel_cpu = r["cpu_efficiency"] / base_cpu if base_cpu else float("nan")
        acc = "" if r["acceptance"] is None else f"{r['acceptance']:.2f}"
        tau = "" if r["tau"] is None else f"{r['tau']:.1f}"
        print(f"{r['method']:<36} {r['spp']:>6} {r['seconds']:>7.2f} {r['mse']:>11.3g} "
              f"{r['mse_mean']:>10.3g} +- {r['mse_se']:<7.2g} {r['efficiency']:>11.3g} {rel:>8.3f} {r['cpu']:>6.2f} "
              f"{rel_cpu:>13.3f} {acc:>7} {tau:>6}")
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="cornell-door")
    ap.add_argument("--res", type=int, default=32)
    ap.add_argument("--seconds", type=float, default=1.5)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--ref-spp", type=int, default=16384)
    ap.add_argument("--cache-dir", type=Path, default=Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
                    / "mcvar")
    ap.add_argument("--methods", default=";".join(DEFAULT_METHODS),
                    help="methods separated by ';' (see the module docstring)")
    ap.add_argument("--trade", action="store_true", help="the chain-count x sigma table (batch=whole)")
    args = ap.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.2f} (1 min) on {os.cpu_count()} CPUs")
    start = time.perf_counter()
    if args.trade:
        methods = ["path"] + [f"pssmlt:chains={c},sigma={s},batch=whole" for c in TRADE_CHAINS for s in TRADE_SIGMAS]
    else:
        methods = [m.strip() for m in args.methods.split(";") if m.strip()]
    equal_time(args.scene, methods, res=args.res, seconds=args.seconds, seeds=args.seeds, ref_spp=args.ref_spp,
               cache_dir=args.cache_dir)
    print(f"load average after: {os.getloadavg()[0]:.2f}; {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
