"""The agreement figures of docs/mitsuba.md: every (scene, unbiased method) against its Mitsuba reference.

Run: ``python benchmarks/mitsuba_agreement.py [--scenes cornell,...] [--methods path,...] [--all]
[--extras-only]``

Uses exactly the test's machinery and plans (``tests/test_mitsuba_reference.py``:
the same replicates, blocks, Welch t and Sidak level) and prints one markdown
row per pair: the largest block |t|, the image-mean t and relative
difference, the smallest p-value against its Sidak threshold, the smallest
skewness-test p-value (heavy tails) and the CPU seconds. ``--all`` also runs
the pairs the test leaves out (heavy-tailed or excluded), so their figures
can be quoted as the evidence for leaving them out. Without ``--scenes`` or
``--methods`` it then prints the ``max_depth`` table (cornell, depths 1-3)
and the biased methods' block errors along their knobs.
"""
from __future__ import annotations

import argparse
import importlib.util
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _tests():
    spec = importlib.util.spec_from_file_location("test_mitsuba_reference", ROOT / "tests" / "test_mitsuba_reference.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default=None)
    ap.add_argument("--methods", default=None)
    ap.add_argument("--all", action="store_true", help="also the excluded and heavy-tailed pairs")
    ap.add_argument("--extras-only", action="store_true", help="only the max_depth and biased-method tables")
    args = ap.parse_args(argv)
    T = _tests()
    from mcvar.integrators import METHODS

    scenes = args.scenes.split(",") if args.scenes else T._recipes()
    methods = args.methods.split(",") if args.methods else list(T.UNBIASED)
    if args.extras_only:
        scenes = []
    print("| scene | method | replicates x spp | max block abs t | image-mean t | mcvar / Mitsuba - 1 "
          "| min p (Sidak) | min skew p (Sidak) | verdict | CPU s |")
    print("|---|---|---|---:|---:|---:|---|---|---|---:|")
    for recipe in scenes:
        for method in methods:
            if method not in METHODS:
                continue
            note = T.EXCLUDED.get((recipe, method)) or T.HEAVY_TAILED.get((recipe, method))
            if note and not args.all:
                continue
            m = METHODS[method]
            try:
                if m.check_scene is not None:
                    m.check_scene(T.scene_of(recipe), m.resolve_options({}))
            except ValueError:
                print(f"| {recipe} | {method} | refuses the scene | | | | | | | |", flush=True)
                continue
            spp, reps = T.PLAN.get((recipe, method), T.DEFAULT_PLAN[method])
            start = time.process_time()
            images = T.mcvar_replicates(recipe, method, spp, reps)
            cpu = time.process_time() - start
            s = T.agreement(images, T._case_name(recipe, m.fixed_depth), T.region_of(recipe))
            heavy = s["min_skew_p"] <= s["skew_p_each"]
            ok = s["min_p"] > s["p_each"]
            verdict = ("heavy-tailed" if heavy else "agrees" if ok else "**differs**") + (" (left out)" if note else "")
            print(f"| {recipe} | {method} | {reps} x {spp} | {s['max_abs_t']:.2f} | {s['image_t']:.2f} | "
                  f"{100 * s['rel']:+.2f} % | {s['min_p']:.1e} ({s['p_each']:.0e}) | "
                  f"{s['min_skew_p']:.1e} ({s['skew_p_each']:.0e}) | {verdict} | {cpu:.1f} |", flush=True)
    if args.scenes or args.methods:
        return
    print("\n| method | max_depth | replicates x spp | max block abs t | image-mean t | mcvar / Mitsuba - 1 | verdict |")
    print("|---|---|---|---:|---:|---:|---|")
    for mark in T.test_max_depth_means_what_it_means_in_mitsuba.pytestmark:
        if mark.name != "parametrize":
            continue
        for method, depth, (spp, reps) in mark.args[1]:
            s = T.agreement(T.mcvar_replicates("cornell", method, spp, reps, max_depth=depth), f"cornell-d{depth}")
            ok = s["min_p"] > s["p_each"] and s["min_skew_p"] > s["skew_p_each"]
            print(f"| {method} | {depth} | {reps} x {spp} | {s['max_abs_t']:.2f} | {s['image_t']:.2f} | "
                  f"{100 * s['rel']:+.2f} % | {'agrees' if ok else '**differs**'} |", flush=True)
    print("\n| method | knob | values | block error (RMS / mean, light's blocks left out) |")
    print("|---|---|---|---|")
    ref_mean, _, _ = T.reference("cornell")
    direct_view, _, _ = T.reference("cornell-d1")
    keep = T.blocks(direct_view).max(axis=1) == 0
    rb = T.blocks(ref_mean)[keep]
    for method, knob, values, spp, reps in T.BIASED_PLAN:
        errors = []
        for v in values:
            images = (T.mcvar_replicates("cornell", method, v, reps) if knob == "spp"
                      else T.mcvar_replicates("cornell", method, spp, reps, **{knob: v}))
            b = T.blocks(images)[:, keep].mean(axis=0)
            errors.append(float(np.sqrt(np.mean((b - rb) ** 2)) / rb.mean()))
        print(f"| {method} | {knob} | {', '.join(map(str, values))} | "
              f"{' -> '.join(f'{e:.3f}' for e in errors)} |", flush=True)


if __name__ == "__main__":
    main()
