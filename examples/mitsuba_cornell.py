"""Is Mitsuba 3 unbiased? mcvar's Cornell box, rendered by Mitsuba, as an mcvar target.

Run from this folder (``pip install -e ".[mitsuba]"`` first)::

    mcvar converge --target mitsuba_cornell:evaluate --out out/mitsuba

``evaluate(method, sampler, spp, rng)`` renders one independent image with
Mitsuba's ``scalar_rgb`` variant (plain C++, no LLVM or CUDA needed): method
``'path'`` is Mitsuba's path tracer with Russian roulette and no depth limit,
``'path:3'`` the same stopped at ``max_depth=3``; the sampler is a Mitsuba
sampler plugin name. The scene is mcvar's ``cornell`` (CORNELL.md) exported by
:func:`mcvar.interop.mitsuba.to_mitsuba`: the same triangles, materials, light
and camera, with a box pixel filter. ``reference(rng)`` is one chunk of the reference (the
unbiased path tracer at 1024 spp); mcvar averages 8 from independent seeds.
"""
from functools import lru_cache

import numpy as np

METHODS = ("path", "path:3")
SAMPLERS = ("independent", "multijitter")
SPP = (1, 4, 16, 64)
RES = 64


@lru_cache(maxsize=16)
def _scene(max_depth: int, sampler: str, res: int):
    import mitsuba as mi

    from mcvar.interop.mitsuba import to_mitsuba
    from mcvar.scene import load_scene

    mi.set_variant("scalar_rgb")
    scene = to_mitsuba(load_scene("cornell"), res=res, spp=1, max_depth=max_depth)
    scene["sensor"]["sampler"] = {"type": sampler, "sample_count": 1}
    return mi.load_dict(scene)


def evaluate(method, sampler, spp, rng, *, res=RES):
    """One image (res, res, 3) of linear radiance from ``spp`` samples per pixel."""
    import mitsuba as mi

    name, _, depth = method.partition(":")
    if name != "path" or (depth and not depth.isdigit()):
        raise ValueError(f"method must be 'path' or 'path:DEPTH'; got {method!r}")
    scene = _scene(int(depth) if depth else None, sampler, res)
    seed = int(rng.integers(2 ** 31))  # each replicate: its own Mitsuba seed, drawn from mcvar's stream
    image = mi.render(scene, spp=int(spp), seed=seed)
    return np.array(image, dtype=np.float64)[..., :3]


def reference(rng, *, res=RES, spp=1024):
    """One chunk of the reference: the unbiased path tracer at ``spp`` spp."""
    return evaluate("path", "independent", spp, rng, res=res)
