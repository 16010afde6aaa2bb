"""Benchmark of the wavefront tracer on the Cornell box (prints figures; not a test).

Run: ``.venv/bin/python benchmarks/bench_render.py [--quick]``

Prints, for the ``path`` and ``direct`` integrators at 64 x 64 and 256 x 256:
camera paths (pixel samples) per second and rays per second (camera,
extension and shadow rays), with float32 and float64 ray geometry and with
1 and 2 worker processes; the peak memory of a 256 x 256 render
(``tracemalloc`` sees NumPy's allocations); MSE x spp against a high-spp
render of our own (constant MSE x spp is the 1/N convergence of an unbiased
estimator); and the top of a cProfile of one render.
"""
from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import os
import tracemalloc

import numpy as np

from mcvar.integrators import PATHS_PER_BATCH, WorkerPool, render
from mcvar.metrics import mse
from mcvar.scene import load_scene


def _rate(scene, integrator, res, spp, repeats, **kw):
    """Best and median paths/s over ``repeats`` renders (the machine may be shared)."""
    render(scene, method=integrator, res=16, spp=1, rng=0, **kw)   # warm-up
    rates, rays = [], []
    for _ in range(repeats):
        r = render(scene, method=integrator, res=res, spp=spp, rng=1, **kw)
        rates.append(res * res * r.spp / r.seconds)
        rays.append(r.rays / (res * res * r.spp))
    return max(rates), float(np.median(rates)), float(np.mean(rays))


def main(quick: bool = False):
    scene = load_scene("cornell")
    print(f"load average before: {os.getloadavg()[0]:.2f} (1 min) on {os.cpu_count()} CPUs")
    repeats = 2 if quick else 5
    print("== throughput (Cornell box, sampler random), best and median of", repeats)
    print(f"{'integrator':>10} {'res':>5} {'spp':>4} {'geometry':>8} {'workers':>7} "
          f"{'paths/s best':>12} {'median':>8} {'rays/s best':>11} {'rays/path':>9}")
    cases = [("path", 64, 16), ("direct", 64, 16), ("path", 256, 4 if quick else 8),
             ("direct", 256, 4 if quick else 8)]
    for integrator, res, spp in cases:
        for precision in ("float32", "float64"):
            for workers in (1, 2):
                if precision == "float64" and workers == 2:
                    continue
                # the same batches for 1 and 2 workers (same image); at least two of them
                bs = max(1, min(spp // 2, PATHS_PER_BATCH // (res * res)))
                # a kept WorkerPool: warm processes over the repeats (workers=2 alone
                # would start a fresh pool for every render)
                with WorkerPool(workers) as pool:
                    best, med, rp = _rate(scene, integrator, res, spp, repeats, precision=precision,
                                          executor=pool if workers > 1 else None, batch_spp=bs)
                print(f"{integrator:>10} {res:>5} {spp:>4} {precision:>8} {workers:>7} "
                      f"{best / 1e6:>10.3f} M {med / 1e6:>6.3f} M {best * rp / 1e6:>9.3f} M {rp:>9.2f}")
    # the general loop (material sort, BSDF method calls) against the trusted
    # Lambertian loop the Cornell box runs by default
    for integrator in ("path", "direct"):
        rates = {fast: _rate(scene, integrator, 64, 16, repeats, kernel="lambertian" if fast else "general")
                 for fast in (True, False)}
        print(f"{integrator:>10} 64x64x16 float32, 1 worker: trusted Lambertian loop "
              f"{rates[True][0] / 1e6:.3f} M (median {rates[True][1] / 1e6:.3f} M), general loop "
              f"{rates[False][0] / 1e6:.3f} M (median {rates[False][1] / 1e6:.3f} M) paths/s")
    print(f"load average after: {os.getloadavg()[0]:.2f}")

    print("\n== peak memory of one 256 x 256 render (tracemalloc, NumPy buffers included)")
    for integrator in ("path", "direct"):
        tracemalloc.start()
        r = render(scene, method=integrator, res=256, spp=4, rng=2)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        print(f"{integrator:>10}: peak {peak / 2**20:.0f} MiB (batches of {256 * 256 * r.batch_spp} paths)")

    print("\n== MSE x spp against a high-spp reference (64 x 64, path, random sampler)")
    ref_spp = 256 if quick else 1024
    ref = render(scene, method="path", res=64, spp=ref_spp, rng=3)
    print(f"reference: {ref_spp} spp in {ref.seconds:.1f} s, image mean {ref.image.mean((0, 1)).round(4)}")
    ref_var = ref.variance.mean() / ref_spp   # the reference's own noise floor, per pixel-channel
    print(f"{'integrator':>10} {'spp':>4} {'MSE':>10} {'MSE x spp':>10} {'(MSE-ref) x spp':>15} {'1/(MSE t)':>10}")
    for integrator in ("path", "direct"):
        if integrator == "direct":
            ref_d = render(scene, method="direct", res=64, spp=ref_spp, rng=4)
            ref_img, floor = ref_d.image, ref_d.variance.mean() / ref_spp
        else:
            ref_img, floor = ref.image, ref_var
        for spp in (1, 4, 16, 64):
            r = render(scene, method=integrator, res=64, spp=spp, rng=10 + spp)
            e = float(mse(ref_img, r.image))
            print(f"{integrator:>10} {spp:>4} {e:>10.5f} {e * spp:>10.4f} {(e - floor) * spp:>15.4f} "
                  f"{1.0 / (e * r.seconds):>10.1f}")

    print("\n== profile: path, 64 x 64, 16 spp (top 12 by own time)")
    prof = cProfile.Profile()
    prof.enable()
    render(scene, method="path", res=64, spp=16, rng=5)
    prof.disable()
    out = io.StringIO()
    pstats.Stats(prof, stream=out).sort_stats("tottime").print_stats(12)
    print("\n".join(line for line in out.getvalue().splitlines() if line.strip())[:4000])


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer samples")
    main(parser.parse_args().quick)
