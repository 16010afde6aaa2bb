"""Figures of issue 13 (prints markdown tables; not a test).

Run: ``PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_global_illumination.py [section ...]``
with sections ``radiosity``, ``photon``, ``sppm``, ``caustics`` (default: all).

* radiosity: the Cornell box at patch sizes 280 .. 20: patches, rays, time,
  Jacobi iterations, image-mean error and the MSE against a path-traced
  reference (pixels that see the light masked: their value is set by pixel
  sampling, not by transport).
* photon: squared bias, variance and MSE per pixel of the photon-map
  estimate against path tracing for the same camera rays, at fixed radii
  and k; peak memory of a photon map.
* sppm: MSE and squared bias vs iterations over replicates, fitted slope.
* caustics: ``cornell-spheres`` at about equal time: path, photon, sppm
  against a long path-traced reference, whole image and the caustic below
  the glass sphere.
"""
from __future__ import annotations

import sys
import time
import tracemalloc

import numpy as np
from scipy import stats
from scipy.ndimage import binary_dilation

from mcvar.integrators import render, trace_paths
from mcvar.integrators.photon import build_photon_map, photon_map_radiance, visible_points
from mcvar.integrators.sppm import sppm
from mcvar.integrators.radiosity import radiosity
from mcvar.scene import load_scene
from mcvar.tracer import Tracer


def _camera_rays(scene, res, spp, rng):
    pix = np.repeat(np.arange(res * res), spp)
    d = scene.camera.ray_directions((res, res), pix, rng.random((pix.size, 2)))
    return np.broadcast_to(scene.camera.position, d.shape), d


def _light_mask(scene, tracer, res):
    g = (np.arange(8) + 0.5) / 8
    off = np.tile(np.stack(np.meshgrid(g, g), -1).reshape(-1, 2), (res * res, 1))
    d = scene.camera.ray_directions((res, res), np.repeat(np.arange(res * res), 64), off)
    h = tracer.intersect(np.broadcast_to(scene.camera.position, d.shape), d)
    lit = ((h.prim >= 0) & (scene.prim_emission[h.prim].sum(1) > 0)).reshape(-1, 64).any(1)
    return binary_dilation(lit.reshape(res, res))


def _moments(x, ref, ref_var):
    r = x.shape[0]
    s2 = x.var(axis=0, ddof=1)
    b = x.mean(axis=0) - ref
    bias2 = np.mean(b * b - s2 / r - ref_var)
    return np.array([bias2, s2.mean(), s2.mean() + bias2])


def _jack(x, ref, ref_var):
    r = x.shape[0]
    jack = np.array([_moments(np.delete(x, i, 0), ref, ref_var) for i in range(r)])
    return _moments(x, ref, ref_var), np.sqrt((r - 1) / r * ((jack - jack.mean(0)) ** 2).sum(0))


def bench_radiosity():
    scene = load_scene("cornell")
    tracer = Tracer(scene)
    res, spp = 32, 16
    ref = render(scene, spp=1024, res=res, rng=11)
    keep = ~_light_mask(scene, tracer, res).ravel()
    o, d = _camera_rays(scene, res, spp, np.random.default_rng(12))
    print("\n### Radiosity on cornell (32 x 32, 16 first-hit samples per pixel, path reference 1024 spp)\n")
    print("| patch size | patches | sides | rays | seconds | Jacobi its | image mean rel. error (R, G, B) | MSE |")
    print("|---|---|---|---|---|---|---|---|")
    rv = (ref.variance.reshape(-1, 3) / ref.spp)[keep]
    rp = ref.image.reshape(-1, 3)[keep]
    for size in (280.0, 140.0, 70.0, 35.0, 20.0):
        sol = radiosity(scene, patch_size=size, rng=13, tracer=tracer)
        img = sol.radiance(scene, tracer, o, d).reshape(res * res, spp, 3).mean(1)[keep]
        mse = float(np.mean((img - rp) ** 2 - rv))
        rel = img.mean(0) / rp.mean(0) - 1
        print(f"| {size:g} | {sol.patches.n} | {2 * sol.patches.n} | {sol.form_factors.rays} | "
              f"{sol.seconds:.2f} | {sol.iterations} | {', '.join(f'{v:+.2%}' for v in rel)} | {mse:.3g} |")


def bench_photon():
    scene = load_scene("cornell")
    tracer = Tracer(scene)
    rng = np.random.default_rng(21)
    res, spp, k = 16, 4, 256
    o, d = _camera_rays(scene, res, spp, rng)
    rad, _ = trace_paths(scene, np.repeat(o, k, 0), np.repeat(d, k, 0), rng.random((o.shape[0] * k, 4)),
                         rng=rng, tracer=tracer)
    rad = rad.reshape(-1, k, 3)
    ref, ref_var = rad.mean(1), rad.var(1, ddof=1) / k
    vp = visible_points(scene, tracer, o, d, rng=22)
    keep = vp.emitted.sum(1) == 0
    tracemalloc.start()
    t = time.perf_counter()
    big = build_photon_map(scene, 1 << 18, rng=23, tracer=tracer)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    print(f"\nPhoton map of 2^18 = {1 << 18} emitted photons: {big.photons.n} stored, "
          f"{big.nbytes / 2 ** 20:.1f} MiB of photon arrays, peak {peak / 2 ** 20:.1f} MiB while "
          f"building (tracemalloc), {time.perf_counter() - t:.2f} s")
    maps = [build_photon_map(scene, 1 << 15, rng=s, tracer=tracer) for s in np.random.default_rng(24).spawn(6)]
    print("\n### Photon map on cornell (6 maps of 2^15 photons, 16 x 16 x 4 camera rays, per-ray path reference)\n")
    print("| gather | squared bias | variance | MSE |")
    print("|---|---|---|---|")
    for kw in (dict(radius=60.0), dict(radius=40.0), dict(radius=20.0), dict(radius=10.0), dict(radius=5.0),
               dict(k=800), dict(k=200), dict(k=50)):
        x = np.array([photon_map_radiance(scene, pm, vp, **kw)[keep].ravel() for pm in maps])
        (b2, var, mse), (sb2, svar, smse) = _jack(x, ref[keep].ravel(), ref_var[keep].ravel())
        name = ", ".join(f"{a} = {v:g}" for a, v in kw.items())
        print(f"| {name} | {b2:.3g} ± {sb2:.2g} | {var:.3g} | {mse:.3g} ± {smse:.2g} |")


def bench_sppm():
    scene = load_scene("cornell")
    tracer = Tracer(scene)
    res = 16
    ref = render(scene, spp=2048, res=res, rng=31)
    keep = ~_light_mask(scene, tracer, res)
    rp, rv = ref.image[keep].ravel(), (ref.variance / ref.spp)[keep].ravel()
    R, iters = 8, (1, 2, 4, 8, 16, 32)
    for r0 in (50.0, None):
        snaps = np.zeros((R, len(iters), rp.size))
        t = time.perf_counter()
        for r, stream in enumerate(np.random.default_rng(32).spawn(R)):
            def cb(i, img, r=r):
                if i in iters:
                    snaps[r, iters.index(i)] = img[keep].ravel()
            out = sppm(scene, res=res, iterations=iters[-1], photons_per_iteration=1 << 12, radius=r0,
                       rng=stream, tracer=tracer, callback=cb)
        sec = (time.perf_counter() - t) / R
        print(f"\n### SPPM on cornell, initial radius {r0 or 'default (9.6)'}: {R} runs of {iters[-1]} "
              f"iterations x 4096 photons, {sec:.1f} s per run, final mean radius {out.radius.mean():.1f}, "
              f"peak photons held {out.peak_photons}\n")
        print("| iterations | squared bias (t) | MSE |")
        print("|---|---|---|")
        mses = []
        for k, i in enumerate(iters):
            (b2, _, mse), (sb2, _, smse) = _jack(snaps[:, k], rp, rv)
            mses.append(mse)
            print(f"| {i} | {b2:.3g} ± {sb2:.2g} ({b2 / sb2:.1f}) | {mse:.3g} ± {smse:.2g} |")
        fit = stats.linregress(np.log(iters), np.log(mses))
        print(f"\nlog-log MSE slope {fit.slope:.2f} ± {fit.stderr:.2f}")


def bench_caustics(seconds: float = 6.0, ref_spp: int = 16384):
    scene = load_scene("cornell-spheres")
    tracer = Tracer(scene)
    res = 32
    t = time.perf_counter()
    ref = render(scene, spp=ref_spp, res=res, rng=41, workers=2)
    ref_noise = ref.variance / ref.spp
    print(f"\n### Caustics on cornell-spheres, 32 x 32, about {seconds:g} s each "
          f"(reference: path, {ref_spp} spp, {time.perf_counter() - t:.0f} s on 2 processes; "
          f"MSE = mean squared difference minus the reference's variance)\n")
    keep = ~_light_mask(scene, tracer, res)
    # the caustic: floor pixels within 160 units of the glass sphere's contact point
    d = scene.camera.ray_directions((res, res), np.arange(res * res), np.full((res * res, 2), 0.5))
    h = tracer.intersect(np.broadcast_to(scene.camera.position, d.shape), d)
    p = scene.camera.position + h.t[:, None] * d
    floor = (h.prim >= 0) & (h.prim < 2)
    caustic = (floor & (np.hypot(p[:, 0] - 180.0, p[:, 2] - 170.0) < 160.0)).reshape(res, res) & keep
    rows = []
    probe = render(scene, spp=16, res=res, rng=42)
    spp = max(1, int(seconds / probe.seconds * 16))
    r = render(scene, spp=spp, res=res, rng=43)
    rows.append(("path", f"{spp} spp", r.seconds, r.image))

    def photon_run(n_ph, rng):
        t0 = time.perf_counter()
        o, dd = _camera_rays(scene, res, 16, np.random.default_rng(rng))
        pm = build_photon_map(scene, n_ph, rng=rng + 1, tracer=tracer)
        vp = visible_points(scene, tracer, o, dd, rng=rng + 2)
        img = photon_map_radiance(scene, pm, vp, k=100).reshape(res * res, 16, 3).mean(1).reshape(res, res, 3)
        return time.perf_counter() - t0, img

    sec, _ = photon_run(1 << 16, 44)
    n_ph = int((1 << 16) * seconds / sec)
    sec, img = photon_run(n_ph, 45)
    rows.append(("photon", f"{n_ph} photons, k = 100, 16 spp", sec, img))
    probe = sppm(scene, res=res, iterations=2, photons_per_iteration=1 << 14, rng=47, tracer=tracer)
    its = max(2, int(seconds / probe.seconds * 2))
    out = sppm(scene, res=res, iterations=its, photons_per_iteration=1 << 14, rng=48, tracer=tracer)
    rows.append(("sppm", f"{its} iterations x 16384 photons", out.seconds, out.image))
    print("| method | work | seconds | MSE (image) | MSE x time | MSE (caustic) | caustic mean / reference |")
    print("|---|---|---|---|---|---|---|")
    for name, work, sec, img in rows:
        e = ((img - ref.image) ** 2 - ref_noise)[keep]
        ec = ((img - ref.image) ** 2 - ref_noise)[caustic]
        print(f"| {name} | {work} | {sec:.1f} | {np.mean(e):.3g} | {np.mean(e) * sec:.3g} | "
              f"{np.mean(ec):.3g} | {img[caustic].mean() / ref.image[caustic].mean():.3f} |")
    return rows, ref.image


SECTIONS = {"radiosity": bench_radiosity, "photon": bench_photon, "sppm": bench_sppm, "caustics": bench_caustics}

if __name__ == "__main__":
    for name in sys.argv[1:] or list(SECTIONS):
        SECTIONS[name]()
