"""Speed across scenes: ``mcvar render``'s default beside Mitsuba 3 LLVM on a suite (issue 27).

Run::

    python benchmarks/bench_suite.py            # rounds x seeds, ~25 min on a quiet 2-core machine
    python benchmarks/bench_suite.py --quick    # 1 round x 3 seeds, short references: a smoke run
    python benchmarks/bench_suite.py --no-mitsuba --no-triangles   # mcvar only, the four cases

The four cases of issue 27 (the Cornell box at 64 x 64 and 128 x 128 with 256
spp and at 256 x 256 with 64 spp; ``cornell-spheres`` at 64 x 64 with 256 spp),
each rendered by

- **mcvar's default**: what ``mcvar render`` runs (:func:`mcvar.adaptive.render_adaptive`,
  sampler ``sobol``, the workers of ``mcvar render``: :func:`mcvar.cli._adaptive_workers`);
- **mcvar plain**: ``render(scene, spp=..., res=..., sampler='sobol')``;
- **Mitsuba 3 LLVM** (``llvm_ad_rgb``): the scene exported by
  :func:`mcvar.interop.mitsuba.to_mitsuba`, ``path`` with ``max_depth = -1`` and
  ``rr_depth = 5``, a box filter, 2 threads, with each of the samplers
  ``independent``, ``multijitter`` and ``ldsampler``; the best of the three
  (lowest MSE x time) is the row compared.

How it is measured
------------------
- Each engine runs in **its own subprocess** (``--worker``), which renders the
  case once unmeasured (imports, JIT compilation, kernel caches, pools) and
  then one image per seed, each timed as the wall time of the whole call.
- **Interleaved**: every round runs every case and engine once, each with
  ``--seeds`` fresh seeds, so that a change of the machine's load touches all
  of them alike. Seconds are medians over rounds x seeds; the MSE is the mean
  over the same images (the median of a skewed error would be biased low).
- The **reference** of each case is Mitsuba 3 (``llvm_ad_rgb``, else
  ``scalar_rgb``, else mcvar's own ``path`` with the random sampler), the sum
  of ``K`` independent renders (``multijitter``, fresh seeds), cached in
  ``.mcvar-cache/``. Its own per-pixel variance of the mean, the chunks'
  sample variance over ``K``, is the **floor**: ``E[mean((x - ref)^2)] =
  MSE(x) + mean(var(ref))`` for an image ``x`` independent of the reference,
  so every MSE is the measured one minus the floor
  (:func:`mse_minus_floor`). Its default budget is 2^25 paths per case
  (8,192 spp at 64 x 64, 512 at 256 x 256; a larger cached one is used
  when there is one): less than the issue's 65,536 spp, and the floor is
  subtracted instead.
- **Agreement first**: each engine's image mean (per channel, over its
  rounds x seeds images) against the reference's, as a z-score with the
  standard error of both (:func:`mean_z_scores`); a case where an engine
  disagrees by more than 5 sigma is flagged in the table.
- The **ratio** of a case is Mitsuba's best MSE x time over mcvar's default's
  (> 1: mcvar ahead); the geometric mean over the cases is printed last.

The **triangle-count series**: the Cornell box with every non-emitting
triangle cut into ``k^2`` pieces (:func:`mcvar.tessellate.subdivide`, the same
image) from 32 to 100,922 triangles (issue 27's 100k point), mcvar's default and plain (paths per
second of the render, without the tracer's build, and of the whole call) and
Mitsuba (``multijitter``, its load not timed) at 64 x 64 and 32 spp, relative
to the box, ``--triangle-rounds`` rounds of ``--triangle-seeds`` renders per point
(medians over all); saved as a log-log plot (``docs/performance-suite-triangles.png``).

Outputs: ``out/bench-suite/suite.csv``, ``suite.md`` (the markdown table),
``triangles.csv``, and the plot (``--quick`` puts it in ``out/bench-suite/``). Mitsuba is optional: without it, or without
a libLLVM >= 16 for its LLVM variant (drjit 1.5 fails with LLVM 14 and 15,
'Cannot select ... fminimum'; ``--libllvm`` or ``DRJIT_LIBLLVM_PATH``, else
the newest ``libLLVM*.so*`` of version >= 16 found in the usual folders), its
rows are skipped with a message saying why.
"""
from __future__ import annotations

import argparse
import csv
import glob
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / ".mcvar-cache"
OUT = ROOT / "out" / "bench-suite"
PLOT = ROOT / "docs" / "performance-suite-triangles.png"


@dataclass(frozen=True)
class Case:
    """One image of the suite: a scene, its resolution and samples per pixel."""

    scene: str
    res: int
    spp: int

    @property
    def name(self) -> str:
        return f"{self.scene} {self.res}x{self.res}, {self.spp} spp"

    @property
    def paths(self) -> int:
        return self.res * self.res * self.spp


#: The four cases of issue 27.
CASES = (Case("cornell", 64, 256), Case("cornell", 128, 256), Case("cornell", 256, 64),
         Case("cornell-spheres", 64, 256))
#: Mitsuba's samplers; the best of them (lowest MSE x time) per case is the one compared.
MITSUBA_SAMPLERS = ("independent", "multijitter", "ldsampler")
#: mcvar's configurations: the default of ``mcvar render`` and plain ``render``.
MCVAR = ("mcvar default", "mcvar plain")
#: Reference: paths per case, the sampler and the largest wavefront of one chunk
#: (pixels x spp of one ``mi.render`` call: Mitsuba holds the whole wavefront in memory).
REF_PATHS = 2 ** 25
REF_SAMPLER = "multijitter"
REF_CHUNK_LANES = 2 ** 22
#: Subdivision levels of the triangle-count series (32 ... 100,922 triangles: k = 58 is issue 27's 100k point) and its image.
TRIANGLE_KS = (1, 2, 4, 8, 16, 32, 56, 58)
TRIANGLE_RES, TRIANGLE_SPP = 64, 32
#: |z| of an image mean against the reference beyond which an engine is flagged.
Z_FLAG = 5.0


# ---------------------------------------------------------------------------
# the statistics (tested in tests/test_bench_suite.py)

def reference_from_chunks(chunks) -> tuple[np.ndarray, np.ndarray]:
    """``(mean, variance of the mean)`` per pixel of ``K`` independent renders ``(K, H, W, 3)``.

    The variance of the mean is the chunks' sample variance (``ddof = 1``)
    over ``K``: unbiased for any sampler whose renders are independent
    randomizations (fresh seeds), QMC included.
    """
    c = np.asarray(chunks, dtype=np.float64)
    if c.ndim < 2 or c.shape[0] < 2:
        raise ValueError(f"chunks must hold at least 2 independent renders along axis 0; got shape {c.shape}")
    k = c.shape[0]
    return c.mean(axis=0), c.var(axis=0, ddof=1) / k


def mse_minus_floor(image, reference, reference_var) -> float:
    """MSE of ``image`` against the truth, estimated with a noisy ``reference``.

    For ``image`` independent of ``reference``, ``E[mean((image - ref)^2)] =
    MSE(image) + mean(var(ref))``: the mean of ``reference_var`` (the
    reference's per-pixel variance of the mean) is subtracted. Unbiased;
    it can come out negative when the image is better than the floor's noise.
    """
    image = np.asarray(image, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64)
    reference_var = np.asarray(reference_var, dtype=np.float64)
    if image.shape != reference.shape or reference_var.shape != reference.shape:
        raise ValueError(f"image {image.shape}, reference {reference.shape} and reference_var "
                         f"{reference_var.shape} must have one shape")
    if not (np.all(np.isfinite(image)) and np.all(np.isfinite(reference)) and np.all(reference_var >= 0)):
        raise ValueError("image and reference must be finite and reference_var finite and >= 0")
    return float(np.mean((image - reference) ** 2) - np.mean(reference_var))


def mean_z_scores(images, reference, reference_var, reference_dof: float = math.inf) -> np.ndarray:
    """Per channel, the z-score of the mean image mean of ``images`` ``(n, H, W, 3)`` against the reference's.

    The standard error of the images' side is the spread of their ``n`` image
    means (exact for any sampler: the images are independent, but known only
    to ``n - 1`` degrees of freedom), the reference's is
    ``sqrt(sum(reference_var)) / pixels`` (its pixels are independent; its
    variance estimated with ``reference_dof`` degrees of freedom, the chunks
    minus one). The difference over the combined standard error is Welch's
    ``t`` (Welch-Satterthwaite degrees of freedom); it is returned as the
    normal quantile of the same two-sided p-value, so that ``|z| > 5`` means
    what it means for a normal variable even with 3 images (``t`` with 2
    degrees of freedom exceeds 12 in 0.7 % of cases).
    """
    from scipy import stats

    images = np.asarray(images, dtype=np.float64)
    if images.ndim != 4 or images.shape[0] < 2:
        raise ValueError(f"images must be (n >= 2, H, W, C); got shape {images.shape}")
    means = images.mean(axis=(1, 2))                                      # (n, C)
    n = means.shape[0]
    n_pix = images.shape[1] * images.shape[2]
    a = means.var(axis=0, ddof=1) / n
    b = np.asarray(reference_var, dtype=np.float64).sum(axis=(0, 1)) / n_pix ** 2
    t = (means.mean(axis=0) - np.asarray(reference, dtype=np.float64).mean(axis=(0, 1))) / np.sqrt(a + b)
    dof = (a + b) ** 2 / (a ** 2 / (n - 1) + (0.0 if math.isinf(reference_dof) else b ** 2 / reference_dof))
    p = 2 * stats.t.sf(np.abs(t), dof)
    return np.sign(t) * stats.norm.isf(p / 2)


def block_means(image, reference_var=None, b: int = 2):
    """Means over ``b x b`` pixel blocks of an ``(H, W, 3)`` image; with
    ``reference_var`` (a reference's per-pixel variance of the mean, its pixels
    independent) the variance of those means instead: ``sum / b^4``."""
    x = np.asarray(image if reference_var is None else reference_var, dtype=np.float64)
    h, w, c = x.shape
    s = x[:h - h % b, :w - w % b].reshape(h // b, b, w // b, b, c).sum(axis=(1, 3))
    return s / b ** 2 if reference_var is None else s / b ** 4


def efficiency_ratio(mse_other: float, seconds_other: float, mse_ours: float, seconds_ours: float) -> float:
    """``(MSE x time of the other engine) / (MSE x time of ours)``: > 1 when ours is ahead."""
    ours = mse_ours * seconds_ours
    if not (ours > 0 and mse_other * seconds_other > 0):
        return float("nan")          # an MSE at or below the floor: not measurable at this reference
    return mse_other * seconds_other / ours


def geometric_mean(values) -> float:
    """Geometric mean of positive ``values`` (NaN entries, unmeasured cases, are left out)."""
    v = np.asarray([x for x in values if not math.isnan(x)], dtype=np.float64)
    if v.size == 0:
        return float("nan")
    if np.any(v <= 0):
        raise ValueError(f"geometric_mean needs positive values; got {v.tolist()}")
    return float(np.exp(np.mean(np.log(v))))


def summarize(seconds, errors, paths: float) -> dict:
    """Median seconds, mean MSE (and its standard error), MSE x time and seconds per million paths."""
    s = np.asarray(seconds, dtype=np.float64)
    e = np.asarray(errors, dtype=np.float64)
    t = float(np.median(s))
    mse = float(np.mean(e))
    se = float(np.std(e, ddof=1) / np.sqrt(e.size)) if e.size > 1 else float("nan")
    return {"seconds": t, "seconds_min": float(s.min()), "seconds_max": float(s.max()), "mse": mse,
            "mse_se": se, "mse_x_time": mse * t, "s_per_mpath": t / (paths / 1e6), "runs": int(s.size)}


# ---------------------------------------------------------------------------
# finding Mitsuba's LLVM

def find_libllvm(given: str | None = None) -> str | None:
    """A libLLVM of version >= 16 for drjit: ``given``, else ``DRJIT_LIBLLVM_PATH``, else the
    newest ``libLLVM*.so*`` in the usual library folders; None if there is none."""
    if given:
        return given
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        return os.environ["DRJIT_LIBLLVM_PATH"]
    best = None
    for folder in ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib", "/usr/local/lib",
                   "/usr/lib64"):
        for path in glob.glob(os.path.join(folder, "libLLVM*.so*")):
            m = re.search(r"libLLVM[-.]?(?:so\.)?(\d+)", os.path.basename(path))
            if m and int(m.group(1)) >= 16 and os.path.isfile(path):
                if best is None or int(m.group(1)) > best[0]:
                    best = (int(m.group(1)), path)
    return None if best is None else best[1]


def _env(libllvm: str | None) -> dict:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT)] + [p for p in [os.environ.get("PYTHONPATH")]
                                                                   if p]))
    if libllvm:
        env["DRJIT_LIBLLVM_PATH"] = libllvm
    return env


def _subprocess(args: list, libllvm: str | None, what: str) -> dict:
    """Run this script as ``--worker ...``; the npz it writes, as a dict of arrays."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.npz"
        p = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--worker", *map(str, args),
                            "--out", str(out)], env=_env(libllvm), capture_output=True, text=True)
        if p.returncode != 0 or not out.is_file():
            tail = (p.stderr or p.stdout).strip().splitlines()[-6:]
            raise RuntimeError(f"{what} failed (exit {p.returncode}):\n  " + "\n  ".join(tail))
        with np.load(out, allow_pickle=False) as d:
            return {k: d[k] for k in d.files}


def mitsuba_status(libllvm: str | None) -> str | None:
    """None when Mitsuba's ``llvm_ad_rgb`` variant renders here, else why not."""
    try:
        import importlib.util

        if importlib.util.find_spec("mitsuba") is None:
            return "Mitsuba 3 is not installed (pip install 'mcvar[mitsuba]')"
    except ValueError:
        return "Mitsuba 3 is not importable"
    if libllvm is None:
        return ("no libLLVM >= 16 found for Mitsuba's LLVM variant (drjit fails with LLVM 14 and 15, 'Cannot "
                "select ... fminimum'): install one (apt-get install libllvm19) and pass --libllvm PATH")
    try:
        _subprocess(["mitsuba", "cornell", 8, 4, "0", "--samplers", "independent"], libllvm, "Mitsuba probe")
    except RuntimeError as exc:
        return f"Mitsuba's llvm_ad_rgb variant did not run with {libllvm}: {exc}"
    return None


# ---------------------------------------------------------------------------
# the workers (one engine, one process)

def _mitsuba_scene(mi, scene_name: str, res: int, spp: int, sampler: str, folder: Path, k: int = 1):
    from mcvar.interop.mitsuba import to_mitsuba
    from mcvar.scene import load_scene
    from mcvar.tessellate import subdivide

    scene = load_scene(scene_name)
    if k > 1:
        scene = subdivide(scene, k)
    d = to_mitsuba(scene, res=res, spp=spp, folder=folder)
    d["integrator"].update(max_depth=-1, rr_depth=5)
    d["sensor"]["sampler"] = {"type": sampler, "sample_count": spp}
    return mi.load_dict(d)


def _worker_mitsuba(a) -> dict:
    """Every sampler: a warm-up render, then one timed image per seed (samplers interleaved)."""
    import drjit as dr
    import mitsuba as mi

    mi.set_variant(a.variant)
    dr.set_thread_count(2)
    folder = Path(tempfile.gettempdir()) / "mcvar-bench-suite"
    out = {}
    scenes = {}
    for s in a.samplers:
        scenes[s] = _mitsuba_scene(mi, a.scene, a.res, a.spp, s, folder, a.k)
        np.asarray(mi.render(scenes[s], spp=a.spp, seed=10 ** 6))
    for seed in a.seeds:
        for s in a.samplers:
            t0 = time.perf_counter()
            img = np.array(mi.render(scenes[s], spp=a.spp, seed=seed), dtype=np.float64)[..., :3]
            out.setdefault(f"{s}/seconds", []).append(time.perf_counter() - t0)
            out.setdefault(f"{s}/images", []).append(img)
    return {k: np.asarray(v) for k, v in out.items()}


def _mcvar_call(config: str):
    """The render function of a mcvar configuration: ``f(scene, spp, res, seed) -> Render``."""
    from mcvar.adaptive import render_adaptive
    from mcvar.cli import _adaptive_workers
    from mcvar.integrators import render

    if config == "mcvar default":
        # mcvar render's default: render(allocation='adaptive', workers=_adaptive_workers(None),
        # **adaptive_settings('path')), which is render_adaptive with those workers
        return lambda scene, spp, res, seed: render_adaptive(scene, spp=spp, res=res, sampler="sobol", rng=seed,
                                                             workers=_adaptive_workers(None))
    if config == "mcvar plain":
        return lambda scene, spp, res, seed: render(scene, spp=spp, res=res, sampler="sobol", rng=seed)
    raise ValueError(f"unknown mcvar configuration {config!r}; one of {MCVAR}")


def _worker_mcvar(a) -> dict:
    """mcvar's configurations: a warm-up render each, then one timed image per seed (interleaved)."""
    from mcvar.scene import load_scene
    from mcvar.tessellate import subdivide

    scene = load_scene(a.scene)
    if a.k > 1:
        scene = subdivide(scene, a.k)
    calls = {c: _mcvar_call(c) for c in a.configs}
    for c, f in calls.items():
        f(scene, min(a.spp, 16), a.res, 10 ** 6)
    out = {}
    for seed in a.seeds:
        for c, f in calls.items():
            t0 = time.perf_counter()
            r = f(scene, a.spp, a.res, seed)
            wall = time.perf_counter() - t0
            out.setdefault(f"{c}/seconds", []).append(wall)
            out.setdefault(f"{c}/render_seconds", []).append(r.seconds)
            out.setdefault(f"{c}/images", []).append(r.image)
            out.setdefault(f"{c}/spp", []).append(r.spp)
    out["triangles"] = [scene.n_triangles]
    return {k: np.asarray(v) for k, v in out.items()}


def _worker_reference(a) -> dict:
    """``a.chunks`` independent renders of ``a.spp`` spp each (Mitsuba, or mcvar's own path)."""
    chunks = []
    t0 = time.perf_counter()
    if a.variant == "mcvar":
        from mcvar.integrators import render
        from mcvar.scene import load_scene

        scene = load_scene(a.scene)
        for i in range(a.chunks):
            chunks.append(render(scene, spp=a.spp, res=a.res, sampler="random", rng=777_000 + i, workers=2,
                                 visible_lights="exact").image)
    else:
        import drjit as dr
        import mitsuba as mi

        mi.set_variant(a.variant)
        dr.set_thread_count(2)
        sc = _mitsuba_scene(mi, a.scene, a.res, a.spp, REF_SAMPLER, Path(tempfile.gettempdir()) / "mcvar-bench-suite")
        for i in range(a.chunks):
            chunks.append(np.array(mi.render(sc, spp=a.spp, seed=777_000 + i), dtype=np.float64)[..., :3])
    return {"chunks": np.asarray(chunks), "seconds": [time.perf_counter() - t0]}


def worker_main(argv) -> int:
    p = argparse.ArgumentParser(prog="bench_suite.py --worker")
    p.add_argument("engine", choices=("mitsuba", "mcvar", "reference"))
    p.add_argument("scene")
    p.add_argument("res", type=int)
    p.add_argument("spp", type=int)
    p.add_argument("seeds", type=lambda s: [int(x) for x in s.split(",") if x])
    p.add_argument("--out", required=True)
    p.add_argument("--samplers", type=lambda s: s.split(","), default=list(MITSUBA_SAMPLERS))
    p.add_argument("--configs", type=lambda s: s.split(","), default=list(MCVAR))
    p.add_argument("--variant", default="llvm_ad_rgb")
    p.add_argument("--chunks", type=int, default=0)
    p.add_argument("--k", type=int, default=1)
    a = p.parse_args(argv)
    got = {"mitsuba": _worker_mitsuba, "mcvar": _worker_mcvar, "reference": _worker_reference}[a.engine](a)
    np.savez(a.out, **got)
    return 0


# ---------------------------------------------------------------------------
# the references

def reference(case: Case, paths: int, libllvm: str | None, mitsuba_ok: bool):
    """``(mean, variance of the mean, its degrees of freedom, description)`` of ``case``'s reference, cached."""
    from mcvar.interop.mitsuba import EXPORTER_VERSION

    if mitsuba_ok:
        variant = "llvm_ad_rgb"
    else:
        import importlib.util

        variant = "scalar_rgb" if importlib.util.find_spec("mitsuba") is not None else "mcvar"
        if variant == "scalar_rgb":
            paths = min(paths, 2 ** 24)            # ~1 M paths/s: keep it to minutes
    lanes = min(REF_CHUNK_LANES, paths // 16)
    chunk_spp = max(1, 2 ** int(math.log2(max(1, lanes // (case.res * case.res)))))
    chunks = max(2, paths // (chunk_spp * case.res * case.res))
    def describe(n_chunks, c_spp, v=variant):
        return (f"{'Mitsuba ' + v if v != 'mcvar' else 'mcvar path, random sampler'}, "
                f"{n_chunks} x {c_spp} spp = {n_chunks * c_spp} spp")

    # the cached reference of this case with at least the paths asked for: an
    # independent renderer's (Mitsuba, either variant) before mcvar's own, then the largest
    cached = []
    for f in CACHE.glob(f"bench-suite-ref-{case.scene}-{case.res}-*x*-v{EXPORTER_VERSION}.npz"):
        m = re.fullmatch(rf"bench-suite-ref-{re.escape(case.scene)}-{case.res}-(\d+)x(\d+)-"
                         rf"(llvm_ad_rgb|scalar_rgb|mcvar)-v{EXPORTER_VERSION}\.npz", f.name)
        if m and int(m.group(1)) * int(m.group(2)) * case.res ** 2 >= paths:
            cached.append((m.group(3) != "mcvar", int(m.group(1)) * int(m.group(2)), int(m.group(2)),
                           int(m.group(1)), m.group(3), str(f)))
    if cached:
        _, _, n_chunks, c_spp, v, f = max(cached)
        with np.load(f) as d:
            return d["mean"], d["var"], n_chunks - 1, describe(n_chunks, c_spp, v) + " (cached)"
    path = CACHE / (f"bench-suite-ref-{case.scene}-{case.res}-{chunk_spp}x{chunks}-{variant}"
                    f"-v{EXPORTER_VERSION}.npz")
    what = describe(chunks, chunk_spp)
    t0 = time.perf_counter()
    print(f"reference of {case.name}: {what} ...", flush=True)
    got = _subprocess(["reference", case.scene, case.res, chunk_spp, "0", "--chunks", chunks, "--variant", variant],
                      libllvm, f"reference of {case.name}")
    mean, var = reference_from_chunks(got["chunks"])
    CACHE.mkdir(parents=True, exist_ok=True)
    np.savez(path, mean=mean, var=var)
    print(f"  {time.perf_counter() - t0:.0f} s; floor (mean variance of the reference) {var.mean():.2e}",
          flush=True)
    return mean, var, chunks - 1, what


# ---------------------------------------------------------------------------
# the suite

def select_cases(spec: str | None) -> tuple:
    """The cases ``--cases`` names (comma-separated scenes or ``scene-res``; None: :data:`CASES`)."""
    if spec is None:
        return CASES
    tokens = [t.strip() for t in spec.split(",") if t.strip()]
    bad = [t for t in tokens if not any(t in (c.scene, f"{c.scene}-{c.res}") for c in CASES)]
    if bad or not tokens:
        raise SystemExit(f"--cases: unknown case(s) {', '.join(bad) or repr(spec)}; the suite has "
                         f"{', '.join(f'{c.scene}-{c.res}' for c in CASES)}")
    return tuple(c for c in CASES if any(t in (c.scene, f"{c.scene}-{c.res}") for t in tokens))


def _load() -> str:
    a, b, c = os.getloadavg()
    return f"{a:.2f} {b:.2f} {c:.2f}"


def run_suite(args, libllvm, mitsuba_ok) -> list[dict]:
    refs = {c: reference(c, args.ref_paths, libllvm, mitsuba_ok) for c in args.cases}
    rows = {(c, e): {"seconds": [], "errors": [], "errors_block": [], "images": [], "spp": []}
            for c in args.cases for e in list(MCVAR) + ([f"Mitsuba {s}" for s in MITSUBA_SAMPLERS] if mitsuba_ok else [])}
    loads = [os.getloadavg()[0]]
    print(f"suite: {args.rounds} rounds x {args.seeds} seeds, load average {_load()} on {os.cpu_count()} CPUs",
          flush=True)
    for rnd in range(args.rounds):
        seeds = ",".join(str(1000 + rnd * args.seeds + s) for s in range(args.seeds))
        for i, case in enumerate(args.cases):
            engines = ["mcvar", "mitsuba"] if mitsuba_ok else ["mcvar"]
            if (rnd + i) % 2:                              # alternate which engine goes first
                engines.reverse()
            for engine in engines:
                t0 = time.perf_counter()
                got = _subprocess([engine, case.scene, case.res, case.spp, seeds], libllvm,
                                  f"{engine} on {case.name}")
                print(f"  round {rnd + 1}, {case.name}, {engine}: {time.perf_counter() - t0:.0f} s "
                      f"(load {os.getloadavg()[0]:.1f})", flush=True)
                names = MCVAR if engine == "mcvar" else MITSUBA_SAMPLERS
                for n in names:
                    key = (case, n if engine == "mcvar" else f"Mitsuba {n}")
                    rows[key]["seconds"] += got[f"{n}/seconds"].tolist()
                    rows[key]["images"] += list(got[f"{n}/images"])
                    rows[key]["spp"] += got[f"{n}/spp"].tolist() if f"{n}/spp" in got else \
                        [case.spp] * len(got[f"{n}/seconds"])
                    mean, var, _, _ = refs[case]
                    rows[key]["errors"] += [mse_minus_floor(im, mean, var) for im in got[f"{n}/images"]]
                    # the same on 2 x 2 block means: what correlated pixels (path reuse) give the image seen coarser
                    rows[key]["errors_block"] += [mse_minus_floor(block_means(im), block_means(mean),
                                                                  block_means(None, var))
                                                  for im in got[f"{n}/images"]]
        loads.append(os.getloadavg()[0])
        print(f"  round {rnd + 1}/{args.rounds} done, load average {_load()}", flush=True)
    out = []
    for (case, engine), r in rows.items():
        mean, var, dof, what = refs[case]
        s = summarize(r["seconds"], r["errors"], case.res ** 2 * float(np.mean(r["spp"])))
        z = mean_z_scores(np.asarray(r["images"]), mean, var, dof) if len(r["images"]) > 1 else np.full(3, np.nan)
        out.append({"case": case.name, "engine": engine, **s, "mse_block": float(np.mean(r["errors_block"])),
                    "z_max": float(np.nanmax(np.abs(z))),
                    "z": [round(float(x), 2) for x in z], "floor": float(var.mean()), "reference": what})
    out.append({"loads": loads})
    return out


def report_suite(rows: list[dict], mitsuba_ok: bool, why: str | None) -> tuple[str, list[float]]:
    """The markdown table (and the ratios per case); prints the agreement check first."""
    loads = rows[-1]["loads"]
    rows = rows[:-1]
    print("\nagreement with the reference (image mean per channel, z-scores; |z| > "
          f"{Z_FLAG:g} is flagged):")
    for r in rows:
        flag = "  DISAGREES" if r["z_max"] > Z_FLAG else ""
        print(f"  {r['case']:<32} {r['engine']:<22} z = {r['z']}{flag}")
    lines = ["| case | Mitsuba best: s / MSE / MSE x time | mcvar default: s / MSE / MSE x time | "
             "mcvar plain: s / MSE / MSE x time | ratio default (plain) | ratio on 2 x 2 means |",
             "|---|---|---|---|---|---|"]
    ratios = []
    for case in dict.fromkeys(r["case"] for r in rows):
        by = {r["engine"]: r for r in rows if r["case"] == case}

        def cell(r):
            flag = " (!)" if r["z_max"] > Z_FLAG else ""
            return f"{r['seconds']:.3f} / {r['mse']:.2e} / {r['mse_x_time']:.2e}{flag}"

        d, p = by["mcvar default"], by["mcvar plain"]
        if mitsuba_ok:
            ok = [by[f"Mitsuba {s}"] for s in MITSUBA_SAMPLERS if by[f"Mitsuba {s}"]["mse_x_time"] > 0]
            m = min(ok, key=lambda r: r["mse_x_time"])
            ratio = efficiency_ratio(m["mse"], m["seconds"], d["mse"], d["seconds"])
            ratio_p = efficiency_ratio(m["mse"], m["seconds"], p["mse"], p["seconds"])
            ratios.append(ratio)
            coarse = (f"{efficiency_ratio(m['mse_block'], m['seconds'], d['mse_block'], d['seconds']):.2f}"
                      if "mse_block" in m and "mse_block" in d else "")
            lines.append(f"| {case} | {m['engine'].split()[-1]}: {cell(m)} | {cell(d)} | {cell(p)} | "
                         f"**{ratio:.2f}** ({ratio_p:.2f}) | {coarse} |")
        else:
            lines.append(f"| {case} | skipped | {cell(d)} | {cell(p)} | | |")
    lines.append("")
    lines.append("| case | " + " | ".join(dict.fromkeys(r["engine"] for r in rows)) + " |")
    lines.append("|---|" + "---|" * len(dict.fromkeys(r["engine"] for r in rows)))
    for case in dict.fromkeys(r["case"] for r in rows):
        lines.append(f"| {case} (s per M paths) | " + " | ".join(f"{r['s_per_mpath']:.3f}" for r in rows
                                                                  if r["case"] == case) + " |")
    lines.append("")
    lines.append(f"Load average (1 min) during the run: {min(loads):.2f}-{max(loads):.2f} "
                 f"(before {loads[0]:.2f}, after {loads[-1]:.2f}); {rows[0]['runs']} images per engine and case; "
                 f"references: " + "; ".join(dict.fromkeys(f"{r['case']}: {r['reference']}, floor "
                                                            f"{r['floor']:.1e}" for r in rows)))
    if not mitsuba_ok:
        lines.append(f"Mitsuba skipped: {why}")
    return "\n".join(lines), ratios


# ---------------------------------------------------------------------------
# the triangle-count series

def triangle_seeds(rnd: int, count: int) -> str:
    """The seeds of round ``rnd`` of the triangle series, ``count`` of them (comma-separated):
    fresh in every round, so that the medians are over independent renders."""
    return ",".join(str(2000 + rnd * count + s) for s in range(count))


def run_triangles(args, libllvm, mitsuba_ok) -> list[dict]:
    ks = args.triangle_ks
    res, spp = args.triangle_res, args.triangle_spp
    acc: dict = {}
    print(f"\ntriangle-count series: subdivided Cornell box, k = {ks}, {res}x{res}, {spp} spp, "
          f"{args.triangle_rounds} rounds x {args.triangle_seeds} seeds; load average {_load()}", flush=True)
    for rnd in range(args.triangle_rounds):
        seeds = triangle_seeds(rnd, args.triangle_seeds)
        for k in ks:
            engines = ["mcvar", "mitsuba"] if mitsuba_ok else ["mcvar"]
            for engine in engines:
                extra = ["--samplers", "multijitter"] if engine == "mitsuba" else []
                got = _subprocess([engine, "cornell", res, spp, seeds, "--k", k, *extra], libllvm,
                                  f"{engine} on the box x{k * k}")
                for n in (MCVAR if engine == "mcvar" else ("multijitter",)):
                    key = (k, n if engine == "mcvar" else "Mitsuba multijitter")
                    a = acc.setdefault(key, {"seconds": [], "render_seconds": [], "spp": [], "mean": []})
                    a["seconds"] += got[f"{n}/seconds"].tolist()
                    a["render_seconds"] += (got[f"{n}/render_seconds"] if f"{n}/render_seconds" in got
                                            else got[f"{n}/seconds"]).tolist()
                    a["spp"] += got[f"{n}/spp"].tolist() if f"{n}/spp" in got else [spp]
                    a["mean"] += [float(np.mean(im)) for im in got[f"{n}/images"]]
                    if "triangles" in got:
                        a_tri = int(got["triangles"][0])
                        for kk in (key, (k, "triangles")):
                            acc.setdefault(kk, {})["triangles"] = a_tri
        print(f"  round {rnd + 1}/{args.triangle_rounds} done, load average {_load()}", flush=True)
    out = []
    for (k, engine), a in acc.items():
        if engine == "triangles":
            continue
        paths = res * res * float(np.mean(a["spp"]))
        out.append({"k": k, "triangles": acc[(k, "triangles")]["triangles"], "engine": engine,
                    "seconds": float(np.median(a["seconds"])), "render_seconds": float(np.median(a["render_seconds"])),
                    "mpaths_per_s": paths / float(np.median(a["render_seconds"])) / 1e6,
                    "mpaths_per_s_call": paths / float(np.median(a["seconds"])) / 1e6,
                    "image_mean": float(np.mean(a["mean"]))})
    for r in out:
        base = next(b for b in out if b["engine"] == r["engine"] and b["k"] == ks[0])
        r["vs_box"] = r["mpaths_per_s"] / base["mpaths_per_s"]
        r["vs_box_call"] = r["mpaths_per_s_call"] / base["mpaths_per_s_call"]
    return sorted(out, key=lambda r: (r["engine"], r["k"]))


def report_triangles(rows: list[dict]) -> str:
    lines = ["| triangles | engine | M paths/s (render) | vs the box | M paths/s (whole call) | vs the box | "
             "image mean |", "|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: (r["k"], r["engine"])):
        lines.append(f"| {r['triangles']:,} | {r['engine']} | {r['mpaths_per_s']:.3f} | {r['vs_box']:.2f} | "
                     f"{r['mpaths_per_s_call']:.3f} | {r['vs_box_call']:.2f} | {r['image_mean']:.5f} |")
    return "\n".join(lines)


def plot_triangles(rows: list[dict], path: Path, load: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    for engine in dict.fromkeys(r["engine"] for r in rows):
        rr = sorted((r for r in rows if r["engine"] == engine), key=lambda r: r["triangles"])
        x = [r["triangles"] for r in rr]
        ax.loglog(x, [r["vs_box"] for r in rr], "o-", label=f"{engine} (render)")
        if engine.startswith("mcvar"):
            ax.loglog(x, [r["vs_box_call"] for r in rr], "x:", label=f"{engine} (whole call, tracer build)")
    ax.axhline(1 / 3, color="0.5", lw=0.8, ls="--")
    ax.text(40, 0.35, "issue 27's goal: 1/3 of the box", fontsize=7, color="0.4")
    ax.set_xlabel("triangles (Cornell box, subdivided)")
    ax.set_ylabel("paths per second / the box's")
    ax.set_title(f"Cost of a path against the scene's triangles, {TRIANGLE_RES}x{TRIANGLE_RES}, "
                 f"{TRIANGLE_SPP} spp (load average {load})", fontsize=8)
    ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _write_csv(path: Path, rows: list[dict]) -> None:
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: json.dumps(v) if isinstance(v, list) else v for k, v in r.items()})


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if str(ROOT) not in sys.path:            # `python benchmarks/bench_suite.py` from a checkout
        sys.path.insert(0, str(ROOT))
    if argv[:1] == ["--worker"]:
        return worker_main(argv[1:])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="1 round x 3 seeds, 2^24-path references, the triangle series to 1,922 triangles")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--ref-paths", type=int, default=REF_PATHS, help="paths per reference (default 2^25)")
    ap.add_argument("--no-mitsuba", action="store_true", help="mcvar only")
    ap.add_argument("--no-triangles", action="store_true", help="skip the triangle-count series")
    ap.add_argument("--no-suite", action="store_true", help="only the triangle-count series")
    ap.add_argument("--triangle-rounds", type=int, default=3)
    ap.add_argument("--triangle-seeds", type=int, default=3,
                    help="renders per engine, level and round in the triangle series (medians over all; "
                         "one render per round moved the 100k point by a third between runs)")
    ap.add_argument("--libllvm", default=None, help="a libLLVM >= 16 for Mitsuba's LLVM variant")
    ap.add_argument("--cases", default=None,
                    help="the suite's cases to run, comma-separated: a scene (cornell-spheres: its case; "
                         "cornell: the three) or scene-res (cornell-128); default all four")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--plot", type=Path, default=None,
                    help=f"where the triangle-count plot goes (default {PLOT.relative_to(ROOT)}; with --quick, "
                         "OUT/triangles.png, so that a smoke run does not overwrite the docs' figure)")
    args = ap.parse_args(argv)
    args.triangle_ks, args.triangle_res, args.triangle_spp = TRIANGLE_KS, TRIANGLE_RES, TRIANGLE_SPP
    args.cases = select_cases(args.cases)
    if args.quick:
        args.rounds, args.seeds, args.triangle_rounds = 1, 3, 1
        args.ref_paths = min(args.ref_paths, 2 ** 24)
        args.triangle_ks = (1, 2, 4, 8)
    for key in ("rounds", "seeds", "ref_paths", "triangle_rounds", "triangle_seeds"):
        if getattr(args, key) < 1:
            raise SystemExit(f"--{key.replace('_', '-')} must be >= 1; got {getattr(args, key)}")
    if args.seeds * args.rounds < 2:
        raise SystemExit("rounds x seeds must be >= 2 (the agreement check needs two images)")
    libllvm = find_libllvm(args.libllvm)
    why = "--no-mitsuba" if args.no_mitsuba else mitsuba_status(libllvm)
    mitsuba_ok = why is None
    print(f"Mitsuba 3 LLVM: {'libLLVM ' + libllvm if mitsuba_ok else 'skipped: ' + why}")
    args.out.mkdir(parents=True, exist_ok=True)
    if args.plot is None:
        args.plot = args.out / "triangles.png" if args.quick else PLOT
    t_start = time.perf_counter()
    ratios = []
    if not args.no_suite:
        rows = run_suite(args, libllvm, mitsuba_ok)
        table, ratios = report_suite(rows, mitsuba_ok, why)
        _write_csv(args.out / "suite.csv", rows[:-1])
        (args.out / "suite.md").write_text(table + "\n")
        print("\n" + table)
    if not args.no_triangles:
        tri = run_triangles(args, libllvm, mitsuba_ok)
        ttable = report_triangles(tri)
        _write_csv(args.out / "triangles.csv", tri)
        with open(args.out / "suite.md", "a") as f:
            f.write("\n" + ttable + "\n")
        plot_triangles(tri, args.plot, _load())
        print("\n" + ttable)
        from mcvar.tracer import BVH_MIN_TRIANGLES

        mc = sorted((r for r in tri if r["engine"] == "mcvar default"), key=lambda r: r["triangles"])
        bvh = [r for r in mc if r["triangles"] >= BVH_MIN_TRIANGLES]      # the BVH's range
        if len(bvh) > 1:
            slope = np.polyfit(np.log([r["triangles"] for r in bvh]),
                               np.log([1 / r["mpaths_per_s"] for r in bvh]), 1)[0]
            print(f"mcvar default: seconds per path grow as triangles^{slope:.3f} from {bvh[0]['triangles']:,} "
                  f"to {bvh[-1]['triangles']:,} triangles (the BVH); {mc[-1]['triangles']:,} triangles at "
                  f"{mc[-1]['vs_box']:.2f}x the box's paths/s")
        print(f"saved {args.plot}")
    print(f"\nwrote {args.out}/suite.csv, suite.md{', triangles.csv' if not args.no_triangles else ''}; "
          f"{time.perf_counter() - t_start:.0f} s in all; load average now {_load()}")
    if ratios:
        for case, r in zip((c.name for c in args.cases), ratios):
            print(f"ratio (Mitsuba best / mcvar default MSE x time), {case}: {r:.2f}")
        print(f"geometric mean of the ratios over {len(ratios)} cases: {geometric_mean(ratios):.2f}")
    elif not args.no_suite:
        print(f"no ratios: Mitsuba skipped ({why})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
