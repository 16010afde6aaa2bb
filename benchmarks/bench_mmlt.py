"""MMLT vs path, bdpt and pssmlt at equal time on cornell-door (prints tables; not a test).

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/bench_mmlt.py [--seconds 2] [--seeds 3] [--first-seed 0] [--res 32] [--slit 20]
[--center 278] [--height 300] [--methods path,bdpt,pssmlt,mmlt] [--mmlt-options '{"chains": 4096}']
[--variants '[{}, {"direct_depth": 2}]']``
(the door's geometry as ``cornell_door_scene``'s parameters; ``--center 200 --height 120`` puts the slit
behind the short block, where the camera sees neither the closet nor any directly lit surface)

Every method renders at the same fixed depth (``--depth``, default
``mmlt.DEFAULT_MAX_DEPTH`` = 5 segments: MMLT's state has a fixed size) so
that one reference serves all. The reference is path tracing (``--ref-method``;
it agrees with BDPT at this depth: 8 192 spp against BDPT at 1 024, the MSE
is the two references' noise, excess 5e-9) at ``--ref-spp`` (4 independent chunks; their spread is its own noise, subtracted from every
MSE), cached in ``.mcvar-cache/`` keyed by the scene, the settings and the
renderer's source (``mcvar.experiments.scene_references``' code key: a change of
the integrators renders a new one). Each method's spp is calibrated by a
pilot to take ``--seconds``; chain methods run one batch (one bootstrap,
the longest chains) of up to ``CHAIN_BATCH`` mutations. Seeds are interleaved across
methods; medians over seeds of time and MSE; efficiency = 1 / (MSE x time).
Timings are wall clock on a shared machine: the load is printed.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import time
from pathlib import Path

import numpy as np

from mcvar.experiments.scene_references import _code_key
from mcvar.integrators import mmlt, render
from mcvar.scene import load_scene

CACHE = Path(__file__).resolve().parents[1] / ".mcvar-cache"
LUM = np.array([0.2126, 0.7152, 0.0722])
#: Mutations per batch of the chain methods (larger renders: independent batches of this size).
CHAIN_BATCH = 1 << 20


def reference(scene, name, res, depth, spp, chunks=4, method="path"):
    """``(image, noise)``: ``method`` at ``spp`` (``chunks`` independent renders), cached; ``noise`` the
    mean variance of the mean per pixel and channel (the floor under every MSE)."""
    key = hashlib.sha256(json.dumps(dict(code=_code_key(), scene=name, res=res, depth=depth, spp=spp,
                                         chunks=chunks, method=method), sort_keys=True).encode()).hexdigest()[:20]
    path = CACHE / f"reference-mmlt-bench-{key}.npz"
    if path.exists():
        with np.load(path) as data:
            return data["value"], float(data["noise"])
    start = time.perf_counter()
    imgs = np.array([render(scene, method=method, spp=spp // chunks, res=res, rng=s, max_depth=depth).image
                     for s in np.random.SeedSequence(2222).spawn(chunks)])
    value = imgs.mean(axis=0)
    noise = float((imgs.var(axis=0, ddof=1) / chunks).mean())
    CACHE.mkdir(exist_ok=True)
    np.savez(path, value=value, noise=noise)
    print(f"reference: {method} {spp} spp in {time.perf_counter() - start:.1f} s, noise {noise:.3g} (cached {path.name})")
    return value, noise


def _render(scene, method, spp, res, depth, seed, options):
    # chain methods: one batch (one bootstrap, the longest chains) up to 2^20 mutations (the
    # driver's memory guard counts a batch's paths), independent batches of that size beyond
    kw = dict(batch_spp=min(spp, max(1, CHAIN_BATCH // (res * res)))) if method in ("mmlt", "pssmlt") else {}
    return render(scene, method=method, spp=spp, res=res, rng=seed, max_depth=depth, progress=False, **kw,
                  **options)


def calibrate(scene, method, res, depth, seconds, options):
    """spp that takes about ``seconds``: pilots doubling the spp until one takes a third of it (a
    chain method's bootstrap has a floor, ``n_bootstrap >= chains``, that a shorter pilot overweights),
    then the time per spp of the last two pilots' difference (that floor cancels)."""
    spp, last = 16, None
    r = _render(scene, method, spp, res, depth, 1, options)
    while r.seconds < seconds / 3 and spp < 1 << 16:
        last = (spp, r.seconds)
        spp *= 2
        r = _render(scene, method, spp, res, depth, 1, options)
    if last is None or r.seconds <= last[1]:
        return max(1, int(spp * seconds / r.seconds))
    per_spp = (r.seconds - last[1]) / (spp - last[0])
    return max(1, int(spp + (seconds - r.seconds) / per_spp))


def table(scene, name, res, depth, seconds, seeds, rows, ref, noise):
    print(f"\n{'method':>52} {'spp':>6} {'time s':>7} {'MSE':>9} {'MSE x t':>9} {'efficiency':>10} "
          f"{'vs path':>7}  per-seed MSE")
    spps = {label: calibrate(scene, m, res, depth, seconds, o) for label, m, o in rows}
    stats = {label: [] for label, _, _ in rows}
    extras = {}
    for seed in seeds:
        for label, m, o in rows:                         # interleaved
            r = _render(scene, m, spps[label], res, depth, 1000 + seed, o)
            stats[label].append((r.seconds, float(np.mean((r.image - ref) ** 2)) - noise))
            if m == "mmlt":
                extras.setdefault(label, []).append(r.extra)
    out = {}
    for label, _, _ in rows:
        t = np.median([a for a, _ in stats[label]])
        e = np.median([b for _, b in stats[label]])
        out[label] = (spps[label], t, e, 1.0 / (t * e))
    base = out[rows[0][0]][3]
    for label, _, _ in rows:
        spp, t, e, eff = out[label]
        print(f"{label:>52} {spp:>6} {t:>7.2f} {e:>9.3g} {t * e:>9.3g} {eff:>10.3g} {eff / base:>7.2f}  "
              + " ".join(f"{b:.2g}" for _, b in stats[label]))
    for label, ex in extras.items():
        e = ex[0]

        def g(a):
            return "[" + " ".join(f"{v:.3g}" for v in np.asarray(a)) + "]"

        print(f"  {label} (first seed): b_d {g(e['b_depth'])} +- {g(e['b_stderr_depth'])}, chains "
              f"{e['chains_depth'].astype(int)}, acceptance {float(e['acceptance_rate'][0]):.3f}, "
              f"tau {g(e['tau_depth'])} (0: chains shorter than {mmlt.MIN_TAU_STEPS} steps), ESS {g(e['ess_depth'])}")
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--first-seed", type=int, default=0, help="seeds 1000 + first-seed ... (another realisation)")
    ap.add_argument("--res", type=int, default=32)
    ap.add_argument("--depth", type=int, default=mmlt.DEFAULT_MAX_DEPTH)
    ap.add_argument("--ref-spp", type=int, default=32768)
    ap.add_argument("--ref-method", default="path", help="path (default: 2x bdpt's efficiency here) or bdpt")
    ap.add_argument("--slit", type=float, default=20.0)
    ap.add_argument("--center", type=float, default=278.0)
    ap.add_argument("--height", type=float, default=300.0)
    ap.add_argument("--methods", default="path,bdpt,pssmlt,mmlt", help="comma-separated; the first is the baseline")
    ap.add_argument("--mmlt-options", default="{}", help='JSON options of mmlt, e.g. \'{"chains": 4096}\'')
    ap.add_argument("--variants", default=None,
                    help='JSON list of mmlt option dicts run side by side (each a row "mmlt <options>"), e.g. '
                         '\'[{}, {"direct_depth": 2}]\'')
    ap.add_argument("--trade", action="store_true", help="also the chains x sigma table of mmlt")
    args = ap.parse_args()
    print(f"load average before: {os.getloadavg()} on {os.cpu_count()} CPUs")
    scene = load_scene("cornell-door", slit=args.slit, center=args.center, height=args.height)
    name = f"cornell-door-slit{args.slit:g}-center{args.center:g}-height{args.height:g}"
    ref, noise = reference(scene, name, args.res, args.depth, args.ref_spp, method=args.ref_method)
    print(f"== {name} {args.res}x{args.res}, max_depth {args.depth}, {args.seconds:g} s per render, "
          f"{args.seeds} seeds; reference mean {ref.mean():.4g}, its noise {noise:.3g} (subtracted)")
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    rows = []
    for m in args.methods.split(","):
        if m == "mmlt" and args.variants is not None:
            rows += [(f"mmlt {json.dumps(v, separators=(',', ':'))}", m, v) for v in json.loads(args.variants)]
        else:
            rows.append((m, m, json.loads(args.mmlt_options) if m == "mmlt" else {}))
    table(scene, name, args.res, args.depth, args.seconds, seeds, rows, ref, noise)
    if args.trade:
        rows = [("path", "path", {})] + [(f"mmlt chains={c} sigma={s}", "mmlt", dict(chains=c, sigma=s))
                                         for c in (4096, 16384, 65536) for s in (0.003, 0.01, 0.03)]
        table(scene, name, args.res, args.depth, args.seconds, seeds, rows, ref, noise)
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
