"""mcvar's Cornell box rendered by Mitsuba 3's LLVM variant, timed inside its own process.

Run: ``.venv/bin/python benchmarks/mitsuba_llvm_cornell.py OUT.npz [--spp 256] [--res 64] [--runs 5]
[--sampler multijitter] [--variant llvm_ad_rgb]``

Optional: needs ``mitsuba`` (the ``mitsuba`` extra) and, for the LLVM variants,
a shared libLLVM on the system (e.g. ``apt-get install llvm``).
:mod:`bench_efficiency` runs it in a subprocess so that Mitsuba's threads and
JIT stay out of mcvar's process, and compares its images with the SAME
mcvar reference.

The scene is :func:`mcvar.scene.load_scene` ('cornell', i.e. ``CORNELL.md``)
exported by :func:`mcvar.interop.mitsuba.to_mitsuba` (docs/mitsuba.md): the
same triangles, two-sided Lambertian materials (Mitsuba's ``diffuse`` is
one-sided, hence ``twosided``), the one-sided rectangular light (radiance
emitted along ``cross(v1 - v0, v2 - v0)``, as the PLY faces are wound),
the pinhole camera with a horizontal field of view, and a **box** pixel filter
(Mitsuba's default Gaussian would blur, not estimate, each pixel's mean).
Mitsuba's ``path`` integrator (unlimited depth, Russian roulette from depth
5, MIS between light and BSDF sampling) renders it.

Each image is timed after a warm-up render (JIT compilation, kernel caches),
from ``mi.render`` to the image in NumPy; the output file holds the images
(runs, res, res, 3) and their seconds.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def scene_dict(res: int, sampler: str, spp: int, folder: Path) -> dict:
    """Mitsuba scene dictionary of mcvar's Cornell box (:func:`mcvar.interop.mitsuba.to_mitsuba`),
    its meshes written into ``folder``, with the Mitsuba ``sampler`` plugin."""
    from mcvar.interop.mitsuba import to_mitsuba
    from mcvar.scene import load_scene

    d = to_mitsuba(load_scene("cornell"), res=res, spp=spp, folder=folder)
    d["sensor"]["sampler"] = {"type": sampler, "sample_count": spp}
    return d


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sampler", default="multijitter")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    args = ap.parse_args(argv)
    import mitsuba as mi

    mi.set_variant(args.variant)
    with tempfile.TemporaryDirectory() as tmp:
        scene = mi.load_dict(scene_dict(args.res, args.sampler, args.spp, Path(tmp)))
    np.asarray(mi.render(scene, spp=args.spp, seed=10 ** 6))          # warm-up: JIT, kernel cache
    images, secs = [], []
    for k in range(args.runs):
        t0 = time.perf_counter()
        img = np.array(mi.render(scene, spp=args.spp, seed=args.seed + k), dtype=np.float64)[..., :3]
        secs.append(time.perf_counter() - t0)
        images.append(img)
    np.savez(args.out, images=np.stack(images), seconds=np.array(secs))


if __name__ == "__main__":
    main()
