"""Efficiency of Cornell-box configurations: MSE x time on one 64 x 64, 256-spp image.

Run: ``.venv/bin/python benchmarks/bench_efficiency.py [--quick] [--runs N] [--ref-spp N] [--frontier]``

Efficiency is ``1 / (MSE x time)`` (Veach 1997, sec. 2.4.3; for an unbiased
estimator MSE is its variance). For every configuration (integrator options,
sampler, workers) the script renders the same image ``--runs`` times,
*interleaved* across configurations so that a busy machine slows all of them
alike, and prints the median seconds, paths/s, the MSE against the project's
own high-spp reference (minus the reference's own variance, estimated from
its per-pixel sample variance) and MSE x time. Seconds are the wall time of
the whole call: ``Render.seconds`` leaves out the sample pattern and the
tracer that :func:`~mcvar.integrators.render` builds before its clock starts
(about 0.1 s of a 0.65 s Sobol render). The last line is the ratio of
the best MSE x time to the previous default (``sobol``, 1 worker) and to the
LLVM renderer's figure quoted in issue 14 (3.9e-6 s on a quiet machine).
When Mitsuba 3's ``llvm_ad_rgb`` variant runs here (``mitsuba`` extra and a
libLLVM >= 16, see ``--libllvm``), the same scene rendered by it is measured
in the same interleaved run (``mitsuba_llvm_cornell.py``, its own process,
timed after a warm-up, MSE against the same reference), and the last lines
compare mcvar's best with it.

A configuration is a dict of :func:`mcvar.integrators.render` keywords; with
``adaptive=True`` it runs :func:`mcvar.adaptive.render_adaptive` (the same
total work, pilot included). ``--frontier`` renders every configuration at
several spp and saves the MSE-against-seconds plot (log-log) that
docs/performance.md shows.

The reference (``path``, random sampler, Russian roulette) is cached in
``.mcvar-cache/`` (git-ignored); the default 65,536 spp (its own variance
1.7e-6, below the best configurations' MSE) takes about two minutes on two
quiet cores.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mcvar.adaptive import render_adaptive
from mcvar.integrators import render
from mcvar.scene import load_scene

#: MSE x time of Mitsuba 3 (LLVM, multi-jitter, 2 threads) on this machine kind,
#: quiet machine, from issue 14.
LLVM_BEST = 3.9e-6

#: name -> render keywords. The first is the previous default of ``render``.
CONFIGS = {
    "sobol, 1 worker (previous default)": dict(sampler="sobol", workers=1),
    "random, 1 worker": dict(sampler="random", workers=1),
    "sobol, exact light, 1 worker": dict(sampler="sobol", workers=1, visible_lights="exact"),
    "sobol, tiles, 2 workers": dict(sampler="sobol", adaptive=True, pilot_spp=0, rr_depth=None, workers=2,
                                    visible_lights="sampled", rr_threshold=1.0),
    "random, adaptive": dict(sampler="random", adaptive=True),
    "sobol, adaptive, sampled light, rr 7, 2 workers (previous mcvar render)":
        dict(sampler="sobol", adaptive=True, workers=2, visible_lights="sampled", rr_threshold=1.0, rr_depth=7),
    "sobol, adaptive, exact light, rr 7, 2 workers":
        dict(sampler="sobol", adaptive=True, workers=2, rr_threshold=1.0, rr_depth=7),
    "sobol, adaptive, exact light, window 0.1, 2 workers": dict(sampler="sobol", adaptive=True, workers=2,
                                                                rr_threshold=0.1),
    "sobol, adaptive, 1 worker": dict(sampler="sobol", adaptive=True),
    "sobol, adaptive, 2 workers (mcvar render)": dict(sampler="sobol", adaptive=True, workers=2),
}
#: The configuration ``mcvar render`` uses by default (see docs/performance.md):
#: adaptive Sobol', the light's pixels exact, roulette with the window 0.2.
BEST = "sobol, adaptive, 2 workers (mcvar render)"

#: Optional configurations: Mitsuba 3's LLVM variant on the same scene
#: (benchmarks/mitsuba_llvm_cornell.py), name -> its sampler plugin. Skipped
#: when Mitsuba or a libLLVM it can use is missing (``--libllvm`` sets
#: ``DRJIT_LIBLLVM_PATH``; drjit 1.5 needs LLVM >= 16 on x86: 14 and 15
#: fail with 'Cannot select ... fminimum').
MITSUBA = {
    "Mitsuba 3 LLVM, multijitter, 2 threads": "multijitter",
    "Mitsuba 3 LLVM, ldsampler, 2 threads": "ldsampler",
    "Mitsuba 3 LLVM, orthogonal, 2 threads": "orthogonal",
    "Mitsuba 3 LLVM, stratified, 2 threads": "stratified",
    "Mitsuba 3 LLVM, independent, 2 threads": "independent",
}
_MITSUBA_SCRIPT = Path(__file__).resolve().with_name("mitsuba_llvm_cornell.py")


def run_mitsuba(sampler, spp, res, seed, libllvm=None):
    """``(image, seconds)`` of one Mitsuba LLVM render, timed inside its own process
    after a warm-up; ``None`` if Mitsuba's LLVM variant does not run here."""
    env = dict(os.environ, PYTHONPATH=str(_MITSUBA_SCRIPT.parents[1]))
    if libllvm:
        env["DRJIT_LIBLLVM_PATH"] = libllvm
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "mitsuba.npz"
        p = subprocess.run([sys.executable, str(_MITSUBA_SCRIPT), str(out), "--spp", str(spp), "--res", str(res),
                            "--runs", "1", "--seed", str(seed), "--sampler", sampler],
                           env=env, capture_output=True, text=True)
        if p.returncode != 0 or not out.is_file():
            return None
        with np.load(out) as d:
            return d["images"][0], float(d["seconds"][0])


def check_reference(scene, res: int, spp: int, cache: Path, ref, ref_var) -> None:
    """Print how the exact-light reference agrees with a sampled one of the same
    spp (``--check-reference`` renders it if it is not cached): per-pixel z
    scores, their chi-square over pixels and channels, and the largest |z|."""
    from scipy import stats

    # its own seed: the reference's seed would make the two renders share their paths
    path = cache / f"bench-efficiency-{scene.name}-{res}-{spp}-sampled-check.npz"
    if path.is_file():
        with np.load(path) as d:
            other, other_var = d["image"], d["variance"]
    else:
        r = render(scene, method="path", spp=spp, res=res, sampler="random", rng=54321, workers=2,
                   progress=True)
        other, other_var = r.image, r.variance / r.spp
        np.savez(path, image=other, variance=other_var)
    var = ref_var + other_var
    ok = var > 0
    z = (ref - other)[ok] / np.sqrt(var[ok])
    chi2 = float(np.sum(z * z))
    p = float(stats.chi2.sf(chi2, z.size))
    print(f"reference check: exact-light against sampled ({spp} spp each): chi-square {chi2:.0f} on {z.size} "
          f"dof (p = {p:.3f}), max |z| {np.abs(z).max():.2f}; means {ref.mean():.5f} / {other.mean():.5f}")


def run(scene, **kw):
    """One render of configuration ``kw`` (``adaptive=True``: :func:`render_adaptive`, that is
    ``render(..., allocation=Adaptive(...))`` with the adaptive path settings)."""
    kw = dict(kw)
    if kw.pop("adaptive", False):
        return render_adaptive(scene, **kw)
    return render(scene, **kw)


def reference(scene, res: int, spp: int, cache: Path):
    """``(image, variance of the image per pixel)`` of a random-sampler render, cached.

    The light's directly seen emission is its exact pixel integral
    (``visible_lights="exact"``): sampled, the light's 44 edge pixels held
    92% of a 65,536-spp reference's variance (a Bernoulli 17-or-0.2 per
    sample), so that the MSE of the best configurations was smaller than the
    reference's own noise. ``check_reference`` compares it with a sampled
    reference of the same spp, pixel by pixel.
    """
    path = cache / f"bench-efficiency-{scene.name}-{res}-{spp}-exact.npz"
    if path.is_file():
        with np.load(path) as d:
            return d["image"], d["variance"]
    t = time.perf_counter()
    r = render(scene, method="path", spp=spp, res=res, sampler="random", rng=12345, workers=2,
               progress=True, visible_lights="exact")
    cache.mkdir(parents=True, exist_ok=True)
    np.savez(path, image=r.image, variance=r.variance / r.spp)
    print(f"reference: {spp} spp in {time.perf_counter() - t:.0f} s")
    return r.image, r.variance / r.spp


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 runs, 2048-spp reference")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--ref-spp", type=int, default=65536)
    ap.add_argument("--only", default="", help="semicolon-separated substrings of configuration names")
    ap.add_argument("--frontier", action="store_true",
                    help="MSE against seconds at several spp per configuration; saves docs/performance-frontier.png")
    ap.add_argument("--spps", default="32,64,128,256,512", help="spp levels of --frontier")
    ap.add_argument("--no-mitsuba", action="store_true", help="skip the Mitsuba LLVM configurations")
    ap.add_argument("--check-reference", action="store_true",
                    help="compare the exact-light reference with a sampled one of the same spp (rendered once)")
    ap.add_argument("--libllvm", default=os.environ.get("DRJIT_LIBLLVM_PATH"),
                    help="path of a libLLVM (>= 16) for Mitsuba's LLVM variant")
    args = ap.parse_args(argv)
    runs = 2 if args.quick else args.runs
    ref_spp = 2048 if args.quick else args.ref_spp
    scene = load_scene("cornell")
    ref, ref_var = reference(scene, args.res, ref_spp, Path(".mcvar-cache"))
    if args.check_reference:
        check_reference(scene, args.res, ref_spp, Path(".mcvar-cache"), ref, ref_var)
    floor = float(ref_var.mean())
    configs = {k: v for k, v in CONFIGS.items()
               if not args.only or any(s in k for s in args.only.split(";"))}
    load0 = os.getloadavg()
    print(f"load average {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f} on {os.cpu_count()} CPUs (a shared "
          f"machine: absolute seconds are loaded-machine figures; ratios within one run are what count); "
          f"reference {ref_spp} spp, its own variance {floor:.2e} is subtracted from every MSE")
    for kw in configs.values():                       # warm-up (pools, caches)
        run(scene, spp=16, res=16, rng=0, **kw)
    mitsuba = {}
    if not args.no_mitsuba and not args.frontier:
        for name, sampler in MITSUBA.items():
            if any(s in name for s in args.only.split(";")) or not args.only:
                if run_mitsuba(sampler, 16, 16, 0, args.libllvm) is None:
                    print(f"{name}: skipped (Mitsuba's llvm_ad_rgb variant did not run; see --libllvm)")
                else:
                    mitsuba[name] = sampler
    if args.frontier:
        frontier(scene, configs, ref, floor, args.res, runs, tuple(int(x) for x in args.spps.split(",")), ref_spp)
        return
    names = list(configs) + list(mitsuba)
    secs = {k: [] for k in names}
    errs = {k: [] for k in names}
    spent = {k: [] for k in names}
    for rep in range(runs):
        for name, sampler in mitsuba.items():        # its own process, timed inside it
            got = run_mitsuba(sampler, args.spp, args.res, 1000 + rep, args.libllvm)
            if got is None:
                raise RuntimeError(f"{name} failed after its warm-up succeeded")
            secs[name].append(got[1])
            spent[name].append(args.spp)
            errs[name].append(float(np.mean((got[0] - ref) ** 2)) - floor)
        for name, kw in configs.items():
            t0 = time.perf_counter()
            r = run(scene, spp=args.spp, res=args.res, rng=1000 + rep, **kw)
            secs[name].append(time.perf_counter() - t0)     # the whole call: Render.seconds
            # leaves out what render() does before its clock starts (the
            # sample pattern, the tracer's build)
            spent[name].append(r.spp)
            errs[name].append(float(np.mean((r.image - ref) ** 2)) - floor)
    load1 = os.getloadavg()
    print(f"\n{'configuration':<40} {'seconds':>8} {'paths/s':>9} {'MSE':>9} {'MSE x time':>11}")
    rows = {}
    for name in names:
        t = float(np.median(secs[name]))
        e = float(np.mean(errs[name]))
        se = float(np.std(errs[name], ddof=1) / np.sqrt(runs)) if runs > 1 else float("nan")
        rows[name] = e * t
        paths = args.res ** 2 * float(np.mean(spent[name]))
        print(f"{name:<40} {t:>8.3f} {paths / t / 1e6:>7.2f} M {e:>9.2e} "
              f"{e * t:>11.2e}   (MSE +- {se:.1e}; seconds {min(secs[name]):.3f}-{max(secs[name]):.3f})")
    print(f"load average at the end {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}; median of {runs} interleaved runs")
    ours = {k: rows[k] for k in configs}
    best = min(ours, key=ours.get)
    base = next(iter(CONFIGS))
    if base in rows:
        print(f"\nbest: {best}: MSE x time {rows[best]:.2e} s; {rows[base] / rows[best]:.2f}x the previous "
              f"default's ({rows[base]:.2e} s, same run); LLVM renderer {LLVM_BEST:.1e} s (quiet machine, issue 14): "
              f"ratio {LLVM_BEST / rows[best]:.2f}")
    for name in mitsuba:
        print(f"{name} in the same run: MSE x time {rows[name]:.2e} s; mcvar's best is "
              f"{rows[name] / rows[best]:.2f}x as efficient (> 1: mcvar ahead)")


def frontier(scene, configs, ref, floor, res, runs, spps, ref_spp):
    """Median seconds and mean MSE per configuration and spp (interleaved), plotted log-log."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = {k: {s: ([], []) for s in spps} for k in configs}
    for rep in range(runs):
        for spp in spps:
            for name, kw in configs.items():
                t0 = time.perf_counter()
                r = run(scene, spp=spp, res=res, rng=5000 + rep, **kw)
                out[name][spp][0].append(time.perf_counter() - t0)
                out[name][spp][1].append(float(np.mean((r.image - ref) ** 2)) - floor)
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    for name, by_spp in out.items():
        t = [float(np.median(by_spp[s][0])) for s in spps]
        e = [float(np.mean(by_spp[s][1])) for s in spps]
        print(name, " ".join(f"{s}:{ti:.3f}s/{ei:.2e}" for s, ti, ei in zip(spps, t, e)))
        ax.loglog(t, e, "o-", label=name)
    for c in (1e-6, 1e-5, 1e-4):
        tt = np.geomspace(0.02, 10, 10)
        ax.loglog(tt, c / tt, ":", color="0.7", lw=0.8)
    ax.set_xlabel("seconds (median, shared machine)")
    ax.set_ylabel(f"MSE against the {ref_spp}-spp reference")
    ax.set_title(f"Cornell box {res}x{res}, {spps[0]}-{spps[-1]} spp, shared machine (load average "
                 f"{os.getloadavg()[0]:.1f}); dotted: MSE x time = 1e-6, 1e-5, 1e-4 s", fontsize=8)
    ax.legend(fontsize=7)
    fig.tight_layout()
    path = Path(__file__).resolve().parents[1] / "docs" / "performance-frontier.png"
    fig.savefig(path, dpi=110)
    print(f"saved {path}; load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
