"""mcvar's scenes for Mitsuba 3: an exporter and a renderer in mcvar's orientation.

A claim checked only against mcvar itself is not checked (issue 26). This
module turns a :class:`~mcvar.scene.Scene` into the scene dictionary that
Mitsuba 3's ``mi.load_dict`` takes, with every element mapped to the Mitsuba
plugin whose model is *the same one*, so that the two engines estimate the
same integral and their images can be compared per block within their
standard errors (``tests/test_mitsuba_reference.py``, docs/mitsuba.md).
Whatever has no counterpart is a ``ValueError`` naming it, never an
approximation.

The mapping
-----------
=========================  ====================================================
mcvar                      Mitsuba 3
=========================  ====================================================
triangles                  a ``ply`` mesh per (material, emission), written once
                           into ``folder`` (content-addressed), ``face_normals``
                           (the geometric normal ``cross(v1 - v0, v2 - v0)``)
spheres                    ``sphere`` (``center``, ``radius``)
``Lambertian(albedo)``     ``twosided`` ``diffuse``: mcvar flips a reflecting
                           surface's normal towards the viewer, so every
                           reflection model is two-sided
``Mirror(reflectance)``    ``twosided`` ``conductor``, ``material: none``
                           (Fresnel 1), ``specular_reflectance`` = reflectance
smooth ``Conductor``       ``twosided`` ``conductor`` with the same ``eta, k``
``Glass(eta, 'exact')``    ``dielectric``, ``int_ior = eta``, ``ext_ior = 1``,
                           tints as ``specular_reflectance/transmittance``
emission (one-sided)       ``area`` emitter on the primitive's shape; emission
                           that is not a light (``prim_light == -1``: found
                           by BSDF sampling only) with ``sampling_weight: 0``
emission (two-sided)       ``area`` towards the only side anything can see
                           (the other side is unobservable: everything else
                           lies on one side of the emitting plane, or inside /
                           outside the emitting sphere); else ``ValueError``
``checker_period``         ``area`` emitter with a ``checkerboard`` texture on
                           texture coordinates ``(x, z) / (2 period)``
point lights               ``point`` (``intensity`` in W/sr, as mcvar's)
constant environment       ``constant``
lat-long environment       ``envmap`` of an EXR resampled so that Mitsuba's
                           bilinear lookup integrates to mcvar's nearest one
                           (see :func:`_envmap_bitmap`), rotated -90 degrees
                           about +y (mcvar's u = 0 is +x, Mitsuba's -z)
``Camera``                 ``perspective``, ``fov`` = ``fov_deg`` on
                           ``fov_axis: x`` (mcvar's field of view is
                           horizontal), ``look_at``
the film                   ``hdrfilm`` RGB float32 with a **box** filter (each
                           pixel the mean over its square, as mcvar's)
=========================  ====================================================

Not exported (``ValueError``): rough ``Conductor`` and ``Microfacet`` (Mitsuba's
``roughconductor`` uses the separable Smith masking ``G1(wo) G1(wi)``, mcvar
the height-correlated ``1 / (1 + Lambda(wo) + Lambda(wi))``: up to 25 % apart
at ``alpha = 0.5``; ``Microfacet`` also uses Schlick's Fresnel), ``Plastic``
(Mitsuba's ``plastic`` diffuse lobe differs from mcvar's by a factor that
depends on the albedo, 1.02 to 2.47 at ``eta = 1.5``), ``Glass`` with
Schlick or constant Fresnel, ``Refractive`` (no Fresnel), ``Retroreflective``,
anisotropic roughness, parallelogram lights without primitives (mcvar samples
them but rays cannot hit them), a checker texture on spheres, and
non-RGB Mitsuba variants (spectral upsampling changes every albedo).
``tests/test_mitsuba_exporter.py`` measures the BSDF values of both engines.

Orientation: Mitsuba's film has row 0 at the top and image right along
``forward x up``, as mcvar's (:class:`~mcvar.scene.Camera`); the tests check
it on the asymmetric Cornell box and with a sparse environment map.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable
import json
import math
import os
import re
import tempfile
from pathlib import Path

import numpy as np

from .._validation import as_rng, check_choice, check_count
from ..bsdf import Conductor, Glass, Lambertian, Mirror
from ..envmap import EnvironmentMap

if TYPE_CHECKING:  # annotations only: importing mcvar.scene here would make a cycle with scene.save_scene
    from ..scene import Scene

#: What a scene must hold to be exported (duck-typed: mcvar.scene imports this
#: module inside save_scene, so this module does not import mcvar.scene).
_SCENE_FIELDS = ("triangles", "sphere_centers", "sphere_radii", "prim_material", "prim_emission", "prim_light",
                 "materials", "material_names", "camera", "light_origin", "point_light_position")

__all__ = ["to_mitsuba", "render_mitsuba", "scene_fingerprint", "INTEGRATORS", "EXPORTER_VERSION"]

#: Mitsuba integrator plugins :func:`to_mitsuba` can ask for: ``path`` (path
#: tracing, NEE + MIS, Russian roulette from depth 5), ``ptracer`` (particle
#: tracing, splats to the film), ``direct`` (one bounce, MIS; depth 2).
INTEGRATORS = ("path", "ptracer", "direct")
#: Bumped whenever the exported dictionary of a scene changes meaning; part of
#: :func:`scene_fingerprint`, so references made by an older exporter are stale.
EXPORTER_VERSION = 1
#: Angle (degrees, about +y) that takes Mitsuba's envmap frame to mcvar's.
ENVMAP_ROTATION_DEG = -90.0
#: Mitsuba's envmap fine grid: at least this many rows, and this many fine
#: texels per mcvar pixel along each axis, unless that exceeds the cap.
_ENV_MIN_ROWS, _ENV_REFINE, _ENV_MAX_TEXELS = 256, 4, 1 << 21


def _mitsuba():
    """Import Mitsuba lazily (an optional extra); pick ``scalar_rgb`` if no variant is set."""
    try:
        import mitsuba as mi
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise ImportError("mcvar.interop.mitsuba needs Mitsuba 3: pip install 'mcvar[mitsuba]'") from exc
    if mi.variant() is None:
        mi.set_variant("scalar_rgb")
    if "_rgb" not in mi.variant():
        raise ValueError(f"the Mitsuba variant must be an RGB one (e.g. 'scalar_rgb', 'llvm_ad_rgb'): mcvar "
                         f"renders linear RGB and spectral upsampling would change every albedo; "
                         f"got {mi.variant()!r}")
    return mi


def _as_res(res) -> tuple[int, int]:
    if isinstance(res, (int, np.integer)) and not isinstance(res, (bool, np.bool_)):
        r = check_count(res, "res")
        return r, r
    if isinstance(res, (tuple, list)) and len(res) == 2:
        return check_count(res[0], "res[0] (width)"), check_count(res[1], "res[1] (height)")
    raise TypeError(f"res must be an int (square image) or a (width, height) pair; got {res!r}")


def _rgb(v) -> dict:
    return {"type": "rgb", "value": [float(x) for x in np.broadcast_to(np.asarray(v, dtype=np.float64), (3,))]}


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]", "_", str(name)) or "m"


# ---------------------------------------------------------------------------
# materials

def _bsdf(material, name: str) -> dict:
    """The Mitsuba BSDF of one mcvar material (same model), or a ``ValueError`` naming it."""
    kind = type(material).__name__
    if type(material) is Lambertian:
        return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": _rgb(material.albedo)}}
    if type(material) is Mirror:
        return {"type": "twosided", "bsdf": {"type": "conductor", "material": "none",
                                             "specular_reflectance": _rgb(material.reflectance)}}
    if type(material) is Conductor:
        if not material.is_delta:
            raise ValueError(
                f"material {name!r}: a rough Conductor (alpha_x={material.alpha_x}) has no Mitsuba counterpart: "
                "Mitsuba's roughconductor uses the separable Smith masking G1(wo) G1(wi), mcvar the "
                "height-correlated 1 / (1 + Lambda(wo) + Lambda(wi)); export smooth conductors only")
        return {"type": "twosided", "bsdf": {"type": "conductor", "eta": _rgb(material.eta), "k": _rgb(material.k)}}
    if type(material) is Glass:
        if material.fresnel != "exact":
            raise ValueError(f"material {name!r}: Glass with fresnel={material.fresnel!r} has no Mitsuba "
                             "counterpart (Mitsuba's dielectric uses the exact Fresnel equations); use 'exact'")
        return {"type": "dielectric", "int_ior": float(material.eta), "ext_ior": 1.0,
                "specular_reflectance": _rgb(material.reflectance),
                "specular_transmittance": _rgb(material.transmittance)}
    why = {
        "Microfacet": "Schlick's Fresnel and height-correlated Smith masking (Mitsuba's roughconductor: "
                      "conductor Fresnel, separable masking)",
        "Plastic": "Mitsuba's plastic/roughplastic couple the diffuse base through the coat differently "
                   "(their diffuse lobe is 1.02x to 2.47x mcvar's at eta 1.5, depending on the albedo)",
        "Refractive": "refraction without Fresnel reflection (Mitsuba's dielectric always reflects F)",
        "Retroreflective": "Mitsuba has no retroreflective BSDF",
    }.get(kind, "not one of Lambertian, Mirror, smooth Conductor, Glass(fresnel='exact')")
    raise ValueError(f"material {name!r} ({kind}) has no Mitsuba counterpart: {why}")


# ---------------------------------------------------------------------------
# files: meshes and environment images, written once by content

def _write_once(folder: Path, stem: str, suffix: str, payload: bytes, write) -> str:
    digest = hashlib.sha256(payload).hexdigest()[:20]
    path = folder / f"{stem}-{digest}{suffix}"
    if not path.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f".{path.name}.{os.getpid()}.tmp{suffix}"
        write(tmp)
        os.replace(tmp, path)
    return str(path)


def _ply_bytes(tris: np.ndarray, uv: np.ndarray | None) -> bytes:
    """A binary little-endian PLY of unshared triangles (3 vertices each)."""
    n_tri = tris.shape[0]
    verts = tris.reshape(-1, 3).astype("<f4")
    props = "property float x\nproperty float y\nproperty float z\n"
    if uv is not None:
        verts = np.concatenate([verts, uv.reshape(-1, 2).astype("<f4")], axis=1)
        props += "property float u\nproperty float v\n"
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {3 * n_tri}\n{props}"
              f"element face {n_tri}\nproperty list uchar int vertex_indices\nend_header\n").encode("ascii")
    faces = np.zeros(n_tri, dtype=[("n", "u1"), ("idx", "<i4", (3,))])
    faces["n"] = 3
    faces["idx"] = np.arange(3 * n_tri, dtype="<i4").reshape(-1, 3)
    return header + np.ascontiguousarray(verts).tobytes() + faces.tobytes()


def _envmap_bitmap(env: EnvironmentMap) -> np.ndarray:
    """The image Mitsuba's ``envmap`` needs to show mcvar's map, shape ``(H', W', 3)`` float32.

    mcvar looks its map up *nearest*: pixel ``(i, j)`` covers
    ``u in [j, j+1) / W``, ``v = theta / pi in [i, i+1) / H``. Mitsuba
    interpolates bilinearly between texels at ``u = (j' + 0.5) / W'`` and
    ``v = i' / (H' - 1)`` (measured with ``emitter.eval``). The fine grid
    ``W' = k W``, ``H' = k H + 1`` puts every mcvar edge half-way between two
    texel columns and on a texel row; texels hold the mean of mcvar's map over
    their cell (the two rows' mean on an edge). A hat-function reconstruction
    of cell means integrates to the same value as the map over every cell
    boundary, so whatever Mitsuba integrates (irradiance, a pixel's footprint)
    matches mcvar's to second order in the fine cell (the ``sin theta``
    weight), and its values differ only within one fine texel of an edge.
    """
    h, w = env.height, env.width
    k = max(_ENV_REFINE, math.ceil(_ENV_MIN_ROWS / h))
    while k > 1 and (k * h + 1) * (k * w) > _ENV_MAX_TEXELS:
        k -= 1
    img = np.asarray(env.image, dtype=np.float64)
    cols = np.repeat(img, k, axis=1)                       # (h, k w, 3): columns are exact
    rows = np.empty((k * h + 1, k * w, 3))
    node = np.arange(k * h + 1)
    inside = node % k != 0
    rows[inside] = cols[node[inside] // k]
    edge = node[~inside] // k                              # edge m between rows m - 1 and m
    above = cols[np.clip(edge - 1, 0, h - 1)]
    below = cols[np.clip(edge, 0, h - 1)]
    rows[~inside] = 0.5 * (above + below)
    return rows.astype(np.float32)


# ---------------------------------------------------------------------------
# emission

def _side_of(points, origin, normal, scale) -> np.ndarray:
    """Signed distances of ``points`` from the plane, in units of ``scale``."""
    return (np.asarray(points, dtype=np.float64).reshape(-1, 3) - origin) @ normal / scale


def _other_points(scene: Scene, skip_tris, skip_spheres):
    """Points that must all lie on one side of a two-sided emitter: the camera,
    point lights, the vertices of other triangles, and other spheres' extremes."""
    keep = np.ones(scene.n_triangles, dtype=bool)
    keep[list(skip_tris)] = False
    pts = [scene.camera.position[None], scene.point_light_position, scene.triangles[keep].reshape(-1, 3)]
    spheres = [s for s in range(scene.n_spheres) if s not in set(skip_spheres)]
    return np.concatenate(pts), spheres


def _triangle_emission_flip(scene: Scene, tri_idx, scale) -> bool:
    """For two-sided emitting triangles: False to emit along their winding, True
    to flip it; a ``ValueError`` when both sides can be seen."""
    tris = scene.triangles[tri_idx]
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    n0 = n[0] / np.linalg.norm(n[0])
    p0 = tris[0, 0]
    what = f"two-sided emission on triangles {list(map(int, tri_idx[:4]))}{'...' if len(tri_idx) > 4 else ''}"
    if np.max(np.abs(_side_of(tris.reshape(-1, 3), p0, n0, scale))) > 1e-9:
        raise ValueError(f"{what}: Mitsuba's area emitter is one-sided, and these triangles are not in one "
                         "plane, so both of their sides may be seen")
    pts, spheres = _other_points(scene, tri_idx, ())
    d = _side_of(pts, p0, n0, scale)
    if spheres:
        c = _side_of(scene.sphere_centers[spheres], p0, n0, scale)
        r = scene.sphere_radii[spheres] / scale
        d = np.concatenate([d, c - r, c + r])
    if np.all(d > 0):
        return False
    if np.all(d < 0):
        return True
    raise ValueError(f"{what}: Mitsuba's area emitter is one-sided, and the camera or other geometry lies on "
                     "both sides of their plane")


def _sphere_emission_inward(scene: Scene, s: int) -> bool:
    """For a two-sided emitting sphere: True if only its inside can be seen."""
    c, r = scene.sphere_centers[s], scene.sphere_radii[s]
    pts, spheres = _other_points(scene, (), (s,))
    dist = np.linalg.norm(pts - c, axis=1)
    oc = np.linalg.norm(scene.sphere_centers[spheres] - c, axis=1) if spheres else np.zeros(0)
    orad = scene.sphere_radii[spheres] if spheres else np.zeros(0)
    inside = np.all(dist < r) and np.all(oc + orad < r) and scene.environment is None
    outside = np.all(dist > r) and np.all(oc - orad > r)
    if inside:
        return True
    if outside:
        return False
    raise ValueError(f"two-sided emission on sphere {s}: Mitsuba's area emitter is one-sided, and the camera "
                     "or other geometry lies both inside and outside it")


def _emitter(le, checker_period, is_light: bool) -> dict:
    """An ``area`` emitter; emission that is not one of mcvar's lights (``prim_light == -1``)
    is found only by BSDF sampling in mcvar, and gets ``sampling_weight: 0`` (never
    chosen by next-event estimation, MIS weight 1 when hit) in Mitsuba too."""
    if checker_period is None:
        e = {"type": "area", "radiance": _rgb(le)}
    else:
        # Mitsuba's checkerboard is color1 where floor(2u) + floor(2v) is odd; with
        # (u, v) = (x, z) / (2 p) that is mcvar's lit square.
        e = {"type": "area", "radiance": {"type": "checkerboard", "color0": _rgb(0.0), "color1": _rgb(le)}}
    if not is_light:
        e["sampling_weight"] = 0.0
    return e


# ---------------------------------------------------------------------------
# the exporter

def _extent(scene: Scene) -> float:
    pts = [scene.camera.position[None], scene.triangles.reshape(-1, 3), scene.point_light_position,
           scene.sphere_centers - scene.sphere_radii[:, None], scene.sphere_centers + scene.sphere_radii[:, None]]
    pts = np.concatenate([p for p in pts if p.size])
    return float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0))) or 1.0


def _check_lights(scene: Scene) -> None:
    """mcvar's parallelogram lights must be the emission of their primitives."""
    for k in range(scene.n_lights):
        prims = np.flatnonzero(scene.prim_light == k)
        if prims.size == 0:
            raise ValueError(f"parallelogram light {k} has no primitives (prim_light == {k}): mcvar samples it, "
                             "but rays cannot hit it; Mitsuba has no such light")
        if not np.allclose(scene.prim_emission[prims], scene.light_radiance[k], rtol=1e-12, atol=0):
            raise ValueError(f"parallelogram light {k}: light_radiance {scene.light_radiance[k].tolist()} differs "
                             "from the emission of its primitives; Mitsuba has one radiance per emitter")
        tris = prims[prims < scene.n_triangles]
        area = 0.5 * np.linalg.norm(np.cross(scene.triangles[tris, 1] - scene.triangles[tris, 0],
                                             scene.triangles[tris, 2] - scene.triangles[tris, 0]), axis=1).sum()
        if tris.size != prims.size or not np.isclose(area, scene.light_area[k], rtol=1e-9):
            raise ValueError(f"parallelogram light {k}: its primitives do not cover it (area {area:g} vs "
                             f"{scene.light_area[k]:g}); Mitsuba samples the emitting shapes themselves")


def to_mitsuba(scene: Scene, *, res, spp: int, integrator: str = "path", max_depth: int | None = None,
               folder=None) -> dict:
    """The Mitsuba 3 scene dictionary of ``scene``, for ``mi.load_dict``.

    Parameters
    ----------
    scene : mcvar.scene.Scene
    res : int or (int, int)
        Square side, or ``(width, height)`` (as :func:`mcvar.integrators.render`).
    spp : int
        The sampler's ``sample_count`` (``independent`` sampler).
    integrator : {'path', 'ptracer', 'direct'}
        Mitsuba's integrator plugin (:data:`INTEGRATORS`).
    max_depth : int or None
        Maximum path segments, as mcvar's: 1 = emitters seen directly, 2 =
        direct light, ...; None is unlimited (Mitsuba's ``-1``, with its
        Russian roulette). ``direct`` takes only None or 2.
    folder : path-like, optional
        Where the triangle meshes (PLY) and environment images (EXR) are
        written, each once, named by their content; default
        ``$TMPDIR/mcvar-mitsuba``.

    Returns
    -------
    dict
        Plain data (strings, numbers, lists, file names) except the
        ``to_world`` values, which are ``mi.ScalarTransform4f`` of the current
        Mitsuba variant (``scalar_rgb`` if none is set). BSDFs are top-level
        entries ``bsdf_<i>_<name>`` referenced by ``{'type': 'ref'}``.

    Raises
    ------
    ValueError
        For anything without a Mitsuba counterpart of the same model (see the
        module docstring), naming it, before any file is written.

    Examples
    --------
    >>> import mitsuba as mi                                  # doctest: +SKIP
    >>> from mcvar.scene import load_scene
    >>> d = to_mitsuba(load_scene("cornell"), res=32, spp=64)  # doctest: +SKIP
    >>> image = mi.render(mi.load_dict(d))                     # doctest: +SKIP
    """
    mi = _mitsuba()
    return scene_dict(scene, res=res, spp=spp, integrator=integrator, max_depth=max_depth, folder=folder,
                      transforms=MitsubaTransforms(
                          look_at=lambda o, t, u: mi.ScalarTransform4f().look_at(origin=o, target=t, up=u),
                          rotate_y=lambda deg: mi.ScalarTransform4f().rotate(axis=[0, 1, 0], angle=deg),
                          write_exr=lambda path, image: mi.Bitmap(image).write(str(path))))


@dataclass(frozen=True)
class MitsubaTransforms:
    """How :func:`scene_dict` builds the dictionary's ``to_world`` values and writes EXR images.

    :func:`to_mitsuba` passes Mitsuba's own (``mi.ScalarTransform4f``,
    ``mi.Bitmap``), for ``mi.load_dict``; :func:`mcvar.scene.save_scene`
    passes XML records and :func:`mcvar.images.write_image`, so that writing a
    scene file needs no Mitsuba.

    Attributes
    ----------
    look_at : callable
        ``look_at(origin, target, up)`` with three lists of 3 floats.
    rotate_y : callable
        ``rotate_y(degrees)``: a rotation about +y.
    write_exr : callable
        ``write_exr(path, image)`` with a float32 ``(H, W, 3)`` image.
    """

    look_at: Callable
    rotate_y: Callable
    write_exr: Callable


def scene_dict(scene: Scene, *, res, spp: int, integrator: str = "path", max_depth: int | None = None,
               folder=None, transforms: MitsubaTransforms) -> dict:
    """:func:`to_mitsuba`'s dictionary with ``transforms`` building its
    ``to_world`` values and writing its EXR images (the one mapping from
    Scene to Mitsuba, shared by :func:`to_mitsuba` and
    :func:`mcvar.scene.save_scene`)."""
    if not all(hasattr(scene, a) for a in _SCENE_FIELDS):
        raise TypeError(f"scene must be a mcvar.scene.Scene (see load_scene); got {type(scene).__name__}")
    width, height = _as_res(res)
    spp = check_count(spp, "spp")
    integrator = check_choice(integrator, "integrator", INTEGRATORS)
    if max_depth is not None:
        max_depth = check_count(max_depth, "max_depth")
    if integrator == "direct" and max_depth not in (None, 2):
        raise ValueError(f"Mitsuba's 'direct' integrator has depth 2; max_depth must be None or 2, got {max_depth}")
    folder = Path(tempfile.gettempdir()) / "mcvar-mitsuba" if folder is None else Path(folder)

    # everything is checked before anything is written
    bsdfs = [_bsdf(m, n) for m, n in zip(scene.materials, scene.material_names)]
    _check_lights(scene)
    extent = _extent(scene)
    if scene.checker_period is not None and np.any(scene.prim_emission[scene.n_triangles:] > 0):
        raise ValueError("checker_period on an emitting sphere has no Mitsuba counterpart (the texture is "
                         "laid out in world x and z, which a sphere's (u, v) cannot follow)")
    env = scene.environment
    if env is not None and not isinstance(env, EnvironmentMap):
        raise ValueError(f"scene.environment must be a mcvar.envmap.EnvironmentMap; got {type(env).__name__}")
    n_tri = scene.n_triangles
    tri_groups: dict = {}
    for t in range(n_tri):
        le = scene.prim_emission[t]
        emits = bool(np.any(le > 0))
        key = (int(scene.prim_material[t]), tuple(le.tolist()) if emits else None,
               bool(scene.prim_two_sided_emission[t]) and emits, bool(scene.prim_light[t] >= 0) and emits)
        tri_groups.setdefault(key, []).append(t)
    flips = {key: (_triangle_emission_flip(scene, np.array(idx), extent) if key[2] else False)
             for key, idx in tri_groups.items()}
    inward = {s: _sphere_emission_inward(scene, s) for s in range(scene.n_spheres)
              if np.any(scene.prim_emission[n_tri + s] > 0) and scene.prim_two_sided_emission[n_tri + s]}

    if not isinstance(transforms, MitsubaTransforms):
        raise TypeError(f"transforms must be a MitsubaTransforms; got {type(transforms).__name__}")
    cam = scene.camera
    d: dict = {"type": "scene"}
    d["integrator"] = {"type": integrator}
    if integrator != "direct":
        d["integrator"].update(max_depth=-1 if max_depth is None else max_depth, hide_emitters=False)
    d["sensor"] = {
        "type": "perspective", "fov": float(cam.fov_deg), "fov_axis": "x",
        "near_clip": 1e-4 * extent, "far_clip": 1e2 * extent,
        "to_world": transforms.look_at([float(x) for x in cam.position], [float(x) for x in cam.look_at],
                                       [float(x) for x in cam.up]),
        "sampler": {"type": "independent", "sample_count": spp},
        "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"},
                 "pixel_format": "rgb", "component_format": "float32"},
    }
    ids = []
    for i, (b, name) in enumerate(zip(bsdfs, scene.material_names)):
        ids.append(f"bsdf_{i}_{_safe(name)}")
        d[ids[-1]] = b
    for g, (key, idx) in enumerate(tri_groups.items()):
        mat, le, _, is_light = key
        tris = scene.triangles[np.array(idx)]
        if flips[key]:
            tris = tris[:, ::-1]
        uv = None
        if le is not None and scene.checker_period is not None:
            uv = tris[..., [0, 2]] / (2.0 * scene.checker_period)
        payload = _ply_bytes(tris, uv)
        path = _write_once(folder, f"mesh{g}", ".ply", payload, lambda p, b=payload: Path(p).write_bytes(b))
        shape = {"type": "ply", "filename": path, "face_normals": True, "bsdf": {"type": "ref", "id": ids[mat]}}
        if le is not None:
            shape["emitter"] = _emitter(le, scene.checker_period, is_light)
        d[f"mesh{g}_{_safe(scene.material_names[mat])}"] = shape
    for s in range(scene.n_spheres):
        mat = int(scene.prim_material[n_tri + s])
        shape = {"type": "sphere", "center": [float(x) for x in scene.sphere_centers[s]],
                 "radius": float(scene.sphere_radii[s]), "bsdf": {"type": "ref", "id": ids[mat]}}
        le = scene.prim_emission[n_tri + s]
        if np.any(le > 0):
            shape["emitter"] = _emitter(le, None, bool(scene.prim_light[n_tri + s] >= 0))
            if inward.get(s, False):
                shape["flip_normals"] = True
        d[f"sphere{s}_{_safe(scene.material_names[mat])}"] = shape
    for p in range(scene.n_point_lights):
        d[f"point{p}"] = {"type": "point", "position": [float(x) for x in scene.point_light_position[p]],
                          "intensity": _rgb(scene.point_light_intensity[p])}
    if env is None and scene.n_lights == 0 and scene.n_point_lights == 0:
        # Mitsuba needs one emitter that next-event estimation can choose; a black
        # point light at the camera keeps every emitter above at sampling weight 0
        d["no_light"] = {"type": "point", "position": [float(x) for x in cam.position], "intensity": _rgb(0.0)}
    if env is not None:
        img = np.asarray(env.image)
        if np.all(img == img[0, 0]):
            d["environment"] = {"type": "constant", "radiance": _rgb(img[0, 0])}
        else:
            bitmap = _envmap_bitmap(env)
            path = _write_once(folder, "envmap", ".exr", bitmap.tobytes() + str(bitmap.shape).encode(),
                               lambda p, b=bitmap: transforms.write_exr(p, b))
            d["environment"] = {"type": "envmap", "filename": path,
                                "to_world": transforms.rotate_y(ENVMAP_ROTATION_DEG)}
    return d


# ---------------------------------------------------------------------------
# fingerprints and rendering

def _canonical(value):
    """JSON-able form of an exported dictionary: transforms as rounded matrices,
    files by their name (which holds their content hash), floats rounded."""
    if isinstance(value, dict):
        return {k: _canonical(v) for k, v in sorted(value.items())}
    if isinstance(value, (list, tuple)):
        return [_canonical(v) for v in value]
    if isinstance(value, bool) or value is None or isinstance(value, int):
        return value
    if isinstance(value, float):
        return float(f"{value:.9g}")
    if isinstance(value, str):
        return os.path.basename(value) if os.sep in value else value
    if hasattr(value, "matrix"):
        return _canonical(np.asarray(value.matrix, dtype=np.float64).tolist())
    raise TypeError(f"cannot fingerprint a {type(value).__name__}")


def scene_fingerprint(scene: Scene, *, res, spp: int, integrator: str = "path", max_depth: int | None = None) -> str:
    """SHA-256 of what :func:`to_mitsuba` exports (and :data:`EXPORTER_VERSION`).

    A stored Mitsuba reference keeps the fingerprint of the scene it rendered;
    when the scene or the exporter changes, the fingerprint does, and a test
    can tell the reference is stale instead of reporting a bias.
    """
    d = to_mitsuba(scene, res=res, spp=spp, integrator=integrator, max_depth=max_depth)
    blob = json.dumps({"exporter": EXPORTER_VERSION, "scene": _canonical(d)}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def render_mitsuba(scene: Scene, *, res, spp: int, rng=None, variant: str = "scalar_rgb",
                   integrator: str = "path", max_depth: int | None = None, folder=None) -> np.ndarray:
    """Render ``scene`` with Mitsuba 3: linear RGB, shape ``(H, W, 3)`` float64, row 0 at the top.

    Parameters
    ----------
    scene, res, spp, integrator, max_depth, folder
        As in :func:`to_mitsuba`.
    rng : None, int, SeedSequence or Generator
        Mitsuba's seed is drawn from it (one 31-bit integer), so independent
        streams (``rng.spawn``) give independent renders.
    variant : str
        A Mitsuba RGB variant (``'scalar_rgb'`` needs no LLVM; ``'llvm_ad_rgb'``
        is faster where libLLVM is installed).
    """
    try:
        import mitsuba as mi
    except ImportError as exc:  # pragma: no cover
        raise ImportError("render_mitsuba needs Mitsuba 3: pip install 'mcvar[mitsuba]'") from exc
    if not isinstance(variant, str) or variant not in mi.variants():
        raise ValueError(f"variant must be one of Mitsuba's {tuple(mi.variants())}; got {variant!r}")
    if "_rgb" not in variant:
        raise ValueError(f"variant must be an RGB variant (mcvar renders linear RGB); got {variant!r}")
    gen = as_rng(rng)
    if mi.variant() != variant:
        mi.set_variant(variant)
    d = to_mitsuba(scene, res=res, spp=spp, integrator=integrator, max_depth=max_depth, folder=folder)
    seed = int(gen.integers(2 ** 31))
    image = mi.render(mi.load_dict(d), spp=check_count(spp, "spp"), seed=seed)
    return np.array(image, dtype=np.float64)[..., :3]
