"""Scenes as plain arrays, and the pinhole camera (layer 4).

A :class:`Scene` is immutable data: triangles and spheres with one material
and one emitted radiance per primitive, the area lights that next-event
estimation samples, an optional environment map and a :class:`Camera`.
Every call of :func:`load_scene` builds fresh read-only arrays; nothing here is
a module-level mutable global. The Cornell box's numbers are stored as Python
tuples (``CORNELL_QUADS`` ...), transcribed from ``shared/scenes/CORNELL.md``,
so that an installed package needs no data file; a test checks them against
``cornell.json``.

Scenes
------
``cornell``
    The original Cornell box measured data, exactly per CORNELL.md: 16 quads
    split into 32 triangles ``(v0, v1, v2)``, ``(v0, v2, v3)``, two-sided
    Lambertian walls, a one-sided 130 x 105 area light of radiance
    (17, 12, 4) facing down, no environment, the 35 mm pinhole camera.
``cornell-spheres``
    The same room with the two blocks replaced by a mirror sphere and a glass
    sphere (index 1.5): the lecture's 'Direct + Reflection + Refraction' vs
    'Global' pair.
``cornell-point``
    The Cornell box with the area light replaced by a point light of the same
    power at its centre, 1 unit below the ceiling (issue 11): the lecture's
    'backward path tracing fails for point lights'.
``checkerboard``
    An emissive checkerboard plane seen in perspective down to the horizon:
    every pixel is the image-plane integral of a 0/1 pattern over its
    footprint (no light transport at all), the classic aliasing target of the
    lecture's sampling slides.
``furnace``
    The camera inside a closed Lambertian sphere of albedo ``rho`` that emits
    ``Le`` everywhere: every pixel converges to ``Le / (1 - rho)``.
``quad-environment``
    A Lambertian quad of albedo ``rho`` filling the view, under a constant
    environment of radiance ``L``: every pixel converges to ``rho * L``.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping

import numpy as np

from ._validation import as_array, as_rgb, check_positive
from .bsdf import BSDF, Conductor, Glass, Lambertian, Mirror
from .envmap import EnvironmentMap
from .geometry import normalize
from .scenefile import read_scene_file

__all__ = [
    "Camera",
    "Scene",
    "SCENES",
    "load_scene",
    "cornell_scene",
    "cornell_spheres_scene",
    "cornell_point_scene",
    "checkerboard_scene",
    "furnace_scene",
    "quad_environment_scene",
    "CORNELL_QUADS",
    "CORNELL_ALBEDO",
    "CORNELL_LIGHT_RADIANCE",
    "CORNELL_CAMERA",
]

# --------------------------------------------------------------------------
# The Cornell box, transcribed from shared/scenes/CORNELL.md (tests compare it
# with cornell.json). Each quad (v0, v1, v2, v3) is split into the triangles
# (v0, v1, v2) and (v0, v2, v3); the measured quads are not all planar, so the
# split is part of the scene.
CORNELL_QUADS = (
    ("floor", "white", ((552.8, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 559.2), (549.6, 0.0, 559.2))),
    ("ceiling", "white", ((556.0, 548.8, 0.0), (556.0, 548.8, 559.2), (0.0, 548.8, 559.2), (0.0, 548.8, 0.0))),
    ("back_wall", "white", ((549.6, 0.0, 559.2), (0.0, 0.0, 559.2), (0.0, 548.8, 559.2), (556.0, 548.8, 559.2))),
    ("green_wall", "green", ((0.0, 0.0, 559.2), (0.0, 0.0, 0.0), (0.0, 548.8, 0.0), (0.0, 548.8, 559.2))),
    ("red_wall", "red", ((552.8, 0.0, 0.0), (549.6, 0.0, 559.2), (556.0, 548.8, 559.2), (556.0, 548.8, 0.0))),
    ("short_top", "white", ((130.0, 165.0, 65.0), (82.0, 165.0, 225.0), (240.0, 165.0, 272.0), (290.0, 165.0, 114.0))),
    ("short_side1", "white", ((290.0, 0.0, 114.0), (290.0, 165.0, 114.0), (240.0, 165.0, 272.0), (240.0, 0.0, 272.0))),
    ("short_side2", "white", ((130.0, 0.0, 65.0), (130.0, 165.0, 65.0), (290.0, 165.0, 114.0), (290.0, 0.0, 114.0))),
    ("short_side3", "white", ((82.0, 0.0, 225.0), (82.0, 165.0, 225.0), (130.0, 165.0, 65.0), (130.0, 0.0, 65.0))),
    ("short_side4", "white", ((240.0, 0.0, 272.0), (240.0, 165.0, 272.0), (82.0, 165.0, 225.0), (82.0, 0.0, 225.0))),
    ("tall_top", "white", ((423.0, 330.0, 247.0), (265.0, 330.0, 296.0), (314.0, 330.0, 456.0), (472.0, 330.0, 406.0))),
    ("tall_side1", "white", ((423.0, 0.0, 247.0), (423.0, 330.0, 247.0), (472.0, 330.0, 406.0), (472.0, 0.0, 406.0))),
    ("tall_side2", "white", ((472.0, 0.0, 406.0), (472.0, 330.0, 406.0), (314.0, 330.0, 456.0), (314.0, 0.0, 456.0))),
    ("tall_side3", "white", ((314.0, 0.0, 456.0), (314.0, 330.0, 456.0), (265.0, 330.0, 296.0), (265.0, 0.0, 296.0))),
    ("tall_side4", "white", ((265.0, 0.0, 296.0), (265.0, 330.0, 296.0), (423.0, 330.0, 247.0), (423.0, 0.0, 247.0))),
    ("light", "light", ((343.0, 548.7, 227.0), (343.0, 548.7, 332.0), (213.0, 548.7, 332.0), (213.0, 548.7, 227.0))),
)
#: Triangulation of every quad: vertex indices into (v0, v1, v2, v3).
CORNELL_TRIANGULATION = ((0, 1, 2), (0, 2, 3))
#: Lambertian albedo per material, linear RGB (BRDF = albedo / pi).
CORNELL_ALBEDO = (
    ("white", (0.725, 0.71, 0.68)),
    ("red", (0.63, 0.065, 0.05)),
    ("green", (0.14, 0.45, 0.091)),
    ("light", (0.0, 0.0, 0.0)),
)
#: Radiance of the light quad, emitted only to the side of cross(v1-v0, v2-v0) = -y.
CORNELL_LIGHT_RADIANCE = (17.0, 12.0, 4.0)
#: Pinhole: position, look-at, up and full field of view in degrees (2 atan(12.5 / 35)).
CORNELL_CAMERA = ((278.0, 273.0, -800.0), (278.0, 273.0, -799.0), (0.0, 1.0, 0.0),
                  math.degrees(2.0 * math.atan(12.5 / 35.0)))


def _frozen(a, dtype=np.float64) -> np.ndarray:
    arr = np.array(a, dtype=dtype)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera, exactly as ``CORNELL.md`` specifies.

    Parameters
    ----------
    position, look_at, up : array_like, shape (3,)
        Eye point, a point it looks at, and the up hint.
    fov_deg : float
        Full horizontal field of view in degrees, in (0, 180).

    Notes
    -----
    With ``forward = normalize(look_at - position)``,
    ``right = normalize(forward x up)`` and ``up' = right x forward`` (for the
    Cornell camera: forward = +z, up = +y, right = -x: world -x is image
    right), pixel column ``j``, row ``i`` (row 0 at the top) of a ``W x H``
    image and a sample offset ``(u, v)`` in [0, 1)^2 give::

        x = (j + u) / W,  y = (i + v) / H,  t = tan(fov / 2)
        d = normalize(forward + (2x - 1) t right + (1 - 2y) t (H / W) up')

    ``H / W = 1`` for the square images of the specification; for other
    shapes the field of view is horizontal (``fov_axis: x`` in cornell.json)
    and pixels stay square.
    """

    position: np.ndarray
    look_at: np.ndarray
    up: np.ndarray
    fov_deg: float

    def __post_init__(self):
        pos = _frozen(as_array(self.position, "position", ndim=1, last=3))
        at = _frozen(as_array(self.look_at, "look_at", ndim=1, last=3))
        up = _frozen(as_array(self.up, "up", ndim=1, last=3))
        fov = check_positive(self.fov_deg, "fov_deg")
        if not fov < 180.0:
            raise ValueError(f"fov_deg must lie in (0, 180); got {fov}")
        forward = at - pos
        if not np.linalg.norm(forward) > 0:
            raise ValueError("look_at must differ from position")
        if not np.linalg.norm(np.cross(forward, up)) > 0:
            raise ValueError("up must not be parallel to the viewing direction")
        object.__setattr__(self, "position", pos)
        object.__setattr__(self, "look_at", at)
        object.__setattr__(self, "up", up)
        object.__setattr__(self, "fov_deg", fov)

    def basis(self):
        """Return ``(forward, right, up)``: orthonormal world vectors of the image axes."""
        forward = normalize(self.look_at - self.position)
        right = normalize(np.cross(forward, self.up))
        up = np.cross(right, forward)
        return forward, right, up

    def ray_directions(self, res, pixel, offsets) -> np.ndarray:
        """Unit world directions of primary rays, shape ``(n, 3)`` float64.

        Parameters
        ----------
        res : tuple of int
            ``(W, H)``.
        pixel : array_like of int, shape (n,)
            Flat pixel index ``i * W + j`` (row ``i`` from the top, column ``j``).
        offsets : array_like, shape (n, 2)
            Sample position ``(u, v)`` inside the pixel, in [0, 1]^2.
        """
        return np.ascontiguousarray(self.ray_directions_soa(res, pixel, offsets).T)

    def ray_directions_soa(self, res, pixel, offsets) -> np.ndarray:
        """:meth:`ray_directions` as structure-of-arrays, shape ``(3, n)`` float64.

        The layout of the wavefront loop (:mod:`mcvar.integrators`): the
        components are built row by row, so no ``(n, 3)`` temporaries and no
        transposing copy (measured: 65 536 rays 4.6 -> 1.9 ms).
        Arguments as in :meth:`ray_directions`.
        """
        width, height = res
        pixel = np.asarray(pixel)
        offsets = np.asarray(offsets, dtype=np.float64)
        row, col = np.divmod(pixel, width)
        t = math.tan(math.radians(self.fov_deg) / 2.0)
        sx = col + offsets[:, 0]
        sx *= 2.0 * t / width
        sx -= t
        sy = row + offsets[:, 1]
        sy *= -2.0 * t / width
        sy += t * (height / width)
        forward, right, up = self.basis()
        d = np.empty((3, pixel.shape[0]))
        for c in range(3):
            np.multiply(sx, right[c], out=d[c])
            d[c] += forward[c]
            d[c] += sy * up[c]
        norm = d[0] * d[0]
        norm += d[1] * d[1]
        norm += d[2] * d[2]
        np.sqrt(norm, out=norm)
        d /= norm
        return d

    # ------------------------------------------------------------------
    # The pinhole as a sensor: projection, importance and its pdfs
    # (light tracing and BDPT connect to the camera; pbrt-v4's
    # PerspectiveCamera::We / PDF_We / SampleWi, Veach 1997 sec. 10.3)

    def film_area(self, res) -> float:
        """Area ``A`` of the film on the plane at distance 1 in front of the pinhole.

        ``A = (2 t)^2 H / W`` with ``t = tan(fov / 2)`` (horizontal field of
        view, square pixels); one pixel covers ``A / (W H)``.
        """
        width, height = _film_res(res)
        t = math.tan(math.radians(self.fov_deg) / 2.0)
        return 4.0 * t * t * height / width

    def _plane_coords(self, directions):
        """``(x, y, cos)``: where world directions (n, 3) cross the plane at
        distance 1 (image right and up), and their cosine with ``forward``."""
        forward, right, up = self.basis()
        d = np.asarray(directions, dtype=np.float64)
        cos = d @ forward
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.where(cos > 0.0, 1.0 / cos, 0.0)
        return (d @ right) * inv, (d @ up) * inv, cos

    def _raster(self, res, directions):
        """Continuous pixel coordinates ``(col + u, row + v)`` of directions
        and whether each lies in the frame (in front of the pinhole)."""
        width, height = _film_res(res)
        t = math.tan(math.radians(self.fov_deg) / 2.0)
        x, y, cos = self._plane_coords(directions)
        scale = width / (2.0 * t)
        px = (x + t) * scale
        py = (t * height / width - y) * scale
        visible = (cos > 0.0) & (px >= 0.0) & (px < width) & (py >= 0.0) & (py < height)
        return np.stack([px, py], axis=-1), visible, cos

    def project(self, points, res):
        """Pixel coordinates of world points: the inverse of :meth:`ray_directions`.

        Parameters
        ----------
        points : array_like, shape (n, 3)
            World points.
        res : tuple of int
            ``(W, H)``.

        Returns
        -------
        pixel_xy : ndarray, shape (n, 2)
            ``(j + u, i + v)``: column plus offset and row plus offset, so the
            ray of pixel ``(i, j)`` with sample offset ``(u, v)`` projects back
            to it. Meaningless where ``visible`` is False.
        visible : ndarray of bool, shape (n,)
            The point is in front of the pinhole and inside the frame
            (``0 <= j + u < W``, ``0 <= i + v < H``). Occlusion is not tested.
        """
        p = as_array(points, "points", ndim=2, last=3)
        v = p - self.position
        r = np.sqrt(np.einsum("ij,ij->i", v, v))
        with np.errstate(divide="ignore", invalid="ignore"):
            d = v / np.where(r > 0.0, r, 1.0)[:, None]
        pixel_xy, visible, _ = self._raster(res, d)
        visible &= r > 0.0
        return pixel_xy, visible

    def pixel_index(self, pixel_xy, res) -> np.ndarray:
        """Flat pixel index ``i * W + j`` of pixel coordinates from :meth:`project`."""
        width, height = _film_res(res)
        xy = np.asarray(pixel_xy, dtype=np.float64)
        col = np.clip(np.floor(xy[:, 0]).astype(np.int64), 0, width - 1)
        row = np.clip(np.floor(xy[:, 1]).astype(np.int64), 0, height - 1)
        return row * width + col

    def We(self, directions, res) -> np.ndarray:
        """Importance ``W_e(omega)`` of the pinhole for rays leaving it along ``directions``.

        Parameters
        ----------
        directions : array_like, shape (n, 3)
            Unit world directions from the pinhole.
        res : tuple of int
            ``(W, H)``.

        Returns
        -------
        ndarray, shape (n,)
            ``1 / (A cos^4 theta)`` inside the frame, 0 outside (``A`` =
            :meth:`film_area`, ``theta`` the angle to ``forward``).

        Notes
        -----
        Normalisation (the one pbrt-v4's ``PerspectiveCamera::We`` uses, with
        the film at distance 1): a pixel value of mcvar is the mean radiance
        over the pixel square of the film (box filter, CORNELL.md),
        ``I_j = (1 / A_pix) int_pixel L(omega(x)) dx``. With
        ``d omega = cos^3 theta dx`` this is
        ``I_j = int W_j(omega) L(omega) cos theta d omega`` with
        ``W_j = 1 / (A_pix cos^4 theta)`` on pixel ``j``, and
        ``sum_j W_j = W H * We`` with ``We = 1 / (A cos^4 theta)``.
        Light tracing with ``N = W H spp`` light paths therefore estimates
        pixel ``j`` as ``(1 / spp) sum (contributions with We landing in
        j)``: image = splat sum / spp, the same normalisation as a camera
        render of ``spp`` samples per pixel. ``We`` integrates to 1 against
        ``cos theta d omega`` over the frame.
        """
        d = as_array(directions, "directions", ndim=2, last=3)
        _, visible, cos = self._raster(res, d)
        with np.errstate(divide="ignore", invalid="ignore"):
            we = 1.0 / (self.film_area(res) * cos ** 4)
        return np.where(visible, we, 0.0)

    def pdf_We(self, directions, res):
        """Densities of the camera's primary rays (pixel uniform over the film).

        Returns
        -------
        pdf_pos : ndarray, shape (n,)
            1: the pinhole is a single point (a Dirac delta in area measure,
            as for a point light); strategies that would have to hit it get
            probability zero (Veach 1997, sec. 10.3.5).
        pdf_dir : ndarray, shape (n,)
            ``1 / (A cos^3 theta)`` per unit solid angle inside the frame,
            else 0: a uniform point on the film of area ``A`` at distance 1
            (``dx = d omega / cos^3 theta``).
        """
        d = as_array(directions, "directions", ndim=2, last=3)
        _, visible, cos = self._raster(res, d)
        with np.errstate(divide="ignore", invalid="ignore"):
            pdf = 1.0 / (self.film_area(res) * cos ** 3)
        return np.ones(d.shape[0]), np.where(visible, pdf, 0.0)

    def sample_Wi(self, points, res):
        """Connect world points to the pinhole (pbrt-v4's ``SampleWi``).

        Parameters
        ----------
        points : array_like, shape (n, 3)
        res : tuple of int

        Returns
        -------
        wi : ndarray, shape (n, 3)
            Unit directions from the points towards the pinhole.
        dist : ndarray, shape (n,)
        We : ndarray, shape (n,)
            Importance of the ray from the pinhole towards each point (0
            outside the frame).
        pdf : ndarray, shape (n,)
            Density of choosing the pinhole, per unit solid angle at the
            point: ``dist^2 / cos theta`` (a delta in position converted to
            solid angle, pbrt's convention), so that a light-tracing vertex
            contributes ``beta f |cos| We / pdf``.
        pixel_xy : ndarray, shape (n, 2)
        visible : ndarray of bool, shape (n,)
        """
        p = as_array(points, "points", ndim=2, last=3)
        v = self.position - p
        dist = np.sqrt(np.einsum("ij,ij->i", v, v))
        with np.errstate(divide="ignore", invalid="ignore"):
            wi = v / np.where(dist > 0.0, dist, 1.0)[:, None]
        pixel_xy, visible, cos = self._raster(res, -wi)
        visible &= dist > 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            we = np.where(visible, 1.0 / (self.film_area(res) * cos ** 4), 0.0)
            pdf = np.where(visible, dist * dist / cos, 0.0)
        return wi, dist, we, pdf, pixel_xy, visible


def _film_res(res):
    """``(W, H)`` as positive ints (the image size a camera method is asked about)."""
    try:
        width, height = res
    except (TypeError, ValueError):
        raise TypeError(f"res must be a (width, height) pair; got {res!r}") from None
    for v, name in ((width, "res[0] (width)"), (height, "res[1] (height)")):
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{name} must be a positive int; got {v!r}")
    return int(width), int(height)


#: Largest coordinate magnitude of scene geometry (vertices, sphere centres
#: and radii, light corners and edges, point lights): the tracer's float32
#: geometry squares coordinate differences, which stay finite in float32 (max
#: 3.4e38) below about 1.8e19; 1e18 leaves room for sums of three squares.
MAX_COORDINATE = 1e18


def _scene_array(value, name: str, row: tuple, dtype=np.float64, *, nonnegative: bool = False) -> np.ndarray:
    """A Scene field as a read-only array of shape ``(n,) + row``: an empty
    input is ``(0,) + row``; another shape, NaN/Inf, (for floats) a negative
    entry where ``nonnegative``, or a value that is not a whole number in an
    integer table is a ValueError naming the field."""
    if isinstance(value, (str, bytes)):
        raise TypeError(f"{name} must be an array of shape (n, {', '.join(map(str, row))}); got a string")
    if np.dtype(dtype) == np.float64:
        arr = as_array(value, name, nonnegative=nonnegative)
    else:
        try:
            raw = np.asarray(value)
        except (TypeError, ValueError) as exc:
            raise TypeError(f"{name} must be an array; got {type(value).__name__}") from exc
        if raw.size and raw.dtype.kind not in ("b" if dtype is bool else "biu"):
            if dtype is bool or raw.dtype.kind != "f" or not np.all(np.isfinite(raw)) \
                    or not np.all(raw == np.round(raw)):
                raise ValueError(f"{name} must hold {'booleans' if dtype is bool else 'integers'}; got dtype "
                                 f"{raw.dtype}")
        arr = raw.astype(dtype)
    if arr.size == 0:
        arr = arr.reshape((0,) + row)
    if arr.shape[1:] != row or arr.ndim != 1 + len(row):
        want = "(n" + "".join(f", {r}" for r in row) + ")" if row else "(n,)"
        raise ValueError(f"{name} must have shape {want}; got shape {arr.shape}")
    arr = np.array(arr, dtype=dtype)
    arr.flags.writeable = False
    return arr


def _check_coordinates(arr: np.ndarray, name: str) -> None:
    """Geometry within +-:data:`MAX_COORDINATE` (finite is checked already)."""
    if arr.size and not np.all(np.abs(arr) <= MAX_COORDINATE):
        raise ValueError(f"{name} must have coordinates within +-{MAX_COORDINATE:g} (the tracer's float32 "
                         f"geometry squares them); got {float(np.abs(arr).max())!r}")


@dataclass(frozen=True, eq=False)
class Scene:
    """Immutable scene data: primitives, materials, emitters and camera.

    Primitives are numbered triangles first (``0 .. T-1``) then spheres
    (``T .. T+S-1``); every per-primitive table is indexed by that number.

    Attributes
    ----------
    name : str
    triangles : ndarray, shape (T, 3, 3)
        Triangle vertices; the geometric normal is ``cross(v1 - v0, v2 - v0)``.
    sphere_centers : ndarray, shape (S, 3)
    sphere_radii : ndarray, shape (S,)
    prim_material : ndarray of int, shape (T + S,)
        Index into ``materials``.
    prim_emission : ndarray, shape (T + S, 3)
        Emitted radiance (linear RGB, >= 0).
    prim_two_sided_emission : ndarray of bool, shape (T + S,)
        False: a triangle emits only to the side of its geometric normal, a
        sphere only outwards.
    prim_light : ndarray of int, shape (T + S,)
        Index of the area light a primitive belongs to, -1 if none. Emission
        of primitives without a light is found only by BSDF sampling
        (its MIS weight is 1).
    prim_group : ndarray of int, shape (T + S,)
        Triangles of group g > 0 are culled by the group's bounding box in
        :mod:`mcvar.tracer`; group 0 is always tested.
    materials : tuple
        :mod:`mcvar.bsdf` objects (``Lambertian``, ``Mirror``, ``Glass``).
    material_names : tuple of str
    light_origin, light_edge1, light_edge2 : ndarray, shape (L, 3)
        Parallelogram area lights ``origin + a edge1 + b edge2``,
        ``(a, b)`` in [0, 1]^2, emitting ``light_radiance`` only to the side of
        ``cross(edge1, edge2)``.
    light_radiance : ndarray, shape (L, 3)
    environment : mcvar.envmap.EnvironmentMap or None
        Radiance arriving from infinitely far away (rays that miss everything).
    camera : Camera
    checker_period : float or None
        If set, the emission of every triangle is multiplied by the checker
        pattern ``(floor(x / p) + floor(z / p)) mod 2`` of the hit point.
    ray_epsilon : float
        Offset along the normal of secondary ray origins (scene units).
    point_light_position : ndarray, shape (P, 3)
        Point lights (default none): a position each, no surface. Nothing
        can hit them, so only methods that connect to lights see them
        (next-event estimation, light tracing, BDPT); ``path_bsdf`` renders
        their illumination black (the lecture's 'probability zero' path).
    point_light_intensity : ndarray, shape (P, 3)
        Radiant intensity ``I`` (W/sr, linear RGB) emitted uniformly in all
        directions: irradiance ``I cos / r^2`` at distance ``r``, power
        ``4 pi I``.
    sphere_light : ndarray of int, shape (Ls,)
        Spheres (indices ``0 .. S-1``) that are area lights next-event
        estimation samples, by the cone they subtend (default none:
        :func:`mcvar.warps.square_to_sphere_from_point`). Lights are numbered
        parallelograms first, then these: sphere ``sphere_light[j]`` is light
        ``L + j``, and its primitive's ``prim_light`` must say so. Its
        radiance is the sphere's ``prim_emission`` (one-sided: outwards).
    render_defaults : mapping
        What a scene file says about rendering it (default empty): ``res``
        ``(width, height)`` of its film, ``spp`` (its sampler's
        sample_count), ``max_depth`` (None: no limit) and ``rr_depth``.
        ``mcvar render`` and ``mcvar converge`` use them unless their
        options say otherwise; :func:`mcvar.integrators.render` does not
        read them.
    """

    name: str
    triangles: np.ndarray
    sphere_centers: np.ndarray
    sphere_radii: np.ndarray
    prim_material: np.ndarray
    prim_emission: np.ndarray
    prim_two_sided_emission: np.ndarray
    prim_light: np.ndarray
    prim_group: np.ndarray
    materials: tuple
    material_names: tuple
    light_origin: np.ndarray
    light_edge1: np.ndarray
    light_edge2: np.ndarray
    light_radiance: np.ndarray
    camera: Camera
    environment: object | None = None
    checker_period: float | None = None
    ray_epsilon: float = 1e-3
    description: str = field(default="")
    point_light_position: np.ndarray | None = None
    point_light_intensity: np.ndarray | None = None
    render_defaults: Mapping = field(default_factory=dict)
    sphere_light: np.ndarray | None = None

    def __post_init__(self):
        if not isinstance(self.name, str):
            raise TypeError(f"Scene.name must be a string; got {type(self.name).__name__}")
        tri = _scene_array(self.triangles, "triangles", (3, 3))
        sc = _scene_array(self.sphere_centers, "sphere_centers", (3,))
        sr = _scene_array(self.sphere_radii, "sphere_radii", ())
        _check_coordinates(tri, "triangles")
        _check_coordinates(sc, "sphere_centers")
        n_prim = tri.shape[0] + sc.shape[0]
        if sr.shape[0] != sc.shape[0]:
            raise ValueError(f"sphere_radii must have one value per row of sphere_centers ({sc.shape[0]}); "
                             f"got {sr.shape[0]}")
        if not np.all((sr > 0) & (sr <= MAX_COORDINATE)):
            raise ValueError(f"sphere_radii must be finite and > 0 (at most {MAX_COORDINATE:g}); got "
                             f"{sr[~((sr > 0) & (sr <= MAX_COORDINATE))][0]}")
        tables = {
            "prim_material": _scene_array(self.prim_material, "prim_material", (), np.int64),
            "prim_emission": _scene_array(self.prim_emission, "prim_emission", (3,), nonnegative=True),
            "prim_two_sided_emission": _scene_array(self.prim_two_sided_emission, "prim_two_sided_emission",
                                                    (), bool),
            "prim_light": _scene_array(self.prim_light, "prim_light", (), np.int64),
            "prim_group": _scene_array(self.prim_group, "prim_group", (), np.int64),
        }
        for key, arr in tables.items():
            if arr.shape[0] != n_prim:
                raise ValueError(f"{key} must have one row per primitive ({n_prim}: {tri.shape[0]} triangles, "
                                 f"{sc.shape[0]} spheres); got {arr.shape[0]}")
        materials = self.materials
        if isinstance(materials, (str, bytes)) or not hasattr(materials, "__iter__"):
            raise TypeError(f"materials must be a tuple of mcvar.bsdf objects; got {type(materials).__name__}")
        materials = tuple(materials)
        for i, m in enumerate(materials):
            if not isinstance(m, BSDF):
                raise TypeError(f"materials[{i}] must be a mcvar.bsdf object (Lambertian, Mirror, Glass, ...); "
                                f"got {type(m).__name__} {m!r}")
        names = self.material_names
        names = (names,) if isinstance(names, str) else tuple(names)
        if len(names) != len(materials) or not all(isinstance(n, str) for n in names):
            raise ValueError(f"material_names must hold one string per entry of materials ({len(materials)}); "
                             f"got {names!r}")
        mat = tables["prim_material"]
        if n_prim and not (mat.min() >= 0 and mat.max() < len(materials)):
            raise ValueError(f"prim_material must index into materials (0 .. {len(materials) - 1}); got values "
                             f"in [{mat.min()}, {mat.max()}]")
        lights = {k: _scene_array(getattr(self, k), k, (3,), nonnegative=(k == "light_radiance"))
                  for k in ("light_origin", "light_edge1", "light_edge2", "light_radiance")}
        n_light = lights["light_origin"].shape[0]
        for k, v in lights.items():
            if v.shape[0] != n_light:
                raise ValueError(f"{k} must have one row per light ({n_light}, as light_origin); got {v.shape[0]}")
            if k != "light_radiance":
                _check_coordinates(v, k)
        area = np.linalg.norm(np.cross(lights["light_edge1"], lights["light_edge2"]), axis=1)
        if not np.all((area > 0) & np.isfinite(area)):
            bad = int(np.argmax(~((area > 0) & np.isfinite(area))))
            raise ValueError(f"light_edge1 and light_edge2 must span a parallelogram of positive area; light {bad} "
                             f"has area {area[bad]}")
        points = {k: _scene_array(np.zeros((0, 3)) if getattr(self, k) is None else getattr(self, k), k, (3,),
                                  nonnegative=(k == "point_light_intensity"))
                  for k in ("point_light_position", "point_light_intensity")}
        if points["point_light_position"].shape != points["point_light_intensity"].shape:
            raise ValueError("point_light_position and point_light_intensity must have one row (3 values) "
                             f"per point light; got {points['point_light_position'].shape} and "
                             f"{points['point_light_intensity'].shape}")
        _check_coordinates(points["point_light_position"], "point_light_position")
        lights.update(points)
        pl = tables["prim_light"]
        sph = _frozen(np.zeros(0) if self.sphere_light is None else self.sphere_light).reshape(-1)
        if not (np.all(np.isfinite(sph)) and np.all(sph == np.round(sph))):
            raise ValueError(f"sphere_light must hold sphere indices (integers); got {sph}")
        sph = _frozen(sph, np.int64)
        n_tri = tri.shape[0]
        if sph.size and not (sph.min() >= 0 and sph.max() < sc.shape[0] and np.unique(sph).size == sph.size):
            raise ValueError(f"sphere_light must hold distinct sphere indices in [0, {sc.shape[0]}); got {sph}")
        if n_prim and not (pl.min() >= -1 and pl.max() < n_light + sph.size):
            raise ValueError(f"prim_light must be -1 or index a light (0 .. {n_light + sph.size - 1}: "
                             f"{n_light} parallelogram(s), then {sph.size} sphere light(s)); got values in "
                             f"[{pl.min()}, {pl.max()}]")
        if np.any(pl[:n_tri] >= n_light):
            raise ValueError("prim_light of a triangle must be -1 or index a parallelogram light")
        expect = np.full(sc.shape[0], -1)
        expect[sph] = n_light + np.arange(sph.size)
        if not np.array_equal(np.where(pl[n_tri:] >= n_light, pl[n_tri:], -1), expect):
            raise ValueError("sphere_light and prim_light disagree: sphere sphere_light[j] must have prim_light "
                             f"{n_light} + j (the lights after the {n_light} parallelogram(s)), and no other "
                             "sphere a light index >= that")
        if sph.size and not np.all(tables["prim_emission"][n_tri + sph] >= 0):
            raise ValueError("sphere lights need non-negative prim_emission")
        lights["sphere_light"] = sph
        if not isinstance(self.camera, Camera):
            raise TypeError(f"camera must be a mcvar.scene.Camera; got {type(self.camera).__name__}")
        if self.environment is not None and not isinstance(self.environment, EnvironmentMap):
            raise TypeError(f"environment must be None or a mcvar.envmap.EnvironmentMap; got "
                            f"{type(self.environment).__name__}")
        if not isinstance(self.description, str):
            raise TypeError(f"description must be a string; got {type(self.description).__name__}")
        object.__setattr__(self, "triangles", tri)
        object.__setattr__(self, "sphere_centers", sc)
        object.__setattr__(self, "sphere_radii", sr)
        for key, arr in {**tables, **lights}.items():
            object.__setattr__(self, key, arr)
        object.__setattr__(self, "materials", materials)
        object.__setattr__(self, "material_names", names)
        check_positive(self.ray_epsilon, "ray_epsilon")
        if self.checker_period is not None:
            check_positive(self.checker_period, "checker_period")

    @property
    def n_triangles(self) -> int:
        return self.triangles.shape[0]

    @property
    def n_spheres(self) -> int:
        return self.sphere_centers.shape[0]

    @property
    def n_lights(self) -> int:
        return self.light_origin.shape[0]

    @property
    def n_sphere_lights(self) -> int:
        """Spheres next-event estimation samples (lights ``L .. L + Ls - 1``)."""
        return self.sphere_light.shape[0]

    @property
    def n_point_lights(self) -> int:
        return self.point_light_position.shape[0]

    @property
    def light_area(self) -> np.ndarray:
        """Area of each parallelogram light, shape (L,)."""
        return np.linalg.norm(np.cross(self.light_edge1, self.light_edge2), axis=1)

    @property
    def light_normal(self) -> np.ndarray:
        """Unit emitting-side normal of each light, shape (L, 3)."""
        n = np.cross(self.light_edge1, self.light_edge2)
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    def emission(self, prim, points, normals, directions) -> np.ndarray:
        """Radiance emitted by primitives ``prim`` at ``points`` towards ``-directions``.

        The surface's emission lookup the integrators call at every emitter
        hit: the primitive's ``prim_emission``, zero on the back of one-sided
        emitters (``normals . directions >= 0``, geometric normals as from
        :meth:`mcvar.tracer.Tracer.normals`) and, when ``checker_period`` is
        set, times the checker texture ``(floor(x / p) + floor(z / p)) mod 2``
        of the hit point.

        Parameters
        ----------
        prim : ndarray of int, shape (n,)
        points, normals, directions : ndarray, shape (n, 3)
            Hit points, unit geometric normals, and the directions of the
            rays that reached them (pointing *at* the surface).

        Returns
        -------
        ndarray, shape (n, 3), float64
        """
        le = np.take(self.prim_emission, prim, axis=0)
        if not np.any(le):
            return le
        front = np.einsum("ij,ij->i", normals, directions) < 0.0
        le = np.where((front | np.take(self.prim_two_sided_emission, prim))[:, None], le, 0.0)
        if self.checker_period is not None:
            c = (np.floor(points[:, 0] / self.checker_period)
                 + np.floor(points[:, 2] / self.checker_period)) % 2.0
            le = le * c[:, None]
        return le


# --------------------------------------------------------------------------
# Builders

def _quad_triangles(quad):
    v = np.asarray(quad, dtype=np.float64)
    return [v[list(t)] for t in CORNELL_TRIANGULATION]


def _room(blocks: bool):
    """Triangles, per-triangle material names and groups of the Cornell box."""
    tris, mats, groups, emit = [], [], [], []
    for name, material, quad in CORNELL_QUADS:
        if not blocks and name.startswith(("short", "tall")):
            continue
        group = 1 if name.startswith("short") else 2 if name.startswith("tall") else 0
        for tri in _quad_triangles(quad):
            tris.append(tri)
            mats.append(material)
            groups.append(group)
            emit.append(name == "light")
    return np.array(tris), mats, groups, np.array(emit)


def _cornell_light():
    quad = np.array(dict((n, q) for n, _, q in CORNELL_QUADS)["light"])
    origin, e1, e2 = quad[0], quad[1] - quad[0], quad[3] - quad[0]
    # The light quad is an exact parallelogram: v0 + e1 + e2 == v2.
    if not np.allclose(origin + e1 + e2, quad[2], rtol=0, atol=1e-9):
        raise AssertionError("the Cornell light quad is not a parallelogram")
    return origin, e1, e2


def _cornell_common(blocks: bool, extra_spheres=()):
    tris, tri_mats, groups, is_light = _room(blocks)
    albedo = dict(CORNELL_ALBEDO)
    names = [name for name, _ in CORNELL_ALBEDO]
    materials = [Lambertian(albedo[n]) for n in names]
    sphere_c, sphere_r, sphere_m = [], [], []
    for center, radius, mat_name, bsdf in extra_spheres:
        names.append(mat_name)
        materials.append(bsdf)
        sphere_c.append(center)
        sphere_r.append(radius)
        sphere_m.append(len(names) - 1)
    n_tri, n_sph = len(tris), len(sphere_c)
    prim_material = [names.index(m) for m in tri_mats] + sphere_m
    emission = np.zeros((n_tri + n_sph, 3))
    emission[:n_tri][is_light] = CORNELL_LIGHT_RADIANCE
    prim_light = np.full(n_tri + n_sph, -1)
    prim_light[:n_tri][is_light] = 0
    origin, e1, e2 = _cornell_light()
    position, look_at, up, fov = CORNELL_CAMERA
    return dict(
        triangles=tris,
        sphere_centers=np.array(sphere_c, dtype=np.float64).reshape(-1, 3),
        sphere_radii=np.array(sphere_r, dtype=np.float64),
        prim_material=prim_material,
        prim_emission=emission,
        prim_two_sided_emission=np.zeros(n_tri + n_sph, dtype=bool),
        prim_light=prim_light,
        prim_group=groups + [0] * n_sph,
        materials=tuple(materials),
        material_names=tuple(names),
        light_origin=origin[None],
        light_edge1=e1[None],
        light_edge2=e2[None],
        light_radiance=np.array([CORNELL_LIGHT_RADIANCE]),
        camera=Camera(position, look_at, up, fov),
        ray_epsilon=0.01,
    )


def cornell_scene() -> Scene:
    """The Cornell box exactly as ``shared/scenes/CORNELL.md`` specifies.

    Returns
    -------
    Scene
        32 triangles (16 quads), 4 Lambertian materials, one parallelogram
        light of radiance (17, 12, 4) facing -y, no environment.

    Notes
    -----
    The converged 64 x 64 image has mean about (0.196, 0.127, 0.036)
    (CORNELL.md's sanity check). Secondary rays start ``ray_epsilon = 0.01``
    units off the surface, far below the 0.1 gap between light and ceiling.
    """
    return Scene(name="cornell", description="Cornell box (original measured data)",
                 **_cornell_common(blocks=True))


def cornell_spheres_scene(eta: float = 1.5) -> Scene:
    """The Cornell room with a mirror sphere and a glass sphere instead of the blocks.

    Parameters
    ----------
    eta : float
        Relative index of refraction of the glass sphere (default 1.5).

    Notes
    -----
    The mirror sphere (radius 100) stands at the back left of the image
    (x = 370, z = 370), the glass sphere (radius 100) at the front right
    (x = 180, z = 170); both rest on the floor. The light, walls and camera are
    those of :func:`cornell_scene`.
    """
    eta = check_positive(eta, "eta")
    spheres = (((370.0, 100.0, 370.0), 100.0, "mirror", Mirror()),
               ((180.0, 100.0, 170.0), 100.0, "glass", Glass(eta)))
    return Scene(name="cornell-spheres", description="Cornell room, mirror and glass spheres",
                 **_cornell_common(blocks=False, extra_spheres=spheres))


#: Distance of the ``cornell-point`` light below the ceiling plane y = 548.8.
CORNELL_POINT_LIGHT_DROP = 1.0


def cornell_point_scene() -> Scene:
    """The Cornell box lit by a point light of the area light's power.

    Notes
    -----
    The light quad is removed; a point light sits at the centre of where it
    was (x = 278, z = 279.5), :data:`CORNELL_POINT_LIGHT_DROP` = 1 unit below
    the ceiling (y = 547.8). Same power: the one-sided Lambertian area light
    emits ``Phi = pi L A`` (``A`` = 130 x 105 = 13 650), and an isotropic
    point light of intensity ``I`` emits ``4 pi I``, so
    ``I = Phi / (4 pi) = L A / 4`` = (58 012.5, 40 950, 13 650). Half of it
    goes up: the ceiling right above the light is a small, very bright spot
    (irradiance ``I / 1^2``) that lights the room indirectly. Path tracing
    reaches the light only through next-event estimation; ``path_bsdf``
    renders the room black (Veach 1997, sec. 10.3.5: a path through a point
    light has probability zero for any method that must hit it).
    """
    common = _cornell_common(blocks=True)
    keep = np.flatnonzero(np.asarray(common["prim_light"]) < 0)      # drop the light quad
    for key in ("triangles", "prim_emission", "prim_two_sided_emission", "prim_light"):
        common[key] = np.asarray(common[key])[keep]
    common["prim_material"] = [common["prim_material"][i] for i in keep]
    common["prim_group"] = [common["prim_group"][i] for i in keep]
    origin, e1, e2 = _cornell_light()
    centre = origin + 0.5 * (e1 + e2)
    position = np.array([centre[0], 548.8 - CORNELL_POINT_LIGHT_DROP, centre[2]])
    area = float(np.linalg.norm(np.cross(e1, e2)))
    power = np.pi * np.array(CORNELL_LIGHT_RADIANCE) * area
    for key in ("light_origin", "light_edge1", "light_edge2", "light_radiance"):
        common[key] = np.zeros((0, 3))
    return Scene(name="cornell-point", description="Cornell box, point light of the area light's power",
                 point_light_position=position[None], point_light_intensity=(power / (4.0 * np.pi))[None],
                 **common)


def checkerboard_scene(period: float = 1.0) -> Scene:
    """An emissive checkerboard plane in perspective: an image-plane integral.

    Parameters
    ----------
    period : float
        Side of one checker square (world units, default 1).

    Notes
    -----
    The plane y = 0, 2000 x 2000 units, emits radiance 1 on the squares where
    ``(floor(x / p) + floor(z / p))`` is odd and 0 elsewhere, and reflects
    nothing (albedo 0); the sky is black. A camera 2 units above it looks at
    a point 10 units ahead on the ground, so squares shrink towards the
    horizon across the image. Every integrator then returns the same pixel
    value: the fraction of the pixel's footprint covered by lit squares, an
    integral of a discontinuous function over the pixel square, the lecture's
    aliasing (moire) example for uniform, random and jittered samples.
    """
    period = check_positive(period, "period")
    s = 1000.0
    quad = np.array([(-s, 0.0, -s), (-s, 0.0, s), (s, 0.0, s), (s, 0.0, -s)])
    tris = np.array(_quad_triangles(quad))
    return Scene(
        name="checkerboard", description="perspective checkerboard (image-plane integral)",
        triangles=tris, sphere_centers=np.zeros((0, 3)), sphere_radii=np.zeros(0),
        prim_material=[0, 0], prim_emission=np.ones((2, 3)),
        prim_two_sided_emission=[True, True], prim_light=[-1, -1], prim_group=[0, 0],
        materials=(Lambertian((0.0, 0.0, 0.0)),), material_names=("black",),
        light_origin=np.zeros((0, 3)), light_edge1=np.zeros((0, 3)),
        light_edge2=np.zeros((0, 3)), light_radiance=np.zeros((0, 3)),
        camera=Camera((0.0, 2.0, 0.0), (0.0, 0.0, 10.0), (0.0, 1.0, 0.0), 60.0),
        checker_period=period, ray_epsilon=1e-3)


def furnace_scene(albedo=0.5, emission=1.0) -> Scene:
    """The camera inside a closed Lambertian sphere that emits everywhere.

    Parameters
    ----------
    albedo : float or (3,) array_like
        Lambertian albedo ``rho`` of the sphere's inside, each in [0, 1).
    emission : float or (3,) array_like
        Radiance ``Le`` emitted by every point, in every direction.

    Notes
    -----
    Radiance is the same everywhere, so the rendering equation
    ``L = Le + rho L`` gives ``L = Le / (1 - rho)`` for every pixel; a path of
    at most ``d`` segments (``max_depth = d``) gathers the truncated sum
    ``Le (1 - rho^d) / (1 - rho)``. The emission is not an area light (next
    event estimation has nothing to sample), so it is found by BSDF sampling
    alone, with MIS weight 1.
    """
    rho = as_rgb(albedo, "albedo")
    if not np.all(rho < 1.0):
        raise ValueError(f"albedo must be < 1 for a finite furnace; got {rho}")
    le = as_rgb(emission, "emission")
    return Scene(
        name="furnace", description="closed emitting Lambertian sphere",
        triangles=np.zeros((0, 3, 3)), sphere_centers=[(0.0, 0.0, 0.0)], sphere_radii=[1.0],
        prim_material=[0], prim_emission=le[None], prim_two_sided_emission=[True],
        prim_light=[-1], prim_group=[0], materials=(Lambertian(rho),), material_names=("inside",),
        light_origin=np.zeros((0, 3)), light_edge1=np.zeros((0, 3)),
        light_edge2=np.zeros((0, 3)), light_radiance=np.zeros((0, 3)),
        camera=Camera((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 1.0, 0.0), 60.0),
        ray_epsilon=1e-5)


def quad_environment_scene(albedo=0.5, radiance=1.0, resolution=(8, 16)) -> Scene:
    """A Lambertian quad under a constant environment, filling the view.

    Parameters
    ----------
    albedo : float or (3,) array_like
        Lambertian albedo ``rho`` in [0, 1].
    radiance : float or (3,) array_like
        Constant environment radiance ``L``.
    resolution : tuple of int
        ``(height, width)`` of the constant lat-long environment image.

    Notes
    -----
    The quad [-1, 1]^2 in the plane y = 0 is seen from (0, 1, 0) looking
    straight down with a 60 degree field of view, so every primary ray hits
    it (tan 30 deg < 1). A point of the quad sees the whole upper hemisphere of
    constant radiance and nothing else, so its reflected radiance is
    ``rho / pi * L * integral(cos) = rho L`` (the lecture's 'Diffuse Exitant
    Radiance'); there are no interreflections.
    """
    from .envmap import constant

    rho = as_rgb(albedo, "albedo")
    le = as_rgb(radiance, "radiance")
    h, w = resolution
    env = constant(le, height=h, width=w)
    quad = np.array([(-1.0, 0.0, -1.0), (-1.0, 0.0, 1.0), (1.0, 0.0, 1.0), (1.0, 0.0, -1.0)])
    return Scene(
        name="quad-environment", description="Lambertian quad under a constant environment",
        triangles=np.array(_quad_triangles(quad)), sphere_centers=np.zeros((0, 3)),
        sphere_radii=np.zeros(0), prim_material=[0, 0], prim_emission=np.zeros((2, 3)),
        prim_two_sided_emission=[False, False], prim_light=[-1, -1], prim_group=[0, 0],
        materials=(Lambertian(rho),), material_names=("diffuse",),
        light_origin=np.zeros((0, 3)), light_edge1=np.zeros((0, 3)),
        light_edge2=np.zeros((0, 3)), light_radiance=np.zeros((0, 3)),
        camera=Camera((0.0, 1.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 60.0),
        environment=env, ray_epsilon=1e-5)


#: Scene builders by name; :func:`load_scene` passes keyword options through.
SCENES: dict[str, Callable[..., Scene]] = {
    "cornell": cornell_scene,
    "cornell-spheres": cornell_spheres_scene,
    "cornell-point": cornell_point_scene,
    "checkerboard": checkerboard_scene,
    "furnace": furnace_scene,
    "quad-environment": quad_environment_scene,
}


def load_scene(name, **options) -> Scene:
    """Build the scene called ``name``, or read it from a Mitsuba 3 XML file.

    Parameters
    ----------
    name : str or path
        One of ``'cornell'``, ``'cornell-spheres'``, ``'cornell-point'``, ``'checkerboard'``,
        ``'furnace'``, ``'quad-environment'``, ``'cornell-door'``; or the path
        of a Mitsuba 3 scene file (``.xml``; docs/scene-files.md lists the
        supported subset).
    **options
        Passed to the builder (e.g. ``albedo=0.8`` for ``'furnace'``); for a
        file, values replacing its ``<default>`` entries (Mitsuba's ``-D
        name=value``).

    Returns
    -------
    Scene
        Fresh read-only arrays on every call. A file's film size, sample
        count and path depth are in ``Scene.render_defaults``.

    Raises
    ------
    ValueError
        An unknown name, or a file mcvar cannot read: the message names the
        file, the line and the element, and what is supported
        (:class:`mcvar.scenefile.SceneFileError`).

    Examples
    --------
    >>> scene = load_scene("cornell")
    >>> scene.n_triangles, scene.n_lights
    (32, 1)
    """
    if isinstance(name, os.PathLike) or (isinstance(name, str) and name not in SCENES
                                         and (name.lower().endswith(".xml") or os.sep in name)):
        return _scene_from_fields(read_scene_file(name, **options))
    if not isinstance(name, str):
        raise TypeError(f"name must be a string (a scene name, one of {tuple(SCENES)}, or the path of a "
                        f"Mitsuba 3 .xml file) or an os.PathLike; got {type(name).__name__}")
    if name not in SCENES:
        raise ValueError(f"unknown scene {name!r}; known scenes: {', '.join(SCENES)} "
                         "(or the path of a Mitsuba 3 .xml file)")
    return SCENES[name](**options)


def _scene_from_fields(fields: dict) -> Scene:
    fields = dict(fields)
    fields["camera"] = Camera(**fields["camera"])
    return Scene(**fields)


def save_scene(scene: Scene, path, *, res=None, spp: int | None = None, max_depth=None):
    """Write ``scene`` as a Mitsuba 3 XML file that :func:`load_scene` and Mitsuba 3 both read.

    Parameters
    ----------
    scene : Scene
    path : str or path
        The ``.xml`` file. Triangle meshes (PLY) and environment images (EXR)
        go into the folder ``<stem>/`` beside it, named by their content, and
        the file refers to them by relative names (move the two together).
    res, spp, max_depth : optional
        The film size, the sampler's sample count and the path depth the
        file asks for; default ``scene.render_defaults`` (else 64 x 64, 16
        spp, no depth limit). ``rr_depth`` is written when the defaults have
        it.

    Returns
    -------
    pathlib.Path
        ``path``.

    Notes
    -----
    One mapping from Scene to Mitsuba: the dictionary of
    :func:`mcvar.interop.mitsuba.to_mitsuba` (which refuses, with a
    ``ValueError`` naming it, whatever has no Mitsuba counterpart of the same
    model), written by :func:`mcvar.scenefile.write_xml`; the camera as a
    ``lookat`` of ``scene.camera`` (exact, where a matrix would be rounded to
    float32). ``ray_epsilon`` and the description travel in a ``<!-- mcvar
    ... -->`` comment that Mitsuba ignores. ``load_scene(save_scene(s))``
    renders the same image as ``s`` with the same seed (tests/test_scenefile.py).
    Needs no Mitsuba: the camera and the environment's rotation are written as
    XML records, an environment image through :func:`mcvar.images.write_image`
    (EXR needs the ``exr`` extra).
    """
    # save_scene is the one function of this module above layer 4: it writes through the
    # exporter of mcvar.interop (layer 5), imported here, when called (tests/test_layering.py)
    from .images import write_image
    from .interop.mitsuba import MitsubaTransforms, scene_dict
    from .scenefile import LookAt, Rotate, write_xml

    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a mcvar.scene.Scene; got {type(scene).__name__}")
    path = Path(path)
    if path.suffix.lower() != ".xml":
        raise ValueError(f"path must name an .xml file; got {str(path)!r}")
    defaults = dict(scene.render_defaults)
    res = defaults.get("res", 64) if res is None else res
    spp = defaults.get("spp", 16) if spp is None else spp
    max_depth = defaults.get("max_depth") if max_depth is None else max_depth
    folder = path.parent / path.stem
    records = MitsubaTransforms(look_at=lambda o, t, u: LookAt(tuple(o), tuple(t), tuple(u)),
                                rotate_y=lambda deg: Rotate((0.0, 1.0, 0.0), float(deg)),
                                write_exr=lambda p, image: write_image(p, image))
    d = scene_dict(scene, res=res, spp=spp, max_depth=max_depth, folder=folder, transforms=records)
    if "rr_depth" in defaults and "max_depth" in d["integrator"]:
        d["integrator"]["rr_depth"] = int(defaults["rr_depth"])
    env = d.get("environment")
    for value in d.values():
        if isinstance(value, dict) and isinstance(value.get("filename"), str):
            value["filename"] = os.path.relpath(value["filename"], path.parent).replace(os.sep, "/")
    meta = f'mcvar ray_epsilon="{scene.ray_epsilon!r}"'
    if env is not None and env.get("type") == "constant":
        meta += f' environment_size="{scene.environment.height} {scene.environment.width}"'
    if scene.description:
        meta += ' description="' + scene.description.replace('"', "'").replace("--", "-") + '"'
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(write_xml(d, comments=[f"{scene.name}: written by mcvar.scene.save_scene", meta]),
                    encoding="utf-8")
    return path


# --------------------------------------------------------------------------
# cornell-door (issue 12): light reaches the visible room only through a slit

def cornell_door_scene(slit: float = 20.0, wall_z: float = 400.0, height: float = 300.0,
                       center: float = 278.0) -> Scene:
    """The Cornell room split by a wall with a narrow door; the light is behind it.

    In the spirit of Veach's door scene (Veach 1997, fig. 11.3): the camera
    sees the front part of the room (the short block, the red and green
    walls, and a white partition wall at ``z = wall_z`` filling the view);
    the light is moved to the ceiling of the closet behind the partition
    (z from 440 to 545). Light enters the visible room only through a
    slit ``slit`` units wide and ``height`` high in the partition
    (x in ``[center - slit/2, center + slit/2]``, y in
    ``[0, height]``: a door left ajar), so next-event estimation from the
    visible room is almost always shadowed and a path tracer finds the
    light through the slit rarely; Metropolis light transport, once it has
    found such a path, explores its neighbours. With the default height the
    camera sees the closet's lit floor and back wall through the slit but
    not the light itself (which would make a few pixels hold most of the
    image's luminance, where MLT spends most of its mutations). With
    ``slit=5, center=200, height=120`` the door is low and behind the short
    block: the camera sees neither the closet nor any surface the light
    reaches directly (direct lighting is 0 in every pixel), as in Veach's
    scene; docs/mcmc.md measures the methods on it.

    Parameters
    ----------
    slit : float
        Width of the slit (scene units; the room is ~556 wide), in (0, 556).
    wall_z : float
        Depth of the partition, in (272, 440) (behind the short block, in
        front of the light).
    height : float
        Height of the slit, in (0, 548.8] (548.8: full height, the light
        is then visible through it).
    center : float
        x of the slit's centre (278: the middle of the room; the camera
        then looks straight through it).

    Returns
    -------
    Scene
        The Cornell materials and light radiance; the tall block is removed
        (it would cross the partition).
    """
    slit = check_positive(slit, "slit")
    wall_z = check_positive(wall_z, "wall_z")
    if not slit < 556.0:
        raise ValueError(f"slit must be < 556 (the room's width); got {slit}")
    if not 272.0 < wall_z < 440.0:
        raise ValueError(f"wall_z must lie in (272, 440); got {wall_z}")
    height = check_positive(height, "height")
    if not height <= 548.8:
        raise ValueError(f"height must be <= 548.8 (the ceiling); got {height}")
    base = _cornell_common(blocks=True)
    groups = np.asarray(base["prim_group"])
    keep = groups != 2                                   # drop the tall block
    shift = np.array([0.0, 0.0, 213.0])                  # light z 227..332 -> 440..545
    tris = np.asarray(base["triangles"])[keep]
    light = np.asarray(base["prim_light"])[keep] >= 0
    tris[light] += shift
    white = base["material_names"].index("white")
    center = check_positive(center, "center")
    x0, x1 = center - slit / 2.0, center + slit / 2.0
    if not (x0 > 0.0 and x1 < 556.0):
        raise ValueError(f"the slit [center - slit/2, center + slit/2] must lie inside (0, 556); got [{x0}, {x1}]")
    top = 548.8
    wall = []
    for a, b, lo in ((0.0, x0, 0.0), (x1, 556.0, 0.0), (x0, x1, height)):
        if lo < top:                                     # the lintel above the slit
            quad = ((b, lo, wall_z), (a, lo, wall_z), (a, top, wall_z), (b, top, wall_z))
            wall += _quad_triangles(quad)
    n_wall = len(wall)
    n_keep = tris.shape[0]
    base.update(
        triangles=np.concatenate([tris, np.array(wall)]),
        prim_material=list(np.asarray(base["prim_material"])[keep]) + [white] * n_wall,
        prim_emission=np.concatenate([np.asarray(base["prim_emission"])[keep], np.zeros((n_wall, 3))]),
        prim_two_sided_emission=np.zeros(n_keep + n_wall, dtype=bool),
        prim_light=np.concatenate([np.asarray(base["prim_light"])[keep], np.full(n_wall, -1)]),
        prim_group=list(groups[keep]) + [0] * n_wall,
        light_origin=np.asarray(base["light_origin"]) + shift,
    )
    return Scene(name="cornell-door", description=f"Cornell room, light behind a wall with a {slit:g}-wide slit",
                 **base)


SCENES["cornell-door"] = cornell_door_scene
__all__ += ["cornell_door_scene"]


# --------------------------------------------------------------------------
# the built-in scenes as Mitsuba 3 files (issue 23): mcvar/data/scenes/<name>.xml

#: Where the built-in scenes are shipped as Mitsuba 3 XML (package data).
SCENE_FILES_DIR = Path(__file__).resolve().parent / "data" / "scenes"


def scene_file(name: str) -> Path:
    """The shipped Mitsuba 3 file of the built-in scene ``name`` (``mcvar/data/scenes/<name>.xml``).

    ``load_scene(scene_file(name))`` renders the image of ``load_scene(name)``
    with the same seed, up to the float32 vertices of its PLY meshes; ``mitsuba
    scene_file(name)`` renders it in Mitsuba 3. Written by
    :func:`write_scene_files`.
    """
    if not isinstance(name, str) or name not in SCENES:
        raise ValueError(f"name must be a built-in scene, one of {', '.join(SCENES)}; got {name!r}")
    if name in NO_SCENE_FILE:
        raise ValueError(f"scene {name!r} has no Mitsuba 3 file: {NO_SCENE_FILE[name]}")
    path = SCENE_FILES_DIR / f"{name}.xml"
    if not path.is_file():
        raise ValueError(f"{path} is missing: run mcvar.scene.write_scene_files() in a source checkout")
    return path


def write_scene_files(folder=None, *, res: int = 64, spp: int = 16) -> list:
    """Write every built-in scene of :data:`SCENES` with :func:`save_scene` (default into
    :data:`SCENE_FILES_DIR`), at ``mcvar render``'s default film and sample count.
    Returns the paths written."""
    folder = SCENE_FILES_DIR if folder is None else Path(folder)
    return [save_scene(SCENES[name](), folder / f"{name}.xml", res=res, spp=spp) for name in SCENES
            if name not in NO_SCENE_FILE]


#: Built-in scenes :func:`save_scene` cannot write, and why (not shipped as files).
NO_SCENE_FILE = {
    "veach-mis": "its rough conductors use height-correlated Smith masking, Mitsuba's roughconductor the "
                 "separable one (mcvar.interop.mitsuba refuses them)",
}

__all__ += ["save_scene", "scene_file", "write_scene_files", "SCENE_FILES_DIR", "NO_SCENE_FILE"]


# --------------------------------------------------------------------------
# veach-mis (issue 21): Veach's multiple importance sampling scene

#: Roughness (GGX ``alpha``) of the four plates, top (nearest the lights) to bottom.
VEACH_PLATE_ALPHA = (0.005, 0.02, 0.05, 0.1)
#: Complex index of the plates' metal (grey, reflectance about 0.9 at normal incidence).
VEACH_PLATE_ETA, VEACH_PLATE_K = 0.2, 3.0
#: Radii of the four sphere lights, left to right (Veach 1997, fig. 9.2: ratio 3).
VEACH_LIGHT_RADIUS = (1.0 / 30.0, 0.1, 0.3, 0.9)
#: Power of each light: radiance ``VEACH_LIGHT_POWER / (4 pi^2 r^2)`` (sphere power ``4 pi^2 r^2 L``).
VEACH_LIGHT_POWER = 40.0


def veach_mis_scene(backdrop: float = 0.1) -> Scene:
    """Veach's MIS scene: four glossy plates, four sphere lights of equal power.

    Veach (1997), *Robust Monte Carlo Methods for Light Transport
    Simulation*, fig. 9.2 (also Nori's and Mitsuba's ``veach-mi``): four
    plates of increasing roughness (:data:`VEACH_PLATE_ALPHA`, GGX
    :class:`mcvar.bsdf.Conductor`, a grey metal; Mitsuba's ``roughconductor``) stacked in front of the
    camera, each tilted so that it mirrors the row of four spherical lights
    (:data:`VEACH_LIGHT_RADIUS`, 27x apart in radius, equal power: radiance
    ``P / (4 pi^2 r^2)``) back to the camera, and a dim Lambertian backdrop.
    Each plate shows a glossy reflection of every light. Light sampling
    (``direct_light``) is noisy where a large light meets a sharp lobe (top
    plate, right light); BSDF sampling (``direct_bsdf``) is noisy where a
    small light meets a rough lobe (bottom plate, left light); MIS
    (``direct``) is good on both.

    Parameters
    ----------
    backdrop : float
        Albedo of the backdrop wall behind the plates, in [0, 1].

    Notes
    -----
    Units: the camera at the origin looks along +z at the plates (z about
    10), the lights sit at y = 6, z = 6, out of view. The spheres are
    sampled lights (:attr:`Scene.sphere_light`): NEE draws a direction in
    the cone each subtends.
    """
    check_positive(backdrop, "backdrop", allow_zero=True)
    if backdrop > 1.0:
        raise ValueError(f"backdrop must lie in [0, 1]; got {backdrop}")
    cam = np.zeros(3)
    light_row = np.array([0.0, 6.0, 6.0])
    tris, mats = [], []
    half_w, half_h = 4.0, 0.42
    for i, y in enumerate((1.5, 0.5, -0.5, -1.5)):
        center = np.array([0.0, y, 10.0])
        n = (cam - center) / np.linalg.norm(cam - center) + \
            (light_row - center) / np.linalg.norm(light_row - center)
        n /= np.linalg.norm(n)
        ex = np.array([1.0, 0.0, 0.0])
        ey = np.cross(n, ex)                                    # in the plate, mostly +y
        ey /= np.linalg.norm(ey)
        if ey[1] < 0:
            ey = -ey
        q = [center - half_w * ex - half_h * ey, center - half_w * ex + half_h * ey,
             center + half_w * ex + half_h * ey, center + half_w * ex - half_h * ey]
        v = np.array(q)
        if np.dot(np.cross(v[1] - v[0], v[2] - v[0]), n) < 0:   # the front faces the camera
            v = v[::-1]
        tris += _quad_triangles(v)
        mats += [i, i]
    back = np.array([[-12.0, -8.0, 14.0], [-12.0, 12.0, 14.0], [12.0, 12.0, 14.0], [12.0, -8.0, 14.0]])
    tris += _quad_triangles(back)
    mats += [4, 4]
    n_tri = len(tris)
    radii = np.array(VEACH_LIGHT_RADIUS)
    centers = np.column_stack([np.array([-3.75, -1.25, 1.25, 3.75]), np.full(4, light_row[1]),
                               np.full(4, light_row[2])])
    radiance = VEACH_LIGHT_POWER / (4.0 * np.pi ** 2 * radii ** 2)
    emission = np.zeros((n_tri + 4, 3))
    emission[n_tri:] = radiance[:, None]
    prim_light = np.full(n_tri + 4, -1)
    prim_light[n_tri:] = np.arange(4)
    materials = tuple(Conductor(VEACH_PLATE_ETA, VEACH_PLATE_K, alpha_x=a) for a in VEACH_PLATE_ALPHA) \
        + (Lambertian(backdrop),) \
        + (Lambertian(0.0),)
    names = tuple(f"plate{i}" for i in range(4)) + ("backdrop", "light")
    return Scene(
        name="veach-mis", description="Veach's MIS scene: four glossy plates, four sphere lights of equal power",
        triangles=np.array(tris), sphere_centers=centers, sphere_radii=radii,
        prim_material=mats + [5] * 4, prim_emission=emission,
        prim_two_sided_emission=np.zeros(n_tri + 4, dtype=bool), prim_light=prim_light,
        prim_group=[0] * (n_tri + 4), materials=materials, material_names=names,
        light_origin=np.zeros((0, 3)), light_edge1=np.zeros((0, 3)), light_edge2=np.zeros((0, 3)),
        light_radiance=np.zeros((0, 3)), sphere_light=np.arange(4),
        camera=Camera(cam, np.array([0.0, 0.0, 10.0]), np.array([0.0, 1.0, 0.0]), 40.0),
        ray_epsilon=1e-4)


SCENES["veach-mis"] = veach_mis_scene
__all__ += ["veach_mis_scene", "VEACH_PLATE_ALPHA", "VEACH_LIGHT_RADIUS", "VEACH_LIGHT_POWER"]


# --------------------------------------------------------------------------
# cornell-caustic (issue 21): a caustic that path tracing reaches only by chance

def cornell_caustic_scene(light_scale: float = 0.1, eta: float = 1.5) -> Scene:
    """The Cornell room with a glass sphere under a small, bright light.

    The blocks are replaced by one :class:`mcvar.bsdf.Glass` sphere (radius
    100, resting on the floor at the room's centre, x = 278, z = 279.5, right
    under the light). The light quad keeps its centre and is shrunk by
    ``light_scale`` along both edges (default 0.1: 1/100 of the area) with
    its radiance raised by ``1 / light_scale^2``: the same power. The sphere
    focuses the light into a bright caustic on the floor around its contact
    point. Path tracing reaches the caustic only when a diffuse bounce on
    the floor samples a direction that refracts twice through the sphere
    *and* hits the small light (NEE cannot see the light through glass):
    probability about the light's solid angle, 1/100 of the Cornell box's.
    Light subpaths (light tracing, BDPT's ``t = 1`` strategies, photons)
    start on the light and find the caustic directly.

    Parameters
    ----------
    light_scale : float
        Linear scale of the light quad, in (0, 1].
    eta : float
        Index of refraction of the sphere.
    """
    light_scale = check_positive(light_scale, "light_scale")
    if light_scale > 1.0:
        raise ValueError(f"light_scale must lie in (0, 1]; got {light_scale}")
    eta = check_positive(eta, "eta")
    spheres = (((278.0, 100.0, 279.5), 100.0, "glass", Glass(eta)),)
    base = _cornell_common(blocks=False, extra_spheres=spheres)
    origin, e1, e2 = base["light_origin"][0], base["light_edge1"][0], base["light_edge2"][0]
    center = origin + 0.5 * (e1 + e2)
    o2, f1, f2 = center - 0.5 * light_scale * (e1 + e2), light_scale * e1, light_scale * e2
    tris = np.array(base["triangles"], dtype=np.float64)
    is_light = np.asarray(base["prim_light"])[: tris.shape[0]] >= 0
    quad = np.array([o2, o2 + f1, o2 + f1 + f2, o2 + f2])
    tris[is_light] = np.array(_quad_triangles(quad))
    emission = np.array(base["prim_emission"], dtype=np.float64)
    radiance = np.asarray(CORNELL_LIGHT_RADIANCE) / light_scale ** 2
    emission[: tris.shape[0]][is_light] = radiance
    base.update(triangles=tris, prim_emission=emission, light_origin=o2[None], light_edge1=f1[None],
                light_edge2=f2[None], light_radiance=radiance[None])
    return Scene(name="cornell-caustic",
                 description=f"Cornell room, glass sphere under a light of {light_scale ** 2:g} the area, same power",
                 **base)


SCENES["cornell-caustic"] = cornell_caustic_scene
__all__ += ["cornell_caustic_scene"]
