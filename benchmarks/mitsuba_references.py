"""Mitsuba 3 references of mcvar's scenes, for ``tests/test_mitsuba_reference.py``.

Run: ``python benchmarks/mitsuba_references.py [--out tests/data/mitsuba] [--only NAME ...]
[--seeds 8] [--spp 8192] [--res 16] [--variant scalar_rgb]``

Every case of :data:`CASES` is a scene (a built-in one, possibly modified by
:func:`build_scene`) rendered by Mitsuba through
:func:`mcvar.interop.mitsuba.to_mitsuba`, ``--seeds`` times from independent
seeds at ``--spp`` samples per pixel each. ``NAME.npy`` holds float32
``(2, H, W, 3)``: the per-pixel mean over the seeds and its standard error
(the seeds' standard deviation / sqrt(seeds)), so a test knows the
reference's own noise. ``NAME.json`` holds the settings and the exporter's
:func:`~mcvar.interop.mitsuba.scene_fingerprint`: when the scene or the
exporter changes, the test sees a stale reference instead of a bias.
Nothing is rendered at test time.

Which Mitsuba integrator makes each reference is a choice per case: the
built-in ``cornell-point`` (all depths and depth 2) is rendered by particle
tracing (``ptracer``), because its camera-side estimates are heavy-tailed:
the ceiling spot 1 unit above the light, in view of the camera, is a tiny,
extremely bright part of its pixels that camera rays find only by luck
(docs/mitsuba.md, 'Heavy tails'); particles reach it in proportion to its
irradiance. ``cornell-caustic`` (all depths) is rendered by particle tracing
too: its caustic under the glass sphere, lit by a light of 1/100 the Cornell
area, is found by camera paths only when a diffuse bounce refracts through
the sphere onto the light, so Mitsuba's ``path`` is as heavy-tailed there as
mcvar's (and the caustic lights the whole room); particles reach it
directly. The particle tracer renders what the camera sees through or in the
glass black (no connection to a pinhole through a delta vertex), as mcvar's
``light`` does, so the tests compare off the sphere; its depth-2 reference
(direct light, no caustic) is Mitsuba's ``path``.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parents[1] / "tests" / "data" / "mitsuba"

#: name -> (scene recipe, Mitsuba integrator, max_depth). A recipe is a
#: built-in scene's name or one of :data:`CUSTOM_SCENES`.
CASES = {
    "cornell": ("cornell", "path", None),
    "cornell-d1": ("cornell", "path", 1),
    "cornell-d2": ("cornell", "path", 2),
    "cornell-d3": ("cornell", "path", 3),
    "cornell-spheres": ("cornell-spheres", "path", None),
    "cornell-spheres-d2": ("cornell-spheres", "path", 2),
    "cornell-point": ("cornell-point", "ptracer", None),
    "cornell-point-d2": ("cornell-point", "ptracer", 2),
    "cornell-point-low": ("cornell-point-low", "path", None),
    "cornell-point-low-d2": ("cornell-point-low", "path", 2),
    "checkerboard": ("checkerboard", "path", None),
    "checkerboard-d2": ("checkerboard", "path", 2),
    "furnace": ("furnace", "path", None),
    "furnace-d2": ("furnace", "path", 2),
    "quad-environment": ("quad-environment", "path", None),
    "quad-environment-d2": ("quad-environment", "path", 2),
    "cornell-door": ("cornell-door", "path", None),
    "cornell-door-d2": ("cornell-door", "path", 2),
    "sphere-sparse-env": ("sphere-sparse-env", "path", None),
    "sphere-sparse-env-d2": ("sphere-sparse-env", "path", 2),
    "cornell-caustic": ("cornell-caustic", "ptracer", None),
    "cornell-caustic-d2": ("cornell-caustic", "path", 2),
}

#: Scenes made here from built-in ones (issue 26):
#: ``cornell-point-low``: the point light lowered to y = 448.8 (100 units
#: below the ceiling), where path tracing is well behaved;
#: ``sphere-sparse-env``: a Lambertian sphere under mcvar's sparse-lights
#: environment, seen with the map behind it (which side is lit tests the
#: map's orientation).
CUSTOM_SCENES = ("cornell-point-low", "sphere-sparse-env")


def build_scene(recipe: str):
    """The :class:`~mcvar.scene.Scene` of a case's recipe."""
    from mcvar.scene import SCENES, load_scene

    if recipe in SCENES:
        return load_scene(recipe)
    if recipe == "cornell-point-low":
        scene = load_scene("cornell-point")
        pos = np.array(scene.point_light_position)
        pos[:, 1] = 448.8
        return dataclasses.replace(scene, name="cornell-point-low", point_light_position=pos)
    if recipe == "sphere-sparse-env":
        from mcvar.bsdf import Lambertian
        from mcvar.envmap import sparse_lights
        from mcvar.scene import Camera, Scene

        return Scene(
            name="sphere-sparse-env", description="Lambertian sphere under the sparse-lights map",
            triangles=np.zeros((0, 3, 3)), sphere_centers=[(0.0, 0.0, 0.0)], sphere_radii=[1.0],
            prim_material=[0], prim_emission=np.zeros((1, 3)), prim_two_sided_emission=[False],
            prim_light=[-1], prim_group=[0], materials=(Lambertian((0.8, 0.8, 0.8)),),
            material_names=("white",), light_origin=np.zeros((0, 3)), light_edge1=np.zeros((0, 3)),
            light_edge2=np.zeros((0, 3)), light_radiance=np.zeros((0, 3)),
            camera=Camera((0.0, 0.0, -3.5), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 45.0),
            environment=sparse_lights(height=64, width=128), ray_epsilon=1e-5)
    raise ValueError(f"unknown scene recipe {recipe!r}")


def make_reference(name: str, *, res: int, spp: int, seeds: int, variant: str, out: Path, seed: int = 2026):
    """Render case ``name`` ``seeds`` times; write ``NAME.npy`` and ``NAME.json`` into ``out``."""
    import mitsuba as mi

    from mcvar.interop.mitsuba import EXPORTER_VERSION, render_mitsuba, scene_fingerprint

    recipe, integrator, max_depth = CASES[name]
    scene = build_scene(recipe)
    start = time.perf_counter()
    streams = np.random.default_rng(seed).spawn(seeds)
    images = np.stack([render_mitsuba(scene, res=res, spp=spp, rng=s, variant=variant, integrator=integrator,
                                      max_depth=max_depth) for s in streams])
    seconds = time.perf_counter() - start
    mean = images.mean(axis=0)
    se = images.std(axis=0, ddof=1) / np.sqrt(seeds)
    out.mkdir(parents=True, exist_ok=True)
    np.save(out / f"{name}.npy", np.stack([mean, se]).astype(np.float32))
    settings = dict(name=name, scene=recipe, integrator=integrator, max_depth=max_depth, res=res,
                    spp_per_seed=spp, seeds=seeds, seed=seed, variant=variant, mitsuba=mi.__version__,
                    exporter=EXPORTER_VERSION,
                    fingerprint=scene_fingerprint(scene, res=res, spp=spp, integrator=integrator,
                                                  max_depth=max_depth),
                    image_mean=[float(x) for x in mean.mean(axis=(0, 1))],
                    image_mean_se=[float(x) for x in np.sqrt((se ** 2).sum(axis=(0, 1))) / (res * res)],
                    seconds=round(seconds, 1))
    (out / f"{name}.json").write_text(json.dumps(settings, indent=1) + "\n")
    return settings


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--only", nargs="*", default=None, help="case names (default: all)")
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--spp", type=int, default=8192)
    ap.add_argument("--res", type=int, default=16)
    ap.add_argument("--variant", default="scalar_rgb")
    args = ap.parse_args(argv)
    import mitsuba as mi

    mi.set_variant(args.variant)
    mi.set_log_level(mi.LogLevel.Warn)              # no progress bars in the log
    names = list(CASES) if not args.only else args.only
    for name in names:
        if name not in CASES:
            raise SystemExit(f"unknown case {name!r}; known: {', '.join(CASES)}")
    for name in names:
        s = make_reference(name, res=args.res, spp=args.spp, seeds=args.seeds, variant=args.variant, out=args.out)
        print(f"{name:22s} {s['integrator']:8s} depth {s['max_depth']!s:4s} mean {np.round(s['image_mean'], 5)} "
              f"+- {np.round(s['image_mean_se'], 6)}  {s['seconds']} s", flush=True)


if __name__ == "__main__":
    main()
