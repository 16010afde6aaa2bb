"""Emitters: the one place that samples lights, and the densities that go with it.

* Next-event estimation (:meth:`Emitters.sample_li`, pbrt-v4's
  ``SampleLi``): for shading points, one emitter (chosen uniformly among the
  area lights and the environment) and a point on it (uniform by area on a
  parallelogram, :mod:`mcvar.envmap`'s sampling for the environment), with
  the solid-angle density ``p_A r^2 / cos theta_l`` (lecture 'Light
  Sampling'; :func:`mcvar.warps.area_to_solid_angle_pdf`); on a sphere
  light (``Scene.sphere_light``), a direction uniform in the cone the
  sphere subtends, density ``1 / (2 pi (1 - cos theta_max))`` (pbrt-v4's
  ``Sphere::Sample(ctx, u)``, :func:`mcvar.warps.square_to_sphere_from_point`;
  from inside, uniform area converted to solid angle). Its partner
  :meth:`Emitters.pdf_li` gives that density for an emitter *hit* by BSDF
  sampling (the MIS weight of emission found by chance).
* Light subpaths (:class:`LightOrigins`, :func:`sample_le`, :func:`pdf_le`,
  pbrt-v4's ``SampleLe``/``PDF_Le``): an emitting primitive, a point light
  or the environment chosen by power, a point uniform by area on it and a
  cosine-weighted direction about its emitting normal (a point light:
  uniform on the sphere; the environment: a direction from its importance
  distribution and a point on a disk of the scene's bounding-sphere radius
  perpendicular to it), for light tracing, bidirectional and photon methods
  (issues 11, 26). NEE also samples point lights (after the area lights; MIS
  weight 1).
"""
from __future__ import annotations

import hashlib

import numpy as np

from .._validation import check_choice
from ..geometry import Frame, _clip_halfplanes, polygon_pixel_coverage
from ..warps import (_rectangle_soa_frame, _rectangle_solid_angle_soa, _spherical_rectangle_soa,
                     area_to_solid_angle_pdf, square_to_cosine_hemisphere,
                     square_to_cosine_hemisphere_pdf, square_to_uniform_disk_concentric,
                     square_to_sphere_from_point, square_to_sphere_from_point_pdf,
                     square_to_uniform_sphere, square_to_uniform_triangle)

__all__ = ["Emitters", "LightOrigins", "VisibleLights", "sample_le", "pdf_le", "LIGHT_SAMPLING",
           "VISIBLE_LIGHTS"]

#: How next-event estimation samples a point on a quad light: uniformly by
#: area (its density converted to solid angle, ``p_A r^2 / cos theta_l``), or
#: uniformly in the solid angle the light subtends (Urena, Fajardo and King
#: 2013; rectangles only; density ``1 / S``, no ``r^2 / cos`` factor).
LIGHT_SAMPLING = ("area", "solid_angle")

#: How the emission of area lights seen *directly* by the camera enters a
#: pixel: ``sampled`` by the pixel's own samples (Monte Carlo), or ``exact``:
#: the light's box-filtered image computed in closed form and the samples
#: estimating only the difference (a control variate, :class:`VisibleLights`).
VISIBLE_LIGHTS = ("sampled", "exact")


def _dot(a, b):
    return np.einsum("ij,ij->j", a, b)


class Emitters:
    """Per-scene tables of the emitters next-event estimation samples.

    Parameters
    ----------
    scene : mcvar.scene.Scene

    Attributes
    ----------
    n_emitters : int
        Parallelogram lights, sphere lights, point lights, plus one for an
        environment.
    select_pdf : float
        ``1 / n_emitters`` (uniform choice), 0 without emitters.
    single_quad : bool
        One parallelogram light and nothing else: sampling is one
        ``(3, 3) @ [1; u0; u1]`` product.
    """

    def __init__(self, scene, light_sampling: str = "area"):
        self.scene = scene
        self.light_sampling = check_choice(light_sampling, "light_sampling", LIGHT_SAMPLING)
        # per light (x, y, z, l1, l2) for solid-angle sampling (ValueError for a non-rectangle)
        self.rect = [] if self.light_sampling == "area" else \
            [_rectangle_soa_frame(e1, e2) for e1, e2 in zip(scene.light_edge1, scene.light_edge2)]
        self.n_lights = scene.n_lights
        self.n_points = scene.n_point_lights
        self.n_spheres = scene.n_sphere_lights
        self.env = scene.environment
        self.n_emitters = self.n_lights + self.n_spheres + self.n_points + (1 if self.env is not None else 0)
        # per sphere light: centre (Ls, 3), radius (Ls,), radiance (3, Ls)
        sph = scene.sphere_light
        self.sphere_center = scene.sphere_centers[sph]
        self.sphere_radius = scene.sphere_radii[sph]
        self.sphere_radiance_soa = np.ascontiguousarray(scene.prim_emission[scene.n_triangles + sph].T)
        self.select_pdf = 1.0 / self.n_emitters if self.n_emitters else 0.0
        self.light_area = scene.light_area
        self.light_normal = scene.light_normal
        # per light: the affine map [o e1 e2] (3, 3) and normal, SoA-friendly
        self.affine = np.stack([scene.light_origin, scene.light_edge1, scene.light_edge2], axis=2)  # (L, 3, 3)
        self.normal_soa = np.ascontiguousarray(self.light_normal.T)          # (3, L)
        self.radiance_soa = np.ascontiguousarray(scene.light_radiance.T)     # (3, L)
        self.pdf_area = self.select_pdf / self.light_area if self.n_lights else np.zeros(0)
        self.single_quad = self.n_lights == 1 and self.env is None and self.n_points == 0 and self.n_spheres == 0
        #: one point light and nothing else (``cornell-point``): sampled without the general branch's scatter
        self.single_point = self.n_points == 1 and self.env is None and self.n_lights == 0 and self.n_spheres == 0

    # -- next-event estimation -------------------------------------------------

    def choose(self, u_sel, m: int) -> np.ndarray:
        """Emitter index of ``m`` samples from ``u_sel`` in [0, 1] (None with one
        emitter): parallelograms ``0 .. L-1``, sphere lights ``L .. L+Ls-1``,
        point lights ``L+Ls .. L+Ls+P-1``, then ``L + Ls + P`` = the
        environment."""
        n_em = self.n_emitters
        if n_em <= 1:
            return np.zeros(m, dtype=np.int64)
        return np.minimum((np.asarray(u_sel) * n_em).astype(np.int64), n_em - 1)

    def sample_li(self, p, u, u_sel, *, radiance: bool = True):
        """An emitter sample for every shading point (structure-of-arrays).

        Parameters
        ----------
        p : ndarray, shape (3, m)
            Shading points.
        u : ndarray, shape (2, m)
            The point on the light (parallelogram coordinates) or the
            environment's 2-D sample.
        u_sel : ndarray, shape (m,), or None
            Chooses the emitter (:meth:`choose`); None with a single emitter.

        radiance : bool
            False: ``le`` is None when the scene's one emitter is a quad light
            (the Lambertian kernel takes ``Le`` from its own table; the masked
            ``(3, m)`` copy cost 2-3% of its next-event estimation).

        Returns
        -------
        w : ndarray, shape (3, m)
            Unit direction from ``p`` to the sample.
        dist : ndarray, shape (m,)
            Distance (inf for the environment).
        le : ndarray, shape (3, m)
            Radiance emitted towards ``p`` (0 from the back of a light).
        pdf : ndarray, shape (m,)
            Solid-angle density of ``w`` including the emitter choice; 0
            where the sample cannot contribute (back side, edge-on).
        light : ndarray of int, shape (m,)
            Parallelogram light index, -1 for the environment (for shadow
            keys), -2 for a point light, -3 for a sphere light (its shadow
            ray stops short of the sampled point on the near cap, so every
            primitive stays a candidate occluder).

        Notes
        -----
        A point light (a Dirac delta in solid angle, issue 11) returns ``le
        = I / r^2`` and ``pdf`` = its selection probability, so that ``f le
        cos / pdf`` is the estimate; BSDF sampling cannot hit it, so its MIS
        weight is 1 (the caller passes a BSDF density of 0 for ``light ==
        -2``).
        """
        m = p.shape[1]
        if self.single_quad:
            return self._area(p, u, None, radiance) + (np.zeros(m, dtype=np.int64),)
        if self.single_point:
            return self._point(p)
        k = self.choose(u_sel, m)
        w = np.zeros((3, m))
        w[1] = 1.0
        dist = np.full(m, np.inf)
        le = np.zeros((3, m))
        pdf = np.zeros(m)
        on_light = k < self.n_lights
        if self.n_lights and np.any(on_light):
            sel = np.flatnonzero(on_light)
            w[:, sel], dist[sel], le[:, sel], pdf[sel] = self._area(p[:, sel], u[:, sel], k[sel])
        n_ls = self.n_lights + self.n_spheres
        on_sphere = (k >= self.n_lights) & (k < n_ls)
        if self.n_spheres and np.any(on_sphere):
            sel = np.flatnonzero(on_sphere)
            w[:, sel], dist[sel], le[:, sel], pdf[sel] = self._sphere(p[:, sel], u[:, sel], k[sel] - self.n_lights)
        on_point = (k >= n_ls) & (k < n_ls + self.n_points)
        if self.n_points and np.any(on_point):
            sel = np.flatnonzero(on_point)
            j = k[sel] - n_ls
            v = np.take(self.scene.point_light_position, j, axis=0).T - p[:, sel]
            d2 = _dot(v, v)
            r = np.sqrt(d2)
            w[:, sel] = v / np.maximum(r, 1e-300)
            dist[sel] = r
            le[:, sel] = np.take(self.scene.point_light_intensity, j, axis=0).T / np.maximum(d2, 1e-300)
            pdf[sel] = self.select_pdf
        if self.env is not None and not np.all(on_light | on_sphere | on_point):
            sel = np.flatnonzero(~(on_light | on_sphere | on_point))
            w_env, pdf_env = self.env.sample(u[:, sel].T)
            w[:, sel] = w_env.T
            le[:, sel] = self.env.radiance(w_env).T
            pdf[sel] = self.select_pdf * pdf_env
        return w, dist, le, pdf, np.where(on_light, k, np.where(on_point, -2, np.where(on_sphere, -3, -1)))

    def _point(self, p):
        """The one point light seen from every ``p`` (SoA): the general branch's
        numbers, written for the whole wavefront at once."""
        m = p.shape[1]
        v = self.scene.point_light_position[0][:, None] - p
        d2 = _dot(v, v)
        r = np.sqrt(d2)
        w = v / np.maximum(r, 1e-300)
        le = self.scene.point_light_intensity[0][:, None] / np.maximum(d2, 1e-300)
        return w, r, le, np.full(m, self.select_pdf), np.full(m, -2, dtype=np.int64)

    def _sphere(self, p, u, j):
        """Sphere lights ``j`` sampled by the cone they subtend from ``p`` (SoA):
        ``(w, dist, le, pdf)``, the pdf including the emitter choice; ``le`` is 0
        from inside a one-sided (outward) sphere."""
        pa = np.asarray(p, dtype=np.float64).T
        c, r = self.sphere_center[j], self.sphere_radius[j]
        w, dist = square_to_sphere_from_point(np.clip(np.asarray(u, dtype=np.float64).T, 0.0, 1.0), pa, c, r)
        # a shading point on the sphere itself (within the ray offset): a convex
        # emitter cannot light itself, and its cone degenerates to points at p
        dc = np.sqrt(np.einsum("ij,ij->i", pa - c, pa - c))
        ok = (np.abs(dc - r) > self.scene.ray_epsilon) & (dist > 0.0)
        w[~ok] = (0.0, 1.0, 0.0)
        pdf = np.where(ok, self.select_pdf * square_to_sphere_from_point_pdf(w, pa, c, r), 0.0)
        le = np.take(self.sphere_radiance_soa, j, axis=1)
        le = np.where((dc > r) & (pdf > 0.0), le, 0.0)
        return np.ascontiguousarray(w.T), dist, le, pdf

    def _area(self, p, u, li, radiance: bool = True):
        """Uniform points on lights ``li`` (None: the single light) seen from ``p``, SoA
        (``radiance`` False with ``li`` None: ``le`` is None)."""
        if self.rect:
            return self._solid_angle(p, u, li)
        m = p.shape[1]
        if li is None:
            # o + u0 e1 + u1 e2 written out: as a (3, 3) @ (3, m) product it
            # is a dgemm that OpenBLAS threads, which on a busy machine cost
            # 12 ms per call instead of 0.1 ms (half of a 256-spp render)
            # in the samples' precision (float32 in the Lambertian kernel)
            a = self.affine[0].astype(np.result_type(u.dtype, p.dtype), copy=False)
            x = a[:, 1:2] * u[0]
            x += a[:, 2:3] * u[1]
            x += a[:, 0:1]
            n_l = self.normal_soa[:, :1]
            pa = float(self.pdf_area[0])
            le = np.broadcast_to(self.radiance_soa[:, :1], (3, m))
        else:
            uh = np.empty((3, m))
            uh[0] = 1.0
            uh[1:] = u
            x = np.einsum("mij,jm->im", np.take(self.affine, li, axis=0), uh)
            n_l = np.take(self.normal_soa, li, axis=1)
            pa = np.take(self.pdf_area, li)
            le = np.take(self.radiance_soa, li, axis=1)
        x -= p                                  # x is ours: the vector to the light
        d2 = _dot(x, x)
        r = np.sqrt(d2)
        w = x
        w /= np.maximum(r, np.finfo(r.dtype).tiny)
        if li is None:
            n = [float(c) for c in n_l[:, 0]]            # Python floats keep w's precision
            cos_l = w[0] * -n[0]
            cos_l -= w[1] * n[1]
            cos_l -= w[2] * n[2]
        else:
            cos_l = -_dot(n_l, w)
        front = cos_l > 0.0
        # area density to solid angle (area_to_solid_angle_pdf's formula): p_A r^2 / cos_l
        with np.errstate(divide="ignore", invalid="ignore"):
            pdf = np.where(front, pa * d2 / cos_l, 0.0)
        if li is None and not radiance:
            le = None
        elif not np.all(front):
            le = np.where(front, le, 0.0)
        return w, r, le, pdf

    def _solid_angle(self, p, u, li):
        """Points on rectangular lights ``li`` (None: the single light) uniform
        in the solid angle seen from ``p`` (SoA): ``(w, dist, le, pdf)``."""
        m = p.shape[1]
        w = np.empty((3, m))
        dist = np.empty(m)
        pdf = np.empty(m)
        ks = [0] if li is None else np.unique(li)
        for k in ks:
            sel = slice(None) if li is None else np.flatnonzero(li == k)
            w[:, sel], dist[sel], s = _spherical_rectangle_soa(u[:, sel], p[:, sel],
                                                              self.scene.light_origin[k], *self.rect[k])
            pdf[sel] = self._rect_pdf(int(k), p[:, sel], s)
        le = np.broadcast_to(self.radiance_soa[:, :1], (3, m)) if li is None else \
            np.take(self.radiance_soa, li, axis=1)
        if not np.all(pdf > 0.0):
            le = np.where(pdf > 0.0, le, 0.0)
        return w, dist, le, pdf

    def _rect_pdf(self, k, p, s=None):
        """``select_pdf / S`` for light ``k`` seen from SoA points ``p`` (0 behind it or edge-on)."""
        if s is None:
            s = _rectangle_solid_angle_soa(p, self.scene.light_origin[k], *self.rect[k])
        n = self.light_normal[k]
        d = p - self.scene.light_origin[k][:, None]
        front = (n[0] * d[0] + n[1] * d[1] + n[2] * d[2]) > 0.0
        ok = front & (s > 0.0)
        return np.where(ok, self.select_pdf / np.where(ok, s, 1.0), 0.0)

    def pdf_li(self, prim, origins, points) -> np.ndarray:
        """Solid-angle density with which :meth:`sample_li` draws emitter hits.

        Parameters
        ----------
        prim : ndarray of int, shape (n,)
            Primitives hit (those without a light get 0: NEE never samples them).
        origins, points : ndarray, shape (n, 3)
            Where the rays started and the hit points.
        """
        light = np.take(self.scene.prim_light, prim)
        pdf = np.zeros(prim.shape[0])
        sphere = light >= self.n_lights
        if np.any(sphere):
            j = light[sphere] - self.n_lights
            o = np.asarray(origins, dtype=np.float64)[sphere]
            d = np.asarray(points, dtype=np.float64)[sphere] - o
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            pdf[sphere] = self.select_pdf * square_to_sphere_from_point_pdf(d, o, self.sphere_center[j],
                                                                            self.sphere_radius[j])
            light = np.where(sphere, -1, light)
        is_light = light >= 0
        if np.any(is_light) and self.rect:
            for k in np.unique(light[is_light]):
                sel = np.flatnonzero(light == k)
                pdf[sel] = self._rect_pdf(int(k), np.ascontiguousarray(np.asarray(origins)[sel].T))
        elif np.any(is_light):
            li = light[is_light]
            pdf[is_light] = area_to_solid_angle_pdf(np.take(self.pdf_area, li), origins[is_light],
                                                    points[is_light], np.take(self.light_normal, li, axis=0))
        return pdf

    def environment_pdf(self, d) -> np.ndarray:
        """Solid-angle density with which :meth:`sample_li` draws environment directions ``d`` (n, 3)."""
        return self.select_pdf * self.env.pdf(d)


# -- light subpaths ------------------------------------------------------------

class _SparseImage:
    """A cached ``(n, 3)`` image that pickles as its nonzero rows: the dense
    array is made on first use in each process and left out of the pickle."""

    __slots__ = ("n", "lit", "values", "_dense")

    def __init__(self, n: int, lit, values):
        self.n, self.lit, self.values, self._dense = int(n), lit, values, None

    @classmethod
    def of(cls, dense: np.ndarray) -> "_SparseImage":
        lit = np.flatnonzero(np.any(dense != 0.0, axis=1))
        out = cls(dense.shape[0], lit, dense[lit])
        dense.flags.writeable = False
        out._dense = dense
        return out

    def dense(self) -> np.ndarray:
        if self._dense is None:
            img = np.zeros((self.n, 3))
            img[self.lit] = self.values
            img.flags.writeable = False
            self._dense = img
        return self._dense

    def __reduce__(self):
        return (_SparseImage, (self.n, self.lit, self.values))


class VisibleLights:
    """Area lights seen directly by the camera, integrated exactly over every pixel.

    A pixel's value is the mean over the pixel of the radiance ``f`` its
    camera paths carry. Part of ``f`` is ``g``: the emission of a light the
    camera ray passes through, ``g = sum_l Le_l [the ray crosses light l's
    emitting face]``, occlusion ignored. For a parallelogram of constant
    radiance the pixel integral of ``g`` is ``Le_l`` times the fraction of
    the pixel covered by the light's projection (a pinhole maps the plane of
    the light to the film projectively, so the projection is a polygon, and
    the box filter is uniform on the film: :meth:`image`,
    :func:`mcvar.geometry.polygon_pixel_coverage`). The estimator

        ``I = image[pixel] + mean(f - g)``

    is unbiased for every sampler (a control variate with coefficient 1,
    e.g. Owen 2013, *Monte Carlo theory, methods and examples*, sec. 8.9;
    Kalos and Whitlock 2008, sec. 4.3). A camera ray whose first hit is a
    light has ``f - g = 0`` (no emission added, nothing subtracted); a ray
    that crosses a light behind a nearer surface subtracts that light's
    radiance (:meth:`hidden`). On the Cornell box no ray is occluded, so the
    light's own pixels and the pixels on its edge, which otherwise hold most
    of a uniform render's error (a radiance-17 emitter next to a 0.1
    ceiling), carry no emission variance at all.

    Parameters
    ----------
    scene : mcvar.scene.Scene

    Attributes
    ----------
    lights : ndarray of int
        The lights handled exactly: one-sided parallelograms of constant
        radiance whose triangles tile them (no checker texture), whose
        emitting face the camera sees. Other emitters stay sampled.
    prim_exact : ndarray of bool, shape (n_prims + 1,)
        Primitives of those lights (the last entry, for a miss, False).
    """

    def __init__(self, scene):
        self.scene = scene
        n_prim = scene.prim_light.shape[0]
        lights = []
        if scene.checker_period is None:
            cam = scene.camera.position
            for k in range(scene.n_lights):
                prims = np.flatnonzero(scene.prim_light == k)
                o, e1, e2 = scene.light_origin[k], scene.light_edge1[k], scene.light_edge2[k]
                nrm = np.cross(e1, e2)
                if (prims.size == 0 or np.any(prims >= scene.n_triangles)
                        or np.any(scene.prim_two_sided_emission[prims])
                        or not np.all(scene.prim_emission[prims] == scene.light_radiance[k])
                        or not (cam - o) @ nrm > 0.0):
                    continue
                tri = scene.triangles[prims]
                area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
                height = (tri.reshape(-1, 3) - o) @ (nrm / np.linalg.norm(nrm))
                scale = max(1.0, float(np.abs(tri).max()))
                if abs(area.sum() - np.linalg.norm(nrm)) > 1e-9 * np.linalg.norm(nrm) \
                        or np.abs(height).max() > 1e-9 * scale:
                    continue
                lights.append(k)
        self.lights = np.array(lights, dtype=np.int64)
        self.prim_exact = np.zeros(n_prim + 1, dtype=bool)
        self.prim_exact[:n_prim] = np.isin(scene.prim_light, self.lights)
        # per light: the plane (origin, unit normal), the dual basis of (e1, e2),
        # its radiance, and the cone from the camera that holds it (axis, cos)
        self._planes = []
        cam = scene.camera.position
        for k in self.lights:
            o, e1, e2 = scene.light_origin[k], scene.light_edge1[k], scene.light_edge2[k]
            nrm = np.cross(e1, e2)
            n2 = nrm @ nrm
            corners = np.stack([o, o + e1, o + e1 + e2, o + e2]) - cam
            axis = corners.sum(axis=0)
            axis /= np.linalg.norm(axis)
            cos_min = float((corners @ axis / np.linalg.norm(corners, axis=1)).min())
            self._planes.append((k, o, nrm / np.sqrt(n2), np.cross(e2, nrm) / n2, np.cross(nrm, e1) / n2,
                                 scene.light_radiance[k], [float(a) for a in axis], cos_min))

    def __bool__(self) -> bool:
        return self.lights.size > 0

    def image(self, res) -> np.ndarray:
        """``(W H, 3)``: per flat pixel ``i W + j``, the box-filtered radiance
        of the exactly handled lights, occlusion ignored (the pixel integral of ``g``).

        Cached on the scene object, by content (camera, lights, resolution):
        derived state of that (frozen) scene, so every batch of a render that
        holds the scene reuses it and the cache lives and dies with the
        scene (no module global). The cache pickles the image sparse (the
        pixels the lights touch and their values; the dense array is made
        once per process that unpickles it): the scene is pickled into every batch a worker
        process runs, and a dense cache made that pickle grow with the
        image (1.7 MB per batch at 256 x 256, 6% of a two-worker render's
        time; 444 pixels, 14 kB, sparse; docs/performance.md, 'Cost per
        path and image size'). Read-only.
        """
        from ..scene import _film_res

        width, height = _film_res(res)
        cam = self.scene.camera
        key = hashlib.sha1(b"".join(np.ascontiguousarray(a, dtype=np.float64).tobytes() for a in (
            cam.position, cam.look_at, cam.up, [cam.fov_deg, width, height], self.lights,
            *(self.scene.light_origin[k] for k in self.lights), *(self.scene.light_edge1[k] for k in self.lights),
            *(self.scene.light_edge2[k] for k in self.lights),
            *(self.scene.light_radiance[k] for k in self.lights)))).hexdigest()
        images = self.scene.__dict__.setdefault("_visible_light_images", {})
        entry = images.get(key)
        if entry is None:
            entry = _SparseImage.of(self._image(width, height))
            if len(images) >= 8:
                images.pop(next(iter(images)))
            images[key] = entry
        return entry.dense()

    def _image(self, width, height):
        out = np.zeros((height * width, 3))
        cam = self.scene.camera
        forward = cam.basis()[0]
        for k, o, _, _, _, le, _, _ in self._planes:
            e1, e2 = self.scene.light_edge1[k], self.scene.light_edge2[k]
            corners = np.stack([o, o + e1, o + e1 + e2, o + e2])
            # the part in front of the pinhole (a light may reach behind it)
            depth = (corners - cam.position) @ forward
            z_near = 1e-9 * max(1.0, float(np.abs(corners - cam.position).max()))
            poly = _clip_halfplanes(corners[None], (depth - z_near)[None])[0]
            if not np.all(np.isfinite(poly)):
                continue
            xy, _ = cam.project(poly, (width, height))
            out += polygon_pixel_coverage(xy, width, height).reshape(-1)[:, None] * le
        return out

    def hidden(self, o, d, t_hit, prim) -> np.ndarray:
        """``g`` of camera rays whose first hit is *not* the light they cross: (3, n).

        ``o, d`` (3, n) camera rays (origins at the camera's position),
        ``t_hit`` (n,) distance to their first hit (inf: a miss), ``prim`` (n,)
        the primitive hit (-1: none). The radiance of every handled light a
        ray crosses through its emitting face beyond ``t_hit``; rays that hit
        a light's own triangles first are left out for that light (their
        ``f - g`` is 0). Only rays inside the cone from the camera around each
        light (one dot product per ray) are tested further.
        """
        n = t_hit.shape[0]
        out = np.zeros((3, n))
        for k, lo, nrm, g1, g2, le, axis, cos_min in self._planes:
            near = axis[0] * d[0]
            near += axis[1] * d[1]
            near += axis[2] * d[2]
            sel = np.flatnonzero(near >= cos_min - 1e-6)      # float32 directions: a margin
            if sel.size == 0:
                continue
            ds = np.asarray(d[:, sel], dtype=np.float64)
            os_ = np.asarray(o[:, sel], dtype=np.float64)
            denom = nrm @ ds
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (nrm @ lo - nrm @ os_) / denom
            x = os_ + t * ds - lo[:, None]
            a, b = g1 @ x, g2 @ x
            crossed = (denom < 0.0) & (t > t_hit[sel]) & (a >= 0.0) & (a <= 1.0) & (b >= 0.0) & (b <= 1.0)
            pr = prim[sel]
            crossed &= np.where(pr >= 0, np.take(self.scene.prim_light, np.maximum(pr, 0)), -1) != k
            if np.any(crossed):
                out[:, sel[crossed]] += le[:, None]
        return out


def _bounding_sphere(scene):
    """Centre and radius of the sphere around the bounding box of the scene's
    triangles and spheres (pbrt's ``Bounds3::BoundingSphere``); the camera is
    not part of it."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    if scene.n_triangles:
        v = scene.triangles.reshape(-1, 3)
        lo, hi = np.minimum(lo, v.min(axis=0)), np.maximum(hi, v.max(axis=0))
    if scene.n_spheres:
        r = scene.sphere_radii[:, None]
        lo = np.minimum(lo, (scene.sphere_centers - r).min(axis=0))
        hi = np.maximum(hi, (scene.sphere_centers + r).max(axis=0))
    if not np.all(hi >= lo):
        return np.zeros(3), 1.0
    center = 0.5 * (lo + hi)
    return center, max(float(np.linalg.norm(hi - center)), 1e-12)


class LightOrigins:
    """Every emitter of a scene as an origin of light subpaths (pbrt-v4's ``SampleLe``/``PDF_Le``).

    Emitting primitives (triangles and spheres: any primitive with emission,
    so also the furnace's sphere and the checkerboard's plane, not only the
    parallelogram lights NEE samples) and point lights, one chosen in
    proportion to its power (mean over RGB): a primitive of area ``A`` emits
    ``pi L A`` one-sided or ``2 pi L A`` two-sided, a point light ``4 pi
    I``. The point is uniform by area on the chosen primitive; the direction
    cosine-weighted about the emitting side's normal (a two-sided emitter
    picks its side with probability 1/2), a point light's uniform over the
    sphere. BDPT's ``s = 1`` strategy joins camera vertices to these same
    origins, so its MIS weights see one light-sampling technique.

    An environment map is an origin too (pbrt-v4's infinite lights): its
    power is ``pi r^2 int L d omega`` for the radius ``r`` of the scene's
    bounding sphere (:attr:`center`, :attr:`radius`: the flux through a disk
    that covers the scene). A sample draws a direction ``w`` towards the
    map from its importance distribution (:meth:`EnvironmentMap.sample`,
    solid-angle density ``p(w)``) and a point uniform on the disk of radius
    ``r`` perpendicular to ``w``, centred at ``center + r w``; the ray
    leaves it along ``-w`` (area density ``1 / (pi r^2)``). The sample's
    ``p`` is that disk point, ``n`` the ray direction ``-w``, ``le = L(w)``,
    ``pdf_pos = p_choice / (pi r^2)``, ``pdf_dir = p(w)`` and ``cos = 1``.

    Parameters
    ----------
    scene : mcvar.scene.Scene

    Attributes
    ----------
    pmf : ndarray, shape (count,)
        Choice probability of every origin: emitting primitives
        (:attr:`prims`), point lights, then the environment (if any).
    power_rgb : ndarray, shape (count, 3)
        Emitted power of every origin (the choice is by its mean over RGB).
    env_index : int
        Index of the environment among the origins, -1 without one.
    center, radius : ndarray (3,), float
        The scene's bounding sphere (of its triangles and spheres).
    """

    def __init__(self, scene):
        self.scene = scene
        n_tri = scene.n_triangles
        n_prim = n_tri + scene.n_spheres
        tri = scene.triangles
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]) if n_tri else np.zeros((0, 3))
        twice = np.linalg.norm(cross, axis=1)
        #: unit geometric normals of the triangles (the emitting side of one-sided ones)
        self.triangle_normal = cross / np.maximum(twice, 1e-300)[:, None]
        prims = np.flatnonzero(np.any(scene.prim_emission > 0.0, axis=1))
        self.prims = prims
        is_tri = prims < n_tri
        area = np.empty(prims.size)
        area[is_tri] = 0.5 * twice[prims[is_tri]]
        area[~is_tri] = 4.0 * np.pi * scene.sphere_radii[prims[~is_tri] - n_tri] ** 2
        two = scene.prim_two_sided_emission[prims]
        self.env = scene.environment
        self.center, self.radius = _bounding_sphere(scene)
        power = [scene.prim_emission[prims] * (area * np.pi * (1.0 + two))[:, None],
                 4.0 * np.pi * scene.point_light_intensity]
        if self.env is not None:
            power.append(np.pi * self.radius ** 2 * self.env.power()[None])
        self.power_rgb = np.concatenate(power)
        self.env_index = self.power_rgb.shape[0] - 1 if self.env is not None else -1
        power = self.power_rgb.mean(axis=1)
        total = power.sum()
        self.count = power.size
        #: choice probability of every origin (emitting primitives, then point lights)
        self.pmf = power / total if total > 0 else np.zeros(power.size)
        self.cdf = np.cumsum(self.pmf)
        #: per primitive: choice probability and area (0 and 1 if it does not emit)
        self.prim_select = np.zeros(n_prim)
        self.prim_select[prims] = self.pmf[:prims.size]
        self.prim_area = np.ones(n_prim)
        self.prim_area[prims] = area

    def index(self, light) -> np.ndarray:
        """Origin index (into :attr:`pmf`) of :func:`sample_le`'s ``light`` codes
        (primitive, ``-1 - j`` point light ``j``, ``-1 - P`` the environment)."""
        light = np.asarray(light, dtype=np.int64)
        n_area = self.prims.size
        return np.where(light >= 0, np.searchsorted(self.prims, np.maximum(light, 0)), n_area - 1 - light)

    @property
    def env_pdf_pos(self) -> float:
        """Area density ``1 / (pi r^2)`` of an environment origin on its disk (no choice)."""
        return 1.0 / (np.pi * self.radius ** 2)

    @property
    def empty(self) -> bool:
        """No emitter with positive power: light subpaths cannot start."""
        return self.count == 0 or not self.cdf[-1] > 0

    def normals(self, prim, p):
        """Unit geometric normals (n, 3) of primitives ``prim`` at points ``p`` (spheres: outward)."""
        n_tri = self.scene.n_triangles
        out = np.zeros((prim.shape[0], 3))
        tri = prim < n_tri
        out[tri] = self.triangle_normal[prim[tri]]
        if not np.all(tri):
            j = prim[~tri] - n_tri
            out[~tri] = (p[~tri] - self.scene.sphere_centers[j]) / self.scene.sphere_radii[j][:, None]
        return out

    def sample(self, u_pos, u_dir):
        """Light-subpath origins from ``u_pos``, ``u_dir`` (n, 2) in [0, 1]^2.

        The origin is chosen by ``u_pos[:, 0]`` (rescaled into the chosen
        interval of the CDF, so stratification survives), the point by
        ``u_pos``, the direction by ``u_dir``. Returns a dict: ``p``, ``n``
        (emitting-side unit normal, 0 for point lights), ``w`` (direction),
        ``prim`` (-1 for point lights), ``point`` (point-light index or -1),
        ``pdf_pos`` (choice x area density; the choice alone for a point
        light, a Dirac delta in position), ``pdf_dir`` (per steradian), ``le``
        (radiance, or a point light's intensity, along ``w``), ``cos`` (1
        for point lights and the environment) and ``env`` (bool: the
        environment's disk, see the class notes).
        """
        scene = self.scene
        u_pos = np.array(u_pos, dtype=np.float64).reshape(-1, 2)
        u_dir = np.array(u_dir, dtype=np.float64).reshape(-1, 2)
        n = u_pos.shape[0]
        if self.empty:
            raise ValueError(f"scene {scene.name!r} has no emitter to start light subpaths from")
        k = np.minimum(np.searchsorted(self.cdf, u_pos[:, 0] * self.cdf[-1], side="right"), self.count - 1)
        lo = np.where(k > 0, np.take(self.cdf, k - 1), 0.0)
        u_pos[:, 0] = np.clip(np.divide(u_pos[:, 0] - lo, np.take(self.pmf, k), out=np.zeros(n),
                                        where=np.take(self.pmf, k) > 0), 0.0, 1.0)
        n_area = self.prims.size
        p = np.zeros((n, 3))
        nrm = np.zeros((n, 3))
        prim = np.full(n, -1)
        point = np.full(n, -1)
        pdf_pos = np.take(self.pmf, k)
        le = np.zeros((n, 3))
        w = np.zeros((n, 3))
        pdf_dir = np.zeros(n)
        cos = np.ones(n)
        ia = np.flatnonzero(k < n_area)
        if ia.size:
            pr = self.prims[k[ia]]
            prim[ia] = pr
            n_tri = scene.n_triangles
            tri = pr < n_tri
            it, isph = ia[tri], ia[~tri]
            if it.size:
                v = scene.triangles[pr[tri]]
                b = square_to_uniform_triangle(u_pos[it])
                p[it] = v[:, 0] + b[:, 0:1] * (v[:, 1] - v[:, 0]) + b[:, 1:2] * (v[:, 2] - v[:, 0])
                nrm[it] = self.triangle_normal[pr[tri]]
            if isph.size:
                j = pr[~tri] - n_tri
                d = square_to_uniform_sphere(u_pos[isph])
                p[isph] = scene.sphere_centers[j] + scene.sphere_radii[j][:, None] * d
                nrm[isph] = d
            pdf_pos[ia] /= self.prim_area[pr]
            two = scene.prim_two_sided_emission[pr]
            u0 = u_dir[ia, 0]
            back = two & (u0 >= 0.5)
            u0 = np.clip(np.where(two, np.where(back, 2.0 * u0 - 1.0, 2.0 * u0), u0), 0.0, 1.0)
            local = square_to_cosine_hemisphere(np.column_stack([u0, u_dir[ia, 1]]))
            fr = Frame(nrm[ia] * np.where(back, -1.0, 1.0)[:, None])
            w[ia] = fr.to_world(local)
            nrm[ia] = fr.n
            cos[ia] = local[:, 1]
            pdf_dir[ia] = square_to_cosine_hemisphere_pdf(local) * np.where(two, 0.5, 1.0)
            le[ia] = self.emission(pr, p[ia], w[ia])
        env = k == self.env_index
        ip = np.flatnonzero((k >= n_area) & ~env)
        if ip.size:
            j = k[ip] - n_area
            point[ip] = j
            p[ip] = scene.point_light_position[j]
            le[ip] = scene.point_light_intensity[j]
            w[ip] = square_to_uniform_sphere(u_dir[ip])
            pdf_dir[ip] = 0.25 / np.pi
        ie = np.flatnonzero(env)
        if ie.size:
            p[ie], w[ie], le[ie], pdf_dir[ie] = self._sample_environment(u_pos[ie], u_dir[ie])
            nrm[ie] = w[ie]
            pdf_pos[ie] *= self.env_pdf_pos
        return dict(p=p, n=nrm, w=w, prim=prim, point=point, pdf_pos=pdf_pos, pdf_dir=pdf_dir, le=le, cos=cos,
                    env=env)

    def _sample_environment(self, u_pos, u_dir):
        """Rays from the environment into the scene (pbrt-v4's infinite-light ``SampleLe``):
        ``(points on the disk, directions -w, L(w), p(w))`` for directions ``w``
        towards the map drawn from its importance distribution."""
        towards, pdf = self.env.sample(u_dir)
        disk = square_to_uniform_disk_concentric(u_pos)
        fr = Frame(towards)
        r = self.radius
        p = self.center + r * (towards + fr.s * disk[:, 0:1] + fr.t * disk[:, 1:2])
        return p, -towards, self.env.radiance(towards), pdf

    def emission(self, prim, p, w):
        """Radiance emitted by primitives ``prim`` at ``p`` towards unit ``w`` (leaving), (n, 3)."""
        return self.scene.emission(prim, p, self.normals(prim, p), -w)

    def pdf_dir(self, prim, p, w):
        """Solid-angle density of emitting ``w`` from ``p`` on primitives ``prim``."""
        c = np.einsum("ij,ij->i", self.normals(prim, p), w)
        two = np.take(self.scene.prim_two_sided_emission, prim)
        return np.where(two, 0.5 * np.abs(c), np.maximum(c, 0.0)) / np.pi

    def pdf_pos(self, prim):
        """Density (choice x area) of starting at a point of primitive ``prim``."""
        return np.take(self.prim_select, prim) / np.take(self.prim_area, prim)

    def light_le(self, point, prim, p, w):
        """The 'BSDF' of light vertices ``y_0``: a point light's intensity, or the
        radiance towards ``w`` (an environment vertex, ``point`` and ``prim``
        both -1: ``L(-w)``, the map seen looking back along the ray)."""
        out = np.zeros((point.shape[0], 3))
        pt = point >= 0
        if np.any(pt):
            out[pt] = self.scene.point_light_intensity[point[pt]]
        env = (point < 0) & (prim < 0)
        if np.any(env):
            out[env] = self.env.radiance(-w[env])
        area = ~pt & ~env
        if np.any(area):
            out[area] = self.emission(prim[area], p[area], w[area])
        return out

    def light_pdf_dir(self, point, prim, p, w):
        """Density with which the origin ``y_0`` emits towards ``w``: per unit
        solid angle, except for an environment vertex (``point`` and ``prim``
        -1), whose rays are parallel: ``1 / (pi r^2)`` per unit area across
        them (the caller multiplies by the cosine at the next vertex, no
        ``1 / r^2``: pbrt-v4's ``PdfLight`` of an infinite light)."""
        out = np.full(point.shape[0], 0.25 / np.pi)
        env = (point < 0) & (prim < 0)
        out[env] = self.env_pdf_pos
        area = (point < 0) & ~env
        if np.any(area):
            out[area] = self.pdf_dir(prim[area], p[area], w[area])
        return out

    def env_pdf_origin(self, towards) -> np.ndarray:
        """Choice times solid-angle density of an environment origin towards
        ``towards`` (n, 3): the 'position' density of a light vertex at infinity
        (pbrt-v4's ``PdfLightOrigin`` of an infinite light)."""
        return self.pmf[self.env_index] * self.env.pdf(towards)


def sample_le(scene, u_pos, u_dir):
    """Start light subpaths: an origin on an emitter and a direction leaving it.

    :class:`LightOrigins` of ``scene``: an emitting primitive or a point light
    chosen by power (``u_pos[:, 0]``, rescaled), a point uniform by area
    (``u_pos``), a cosine-weighted direction about its emitting normal, or
    uniform on the sphere for a point light (``u_dir``).

    Parameters
    ----------
    scene : mcvar.scene.Scene
        With at least one emitter (an environment map counts: its origins
        lie on a disk beyond the scene, :class:`LightOrigins`).
    u_pos, u_dir : ndarray, shape (n, 2)
        Uniform numbers in [0, 1]^2.

    Returns
    -------
    points, directions, normals : ndarray, shape (n, 3)
        Origin, unit direction leaving it, the emitting side's normal (0 for
        a point light).
    le : ndarray, shape (n, 3)
        Emitted radiance along ``directions`` (a point light: its intensity).
    pdf_pos : ndarray, shape (n,)
        Area density of the origin including its choice (a point light: the
        choice probability alone).
    pdf_dir : ndarray, shape (n,)
        Solid-angle density of the direction (``cos theta / pi`` one-sided,
        half that two-sided, ``1 / (4 pi)`` for a point light).
    light : ndarray of int, shape (n,)
        The emitting primitive, ``-1 - j`` for point light ``j``, or
        ``-1 - P`` (``P`` point lights) for the environment map.

    Notes
    -----
    One sample's estimate of the emitted power is ``le cos / (pdf_pos
    pdf_dir)`` (pbrt-v4, section 12.5 ``SampleLe``): ``pi L A_k / p_k`` for
    an area emitter chosen with probability ``p_k``.
    """
    s = LightOrigins(scene).sample(u_pos, u_dir)
    light = np.where(s["point"] >= 0, -1 - s["point"], s["prim"])
    light[s["env"]] = -1 - scene.n_point_lights
    return s["p"], s["w"], s["n"], s["le"], s["pdf_pos"], s["pdf_dir"], light


def pdf_le(scene, light, points, directions):
    """Densities with which :func:`sample_le` starts at ``points`` on ``light`` (n,) along ``directions``.

    Returns ``(pdf_pos, pdf_dir)``: choice x area density (the choice alone
    for a point light, ``light = -1 - j``) and the solid-angle density of
    the direction (0 behind a one-sided emitter).
    """
    origins = LightOrigins(scene)
    light = np.asarray(light, dtype=np.int64).reshape(-1)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    env = (light == -1 - scene.n_point_lights) & (origins.env_index >= 0)
    point = np.where((light < 0) & ~env, -1 - light, -1)
    prim = np.maximum(light, 0)
    pdf_pos = origins.pdf_pos(prim)
    is_point = point >= 0
    if np.any(is_point):
        pdf_pos[is_point] = np.take(origins.pmf, origins.prims.size + point[is_point])
    pdf_dir = np.zeros(light.shape[0])
    if np.any(~env):
        pdf_dir[~env] = origins.light_pdf_dir(point[~env], prim[~env], points[~env], directions[~env])
    if np.any(env):
        # a point of the disk perpendicular to the direction, at r beyond the centre, of radius r
        towards = -directions[env]
        off = points[env] - origins.center - origins.radius * towards
        on_disk = (np.abs(np.einsum("ij,ij->i", off, towards)) <= 1e-9 * origins.radius) & \
            (np.einsum("ij,ij->i", off, off) <= origins.radius ** 2 * (1 + 1e-9))
        pdf_pos[env] = np.where(on_disk, origins.pmf[origins.env_index] * origins.env_pdf_pos, 0.0)
        pdf_dir[env] = origins.env.pdf(towards)
    return pdf_pos, pdf_dir
