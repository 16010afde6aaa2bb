"""The shared reference of each scene, rendered once and cached on disk (issue 21).

Every method's equal-time image on a scene is compared with one reference of that scene, rendered by
the method whose estimate is close to normal there (:data:`REFERENCES`; heavy-tailed path tracing
would make a reference whose error hides in a few pixels), in independent chunks whose spread gives
its own noise (the floor under every MSE), and cached keyed by every setting that changes it.
"""
from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._validation import check_count
from . import compare_args as _args
from .compare_args import _names, _options, _seed_sequence, check_compare_args, compare_methods

__all__ = ["REFERENCES", "SceneReference", "scene_reference"]

#: Per scene: (reference method, total reference spp, why that method). Scenes not listed use path tracing.
REFERENCES = {
    "cornell": ("path", 4096, "a large area light that next-event estimation finds from every point: "
                              "path tracing's pixel estimates are close to normal"),
    "cornell-spheres": ("bdpt", 4096, "the glass sphere's caustic reaches path tracing only when a refracted "
                                      "BSDF sample hits the light (heavy-tailed pixels under the sphere); "
                                      "BDPT's light subpaths carry it. 4096 spp: at 512 the reference's own "
                                      "noise in the caustic (8.1e-4) was a third of the MSEs measured there "
                                      "and made SPPM look like the winner"),
    "cornell-point": ("bdpt", 512, "path tracing is heavy-tailed at this point light under the ceiling: six "
                                   "16 x 16 images of 256 spp had means from 0.038 to 0.169 and pixels up to "
                                   "33, where six of BDPT at 16 spp had means from 0.0709 to 0.0721 and no "
                                   "pixel above 3.1 (and light tracing agrees with BDPT)"),
    "cornell-door": ("bdpt", 512, "the light reaches the room only through the door: next-event estimation is "
                                  "blocked from most points and path tracing finds the light through BSDF "
                                  "samples (heavy-tailed); BDPT's light subpaths enter through the door"),
    "cornell-caustic": ("bdpt", 4096, "the caustic under the glass sphere reaches path tracing only when a "
                                      "floor bounce refracts twice onto the small light (16 renders of 32 spp "
                                      "had means from 0.066 to 0.201); BDPT's light subpaths carry it with "
                                      "bounded weights (docs/veach-mis.md). 4096 spp, as for cornell-spheres"),
    "veach-mis": ("path", 4096, "four sphere lights that next-event estimation samples by their cone and "
                                "BSDF sampling finds on the glossy plates, weighted by MIS: path tracing's "
                                "pixel estimates are close to normal (the backdrop's indirect light is "
                                "included, which the direct methods leave out)"),
    "quad-environment": ("path", 4096, "a smooth environment that BSDF and environment sampling find from "
                                       "every point: path tracing's pixel estimates are close to normal "
                                       "(light subpaths from the environment are far noisier: 7.7e-3 against "
                                       "1.3e-5 at 2 s, docs/compare.md)"),
}

#: Version of the cached reference files' layout (part of their key).
_REFERENCE_FORMAT = 2


@dataclass(frozen=True)
class SceneReference:
    """A scene's shared reference image.

    ``value`` (H, W, 3) is the mean of ``chunks`` independent renders of
    ``spp / chunks`` spp by ``method``; ``variance`` (H, W, 3) the variance
    of that mean per pixel (from the chunks' spread) and ``noise`` its mean
    over pixels and channels, the floor under every MSE measured against it;
    ``cached`` whether it was read from the cache instead of rendered.
    """

    scene: str
    method: str
    spp: int
    chunks: int
    value: np.ndarray = field(repr=False)
    variance: np.ndarray = field(repr=False)
    noise: float
    seconds: float
    why: str
    key: str
    cached: bool = False


def _code_key() -> str:
    """A hash of the renderer's source (integrators, scene, tracer, BSDFs, environment maps): a
    reference cached by other code is not reused (read once per reference, a few ms)."""
    root = Path(__file__).resolve().parents[1]
    files = sorted(p for pattern in ("integrators/*.py", "scene*.py", "scene*/*.py", "tracer.py", "bsdf.py",
                                     "envmap.py", "optics.py", "warps.py", "samplers.py")
                   for p in root.glob(pattern))
    digest = hashlib.sha256()
    for f in files:
        digest.update(f.name.encode() + f.read_bytes())
    return digest.hexdigest()[:16]


def _reference_key(scene, res, method, spp, chunks, seed, options) -> str:
    text = json.dumps(dict(v=_REFERENCE_FORMAT, code=_code_key(), scene=scene, res=res, method=method, spp=spp,
                           chunks=chunks,
                           seed=seed, options=sorted((k, repr(v)) for k, v in options.items())), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def scene_reference(scene: str, res: int, *, method: str | None = None, spp: int | None = None,
                    chunks: int = 4, seed: int = 0, cache_dir=None, progress: bool = False) -> SceneReference:
    """The shared reference of ``scene`` at ``res`` (rendered, or read from ``cache_dir``).

    Parameters
    ----------
    scene : str
        A scene name.
    res : int
        Image side in pixels.
    method, spp : optional
        Reference method and total spp; default :data:`REFERENCES` (path
        tracing at 4096 spp for unlisted scenes).
    chunks : int
        Independent renders the spp are split into (their spread gives ``noise``).
    seed : int
        Seed of the reference's streams.
    cache_dir : path, optional
        Folder of ``reference-<scene>-<key>.npz``; the key hashes scene, res,
        method, spp, chunks, seed, the method's options and the renderer's
        source, so a change of any renders a new reference.
    """
    from ..scene import load_scene

    (scene,), _, _, res, chunks = check_compare_args([scene], ["path"], 1.0, res, chunks)
    default = REFERENCES.get(scene, ("path", 4096, "path tracing (no reference chosen for this scene)"))
    method = default[0] if method is None else _names([method], "method", compare_methods())[0]
    spp = default[1] if spp is None else check_count(spp, "spp")
    why = default[2] if method == default[0] else f"{method} (chosen by the caller)"
    if spp < chunks:
        raise ValueError(f"spp must be >= chunks ({chunks}); got {spp}")
    options = _options(method)
    key = _reference_key(scene, res, method, spp, chunks, seed, options)
    path = None
    if cache_dir is not None:
        path = Path(cache_dir) / f"reference-{scene}-{key}.npz"
        if path.exists():
            with np.load(path) as data:
                return SceneReference(scene, method, spp, chunks, data["value"], data["variance"],
                                      float(data["noise"]),
                                      float(data["seconds"]), why, key, cached=True)
    sc = load_scene(scene)
    per = spp // chunks
    streams = _seed_sequence("reference", scene, seed).spawn(chunks)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=chunks, desc=f"reference {scene} ({method}, {spp} spp)", unit="chunk", leave=False)
    start = time.perf_counter()
    images = []
    try:
        for stream in streams:
            r = _args._render(sc, integrator=method, spp=per, res=res, rng=stream, progress=False, **options)
            if r.interrupted:
                raise KeyboardInterrupt
            images.append(np.asarray(r.image, dtype=np.float64))
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - start
    stack = np.stack(images)
    value = stack.mean(axis=0)
    variance = stack.var(axis=0, ddof=1) / chunks if chunks > 1 else np.full_like(value, np.nan)
    noise = float(variance.mean())
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npz")
        np.savez(tmp, value=value, variance=variance, noise=noise, seconds=seconds)
        tmp.replace(path)
    return SceneReference(scene, method, per * chunks, chunks, value, variance, noise, seconds, why, key)

