"""Benchmark: every sampler at n = 10^6 (or the largest sane n), every discrepancy at n = 4096.

Prints seconds (best of ``--repeat`` runs, one core) and, where scipy computes the same
measure, the time ratio mcvar / scipy. Not part of the test run::

    .venv/bin/python benchmarks/bench_sampling.py [--repeat 3] [--n 1000000]
"""
from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
from scipy.stats import qmc

from mcvar import discrepancy as D
from mcvar import samplers as S


def best_time(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--n", type=int, default=1_000_000, help="points per sampler (default 10^6)")
    parser.add_argument("--n-disc", type=int, default=4096, help="points for the discrepancies")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(20_240_601)

    print(f"== samplers at n = {args.n} (grid/jittered: {1000 ** 2}; blue_noise: 2^17)")
    print(f"{'sampler':16s} {'n':>9s} {'seconds':>9s} {'Mpoints/s':>10s}")
    sizes = {"grid": 1000 ** 2, "jittered": 1000 ** 2, "blue_noise": 2 ** 17, "sobol": 2 ** 20}
    for name, fn in S.SAMPLERS.items():
        n = sizes.get(name, args.n) if args.n == 1_000_000 else args.n
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            t = best_time(lambda: fn(n, rng=rng), 1 if name == "blue_noise" else args.repeat)
        print(f"{name:16s} {n:9d} {t:9.3f} {n / t / 1e6:10.2f}")
    for extra, call in [("pixel_samples sobol 256^2 px x 64 spp x 4 dim",
                         lambda: S.pixel_samples("sobol", 256 * 256, 64, dim=4, rng=rng)),
                        ("pixel_samples multi_jittered 256^2 x 64 x 4",
                         lambda: S.pixel_samples("multi_jittered", 256 * 256, 64, dim=4, rng=rng))]:
        print(f"{extra}: {best_time(call, args.repeat):.3f} s")

    n = args.n_disc
    pts = S.random(n, rng=rng)
    print(f"\n== discrepancies at n = {n} (random points)")
    print(f"{'measure':14s} {'mcvar s':>9s} {'scipy s':>9s} {'mcvar/scipy':>12s}")
    scipy_method = {"l2_star": "L2-star", "centered": "CD", "wrap_around": "WD", "mixture": "MD"}
    for name, fn in D.DISCREPANCIES.items():
        t = best_time(lambda: fn(pts), args.repeat)
        if name in scipy_method:
            ts = best_time(lambda: qmc.discrepancy(pts, method=scipy_method[name]), args.repeat)
            print(f"{name:14s} {t:9.3f} {ts:9.3f} {t / ts:12.2f}")
        else:
            print(f"{name:14s} {t:9.3f} {'-':>9s} {'(no scipy)':>12s}")
    for fam in ("anchored", "boxes", "disks"):
        t = best_time(lambda: D.local(pts, fam), args.repeat)
        print(f"local {fam:8s} {t:9.3f} {'-':>9s} {'(no scipy)':>12s}")
    t = best_time(lambda: D.power_spectrum(pts), args.repeat)
    print(f"power_spectrum {t:9.3f} {'-':>9s} {'(K = 128)':>12s}")
    t = best_time(lambda: D.is_net(S.sobol(n, rng=rng), 12), args.repeat)
    print(f"is_net         {t:9.3f}")


if __name__ == "__main__":
    main()
