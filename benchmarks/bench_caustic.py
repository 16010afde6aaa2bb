"""Photons on the caustic (issue 21): path tracing, SPPM and photon mapping at equal time on
``cornell-caustic`` (prints a markdown table; not a test).

Run::

    PYTHONPATH=$PWD /work/venv/bin/python benchmarks/bench_caustic.py [--res 32] [--seconds 4]
        [--seeds 3] [--methods path,sppm,photon] [--cache out/.cache]

A method may carry options, ``sppm:photons=65536,radius=20``. Every method renders the scene for
``--seconds`` of wall time per seed (:func:`mcvar.experiments.compare.equal_time_render`: rounds of
spp, or one progressive run for ``sppm``), and its image is compared with one shared reference
(:func:`mcvar.experiments.compare.scene_reference`, cached in ``--cache``): BDPT at
``--reference-spp``, because path tracing is heavy-tailed on this scene (tests/test_cornell_caustic.py:
256-spp image means 0.133 and 0.153 from two seeds, BDPT's 0.1345-0.1350).

MSE is the mean over pixels and channels of ``(image - reference)^2`` over

* ``image``: every pixel that does not see the light, directly or through the glass
  (:func:`mcvar.integrators.photon.sees_emitters`: a radiance-1700 light over a sliver of a pixel is pixel-sampling noise that
  no transport method changes, and the reference's own variance is largest there);
* ``caustic``: the floor within two sphere radii of the sphere's contact point (pixel centres), where
  the focused light lands.

Per method: the median over the seeds of MSE and of the seconds used, ``MSE x time`` of the medians,
its ratio to path tracing's (below 1: more efficient than path tracing), and the reference's own
noise (the floor under every MSE). The machine's load average is printed before and after.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from mcvar.experiments.compare import equal_time_render, scene_reference
from mcvar.integrators.photon import sees_emitters
from mcvar.scene import load_scene
from mcvar.experiments.slide_pairs import caustic_pixels

SCENE = "cornell-caustic"


def _value(text: str):
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return {"none": None, "true": True, "false": False}.get(text.lower(), text)


def parse_method(spec: str):
    """``name`` or ``name:key=value,key=value`` -> (label, name, options)."""
    name, _, rest = spec.partition(":")
    options = {}
    for item in filter(None, rest.split(",")):
        key, _, val = item.partition("=")
        options[key.strip()] = _value(val.strip())
    return spec, name.strip(), options


def measure(methods, *, res: int, seconds: float, seeds: int, reference_spp: int, cache, seed: int = 0,
            reference=None):
    """Rows of the table: one per method spec, medians over ``seeds`` equal-time runs
    (``reference``: a :class:`~mcvar.experiments.compare.SceneReference` to use instead)."""
    sc = load_scene(SCENE)
    ref = reference if reference is not None else scene_reference(
        SCENE, res, method="bdpt", spp=reference_spp, seed=seed, cache_dir=cache, progress=True)
    keep = ~sees_emitters(sc, res)
    caustic = caustic_pixels(sc, res) & keep
    rows = []
    for label, name, options in methods:
        runs = []
        for i in range(seeds):
            tr = equal_time_render(sc, name, seconds=seconds, res=res, options=options,
                                   rng=np.random.SeedSequence([seed, 2112, i]))
            err = (tr.image - ref.value) ** 2
            runs.append((tr.seconds, float(err[keep].mean()), float(err[caustic].mean()), tr.spp))
        t, mse, mse_c, spp = (float(np.median(x)) for x in zip(*runs))
        rows.append(dict(method=label, spp=spp, seconds=t, mse=mse, mse_caustic=mse_c,
                         runs=runs))
    noise = float(ref.variance[keep].mean()), float(ref.variance[caustic].mean())
    return rows, noise, ref


def table(rows, noise) -> str:
    base = next((r for r in rows if r["method"] == "path"), rows[0])
    out = ["| method | spp / iterations | seconds | MSE (image) | MSE x time | ratio to path | "
           "MSE (caustic) | MSE x time (caustic) | ratio to path (caustic) |",
           "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        e, ec = r["mse"] * r["seconds"], r["mse_caustic"] * r["seconds"]
        be, bec = base["mse"] * base["seconds"], base["mse_caustic"] * base["seconds"]
        out.append(f"| `{r['method']}` | {r['spp']:.0f} | {r['seconds']:.2f} | {r['mse']:.3g} | {e:.3g} | "
                   f"{e / be:.3g} | {r['mse_caustic']:.3g} | {ec:.3g} | {ec / bec:.3g} |")
    out.append(f"\nreference noise (mean variance of the reference's pixels): image {noise[0]:.2g}, "
               f"caustic {noise[1]:.2g}")
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=int, default=32)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--methods", default="path,sppm,photon",
                    help="method specs separated by ',' (names only) or ';' (when a spec has options), "
                         "e.g. 'path;sppm:photons=65536,radius=20'")
    ap.add_argument("--reference-spp", type=int, default=4096)
    ap.add_argument("--cache", default="out/.cache")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    specs = a.methods.split(";") if ";" in a.methods else a.methods.split(",")
    methods = [parse_method(s) for s in specs if s.strip()]
    load0 = os.getloadavg()
    start = time.perf_counter()
    rows, noise, ref = measure(methods, res=a.res, seconds=a.seconds, seeds=a.seeds,
                               reference_spp=a.reference_spp, cache=a.cache, seed=a.seed)
    load1 = os.getloadavg()
    print(f"{SCENE}, {a.res} x {a.res}, {a.seconds:g} s per run, {a.seeds} seeds (medians); reference "
          f"{ref.method} {ref.spp} spp ({'cached' if ref.cached else f'{ref.seconds:.0f} s'}); "
          f"load average (1, 5, 15 min) before {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}, "
          f"after {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}; {time.perf_counter() - start:.0f} s in all\n")
    print(table(rows, noise))
    for r in rows:
        print(f"  {r['method']}: per seed (seconds, MSE image, MSE caustic, spp) "
              + "; ".join(f"({t:.2f}, {m:.3g}, {c:.3g}, {s})" for t, m, c, s in r["runs"]))


if __name__ == "__main__":
    main()
