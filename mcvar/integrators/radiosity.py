"""Finite-element radiosity of diffuse scenes: the registered method ``radiosity``.

The lecture's 'Finite Element Radiosity' slide: "transport light between
patches in the scene; solve a large linear system for the equilibrium
distribution; good for diffuse lighting, hard to capture other light paths".
This module does exactly that, in four steps:

1. :func:`mesh_patches` cuts every triangle of the scene (the Cornell box's
   quads are triangle pairs) into ``k^2`` congruent sub-triangles, ``k`` the
   smallest integer that makes every sub-edge at most ``patch_size`` long.
   Every patch has two *sides* (the walls are two-sided Lambertian): side
   ``2 i`` faces along the triangle's geometric normal, side ``2 i + 1``
   against it.
2. :func:`form_factors` estimates the form factor ``F_ij`` from side ``i`` to
   side ``j`` by Monte Carlo *ray casting* (Malley's method; Cohen and
   Wallace 1993, sec. 4.9.6): uniform points on side ``i``, cosine-weighted
   directions, and the tracer's closest hit decides which side receives each
   ray. Since ``F_ij = (1/A_i) int_{A_i} int_{H} cos/pi V(x, w) [hit j] dw dA``,
   the fraction of side ``i``'s rays that land on side ``j`` is an unbiased
   estimate, *visibility included*, and every row sums to the fraction of rays
   that hit anything: at most 1, exactly 1 in a closed room. Rays that escape
   gather the environment's irradiance (``pi E[L_env]`` under cosine
   sampling).
3. :func:`solve_radiosity` solves ``(I - rho F) B = E'`` per RGB channel,
   ``E' = E + rho H_env``, either by Jacobi iteration
   ``B_{k+1} = E' + rho F B_k`` (iterate ``k`` holds exactly the light of
   paths with at most ``k`` diffuse bounces; it stops when the residual
   ``max |E' + rho F B_k - B_k|`` is at most ``tol * max |B_k|``) or directly
   by ``scipy.sparse.linalg.spsolve``.
4. :meth:`Radiosity.radiance` looks the solution up at the first hit of camera
   rays (flat shading: one value per patch side): exact emission at the hit
   plus ``rho / pi`` times the patch side's irradiance ``H = F B + H_env``.

Why ray casting and not the point-to-patch estimator: sampling a point on
each of two patches and weighting by ``cos cos V / (pi r^2)`` has *infinite
variance* for patches that share an edge (the kernel grows like ``1 / r^2``
at the Cornell box's corners), and the analytic polygon form factor with a
separate shadow-ray visibility fraction is biased wherever visibility is
partial. Ray casting is unbiased with binomial variance
``F_ij (1 - F_ij) / M`` for ``M`` rays per side, which makes reciprocity
``A_i F_ij = A_j F_ji`` a testable statistical statement.

The method is biased at every ray count (the radiosity is constant over a
patch, the exitant light is assumed diffuse) and consistent only under
refinement: the error falls as ``patch_size`` shrinks and rays grow, not with
spp. Only Lambertian materials are allowed (:func:`check_diffuse`); mirrors,
glass or any other BSDF raise ``ValueError`` naming the material, and so do
spheres (not meshed here).

References
----------
.. [1] C. M. Goral, K. E. Torrance, D. P. Greenberg, B. Battaile, "Modeling
   the Interaction of Light Between Diffuse Surfaces", SIGGRAPH 1984.
.. [2] M. F. Cohen, J. R. Wallace, "Radiosity and Realistic Image
   Synthesis", Academic Press, 1993 (ch. 4: form factors; ch. 5: solvers).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .._validation import as_array, as_rng, check_budget, check_choice, check_count, check_positive, settings_with
from ..bsdf import Lambertian
from ..geometry import Frame
from ..scene import Scene
from ..tracer import Tracer
from ..warps import _plane_coords, square_to_cosine_hemisphere, square_to_uniform_triangle
from .film import BatchJob, BatchResult, camera_result
from .knobs import scaled_knob
from .registry import Method, register
from .stream import camera_rays

__all__ = ["Patches", "FormFactors", "Radiosity", "RadiositySettings", "check_diffuse", "mesh_patches",
           "form_factors", "solve_radiosity", "radiosity", "SOLVERS", "run_radiosity_batch", "patch_count",
           "BYTES_PER_PATCH", "BYTES_PER_NONZERO"]

#: Linear solvers of :func:`solve_radiosity`.
SOLVERS = ("jacobi", "direct")
#: Rays cast per call of the tracer while estimating form factors (memory bound).
RAYS_PER_CHUNK = 1 << 16
#: Peak bytes per patch while meshing and estimating (corners, area, normal,
#: index; two sides' emission, environment, ray counts and areas; the
#: meshing temporaries of its triangle), rounded up.
BYTES_PER_PATCH = 512
#: Bytes per non-zero of the form-factor counts as the solve uses them (the
#: CSR counts, ``C + C^T`` in COO and the CSR matrix: value and two indices each).
BYTES_PER_NONZERO = 48


def patch_count(scene: Scene, patch_size: float) -> int:
    """Patches :func:`mesh_patches` makes of ``scene`` at ``patch_size``
    (``sum k^2``, ``k = ceil(longest edge / patch_size)`` per triangle),
    computed without meshing (in float: a huge count does not overflow)."""
    h = check_positive(patch_size, "patch_size")
    tri = scene.triangles
    edges = np.linalg.norm(tri[:, [1, 2, 0]] - tri, axis=2).max(axis=1)
    k = np.maximum(1.0, np.ceil(edges / h - 1e-9))
    return int(min(float(np.sum(k * k)), 2.0 ** 62))


def _check_patch_budget(n_patches: int, patch_size) -> None:
    check_budget("patch_size", patch_size, float(n_patches) * BYTES_PER_PATCH,
                 what=f"{n_patches} patches of {BYTES_PER_PATCH} bytes; a larger patch_size makes fewer")


def _check_counts_budget(n_side: int, total_rays: float, rays_per_side: int, emitter_rays: int,
                         patch_size) -> None:
    """The counts matrix (one non-zero per ray at most, at most ``n_side^2``)
    against the budget; the message blames the larger share of the rays
    (``emitter_rays``, or ``rays_per_side`` from every side of ``patch_size``'s patches)."""
    nonzero = min(float(total_rays), float(n_side) ** 2)
    big = emitter_rays > float(n_side) * rays_per_side
    label = f"emitter_rays={emitter_rays!r}" if big else \
        f"rays_per_side={rays_per_side!r} on the patches of patch_size={patch_size!r}"
    check_budget(label, None, nonzero * BYTES_PER_NONZERO,
                 what=f"form-factor counts of {n_side} sides: up to one non-zero per ray, at most {n_side}^2")


def check_diffuse(scene: Scene) -> None:
    """Raise ``ValueError`` unless radiosity can represent ``scene``.

    Radiosity holds only diffuse (Lambertian) surfaces on triangles: a
    mirror, glass or any other BSDF, or a sphere, is named in the message.
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a mcvar.scene.Scene; got {type(scene).__name__}")
    used = np.unique(scene.prim_material)
    bad = [f"{scene.material_names[m]!r} ({type(scene.materials[m]).__name__})"
           for m in used if type(scene.materials[m]) is not Lambertian]
    if bad:
        raise ValueError(f"radiosity handles only diffuse (Lambertian) surfaces; scene {scene.name!r} "
                         f"has the non-diffuse material(s) {', '.join(bad)}")
    if scene.n_spheres:
        raise ValueError(f"radiosity meshes triangles only; scene {scene.name!r} has "
                         f"{scene.n_spheres} sphere(s)")
    if getattr(scene, "n_point_lights", 0):
        raise ValueError(f"radiosity transports light between patches; scene {scene.name!r} has "
                         f"{scene.n_point_lights} point light(s), which no patch can hold")
    if scene.n_triangles == 0:
        raise ValueError(f"scene {scene.name!r} has no triangles to mesh into patches")


# ---------------------------------------------------------------------------
# Meshing

@dataclass(frozen=True, eq=False)
class Patches:
    """Sub-triangle patches of a scene's triangles.

    Attributes
    ----------
    patch_size : float
        Requested longest sub-edge (scene units).
    triangle : ndarray of int, shape (n,)
        Scene triangle each patch lies on.
    corners : ndarray, shape (n, 3, 3)
        Patch vertices, in the orientation of their triangle.
    area : ndarray, shape (n,)
    normal : ndarray, shape (n, 3)
        Unit geometric normal of the patch's triangle (side 0 faces along it).
    divisions : ndarray of int, shape (T,)
        ``k`` of every scene triangle (its patches are ``k^2`` sub-triangles).
    offset : ndarray of int, shape (T,)
        Index of each triangle's first patch.
    """

    patch_size: float
    triangle: np.ndarray
    corners: np.ndarray
    area: np.ndarray
    normal: np.ndarray
    divisions: np.ndarray
    offset: np.ndarray

    @property
    def n(self) -> int:
        return self.triangle.shape[0]

    def locate(self, prim, bary) -> np.ndarray:
        """Patch index of points given by their triangle and barycentrics ``(b1, b2)``.

        Sub-triangles of a triangle with ``k`` divisions are numbered by cell
        ``(i, j) = floor(k (b1, b2))``: the 'up' triangle of the cell
        (``frac_i + frac_j < 1``) is local index ``2 (i k + j)``, the 'down'
        one ``2 (i k + j) + 1``; :func:`mesh_patches` keeps the valid ones
        and this maps a local index to the kept numbering.
        """
        k = np.take(self.divisions, prim)
        a = np.clip(bary[:, 0], 0.0, 1.0) * k
        c = np.clip(bary[:, 1], 0.0, 1.0) * k
        i = np.minimum(np.floor(a).astype(np.int64), k - 1)
        j = np.minimum(np.floor(c).astype(np.int64), k - 1)
        down = (a - i) + (c - j) >= 1.0
        # a 'down' cell exists only for i + j <= k - 2; points on the far edge go up
        down &= i + j <= k - 2
        over = i + j > k - 1
        j = np.where(over, k - 1 - i, j)
        return np.take(self.offset, prim) + _local_index(i, j, down, k)


def _local_index(i, j, down, k):
    """Rank of sub-triangle (i, j, down) among the k^2 sub-triangles of a triangle,
    numbered row by row (i), 'up' before 'down' in each cell."""
    # cells before row i: sum over r < i of (k - r) up + (k - r - 1) down = i (2k - i)
    return i * (2 * k - i) + 2 * j + down.astype(np.int64)


def mesh_patches(scene: Scene, patch_size: float) -> Patches:
    """Cut every triangle of ``scene`` into ``k^2`` congruent sub-triangles.

    Parameters
    ----------
    scene : Scene
    patch_size : float
        Largest allowed sub-edge length, > 0 (scene units; the Cornell box's
        walls are about 550 long).

    Returns
    -------
    Patches
    """
    h = check_positive(patch_size, "patch_size")
    _check_patch_budget(patch_count(scene, h), patch_size)
    tri = scene.triangles
    edges = np.linalg.norm(tri[:, [1, 2, 0]] - tri, axis=2).max(axis=1)
    k_all = np.maximum(1, np.ceil(edges / h - 1e-9).astype(np.int64))
    counts = k_all * k_all
    offset = np.concatenate([[0], np.cumsum(counts)[:-1]])
    tri_idx, corners = [], []
    for k in np.unique(k_all):
        sel = np.flatnonzero(k_all == k)
        ii, jj = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
        ok = ii + jj <= k - 1
        i, j = ii[ok], jj[ok]
        up = np.stack([np.stack([i, j], -1), np.stack([i + 1, j], -1), np.stack([i, j + 1], -1)], 1)
        okd = i + j <= k - 2
        dn = np.stack([np.stack([i + 1, j], -1), np.stack([i + 1, j + 1], -1),
                       np.stack([i, j + 1], -1)], 1)[okd]
        rank_up = _local_index(i, j, np.zeros(i.shape, bool), k)
        rank_dn = _local_index(i[okd], j[okd], np.ones(okd.sum(), bool), k)
        local = np.concatenate([up, dn]) / k                       # (k^2, 3, 2) barycentrics
        order = np.argsort(np.concatenate([rank_up, rank_dn]))
        local = local[order]
        v0 = tri[sel, 0][:, None, None, :]
        e1 = (tri[sel, 1] - tri[sel, 0])[:, None, None, :]
        e2 = (tri[sel, 2] - tri[sel, 0])[:, None, None, :]
        pts = v0 + local[None, :, :, 0:1] * e1 + local[None, :, :, 1:2] * e2   # (s, k^2, 3, 3)
        for row, t in enumerate(sel):
            tri_idx.append((offset[t], np.full(k * k, t)))
            corners.append((offset[t], pts[row]))
    n = int(counts.sum())
    triangle = np.empty(n, dtype=np.int64)
    corner = np.empty((n, 3, 3))
    for (o, t), (_, c) in zip(tri_idx, corners):
        triangle[o:o + t.size] = t
        corner[o:o + t.size] = c
    cr = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    area = 0.5 * np.linalg.norm(cr, axis=1)
    tn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    tn /= np.linalg.norm(tn, axis=1, keepdims=True)
    return Patches(patch_size=h, triangle=triangle, corners=corner, area=area,
                   normal=tn[triangle], divisions=k_all, offset=offset)


def _barycentrics(scene: Scene, prim, points):
    """``(b1, b2)`` of ``points`` in triangles ``prim`` (least squares in the plane)."""
    tri = scene.triangles[prim]
    s, t, _ = _plane_coords(points, tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return np.stack([s, t], axis=-1)


# ---------------------------------------------------------------------------
# Form factors

@dataclass(frozen=True, eq=False)
class FormFactors:
    """Monte Carlo (ray-cast) form factors between patch sides.

    Attributes
    ----------
    counts : scipy.sparse.csr_matrix, shape (2n, 2n)
        ``C_ij``: how many of side ``i``'s rays had side ``j`` as closest hit
        (side ``2p`` faces along patch ``p``'s normal, ``2p + 1`` against it).
    rays_per_side : ndarray of int, shape (2n,)
        ``M_i``.
    area : ndarray, shape (2n,)
        Area of every side.
    env_irradiance : ndarray, shape (2n, 3)
        Irradiance arriving from the environment through rays that escaped.
    emission : ndarray, shape (2n, 3)
        Exitant radiosity ``E = pi Le`` of each side, averaged over its sample points.
    rays : int
        Rays traced.
    """

    counts: sp.csr_matrix
    rays_per_side: np.ndarray
    area: np.ndarray
    env_irradiance: np.ndarray
    emission: np.ndarray
    rays: int

    @property
    def one_way(self) -> sp.csr_matrix:
        """``F_ij = C_ij / M_i``: unbiased, every row sums to the fraction of
        side ``i``'s rays that hit anything (<= 1, exactly 1 in a closed room);
        standard error ``sqrt(F_ij (1 - F_ij) / M_i)``."""
        return sp.csr_matrix(sp.diags(1.0 / self.rays_per_side) @ self.counts)

    @property
    def matrix(self) -> sp.csr_matrix:
        """Both directions' rays combined: ``F_ij = G_ij / A_i`` with
        ``G_ij = (C_ij + C_ji) / (M_i / A_i + M_j / A_j)``.

        ``A_i C_ij / M_i`` and ``A_j C_ji / M_j`` are two unbiased estimates
        of the same ``G_ij = A_i F_ij = A_j F_ji``, with variances about
        ``A_i G_ij / M_i`` and ``A_j G_ij / M_j``; this is their
        inverse-variance weighted mean. It is reciprocal by construction, so
        the many rays shot from a small light (``emitter_rays``) sharpen
        every receiver's direct lighting. Rows sum to 1 only within Monte
        Carlo error.
        """
        c = self.counts
        both = (c + c.T).tocoo()
        density = self.rays_per_side / self.area
        g = both.data / (density[both.row] + density[both.col])
        return sp.csr_matrix((g / self.area[both.row], (both.row, both.col)), shape=c.shape)

    @property
    def row_sums(self) -> np.ndarray:
        """Row sums of :attr:`one_way`."""
        return np.asarray(self.counts.sum(axis=1)).ravel() / self.rays_per_side


def _emitting_sides(scene: Scene, patches: Patches) -> np.ndarray:
    """Sides that may emit: front sides of emitting triangles, both if two-sided."""
    emits = np.any(scene.prim_emission[patches.triangle] > 0, axis=1)
    two = scene.prim_two_sided_emission[patches.triangle]
    return np.stack([emits, emits & two], axis=1).reshape(-1)


def form_factors(scene: Scene, patches: Patches, *, rays_per_side: int = 256, emitter_rays: int = 1 << 20,
                 rng=None, tracer: Tracer | None = None, progress=None) -> FormFactors:
    """Estimate every side-to-side form factor by ray casting (Malley's method).

    Parameters
    ----------
    scene : Scene
    patches : Patches
        From :func:`mesh_patches` of the same scene.
    rays_per_side : int
        ``M`` rays from uniform points of each patch side, cosine-distributed
        about its normal.
    emitter_rays : int
        Rays shot from the emitting sides together, spread over them in
        proportion to their area (each gets at least ``rays_per_side``):
        with :attr:`FormFactors.matrix` they carry the direct lighting, the
        part the few receiver rays that hit a small light estimate badly.
    rng : None, int, SeedSequence or Generator
    tracer : Tracer, optional
        Reused if given.
    progress : callable, optional
        ``progress(rays_done, rays_total)`` after every chunk.

    Returns
    -------
    FormFactors

    Notes
    -----
    The rays leave ``ray_epsilon`` off the surface; a ray whose closest hit
    is triangle ``t`` at point ``y`` lands on the patch :meth:`Patches.locate`
    gives, on the side its direction arrives from (front if
    ``d . n_t < 0``). Work is cut into chunks of about
    :data:`RAYS_PER_CHUNK` rays (whole sides, or pieces of a side that has
    more), summed into the sparse counts chunk by chunk, so memory is bounded
    by the chunk and the distinct side pairs hit; a count matrix that could
    exceed the memory budget (one non-zero per ray, at most ``(2n)^2``,
    :data:`BYTES_PER_NONZERO` each) is a ``ValueError`` before any ray.
    """
    m = check_count(rays_per_side, "rays_per_side")
    m_e = check_count(emitter_rays, "emitter_rays")
    rng = as_rng(rng)
    tracer = Tracer(scene) if tracer is None else tracer
    n_side = 2 * patches.n
    area = np.repeat(patches.area, 2)
    per_side = np.full(n_side, m, dtype=np.int64)
    emitting = _emitting_sides(scene, patches)
    if np.any(emitting):
        share = area[emitting] / area[emitting].sum()
        per_side[emitting] = np.maximum(m, np.ceil(m_e * share).astype(np.int64))
    ends = np.cumsum(per_side)
    total = int(ends[-1])
    _check_counts_budget(n_side, total, m, m_e, patches.patch_size)
    counts = None
    env = np.zeros((n_side, 3))
    emission = np.zeros((n_side, 3))
    eps = float(scene.ray_epsilon)
    pos = 0                                   # first ray of the chunk (rays numbered side after side)
    while pos < total:
        first = int(np.searchsorted(ends, pos, side="right"))
        if pos == ends[first] - per_side[first]:   # whole sides, up to RAYS_PER_CHUNK rays
            last = int(np.searchsorted(ends, pos + RAYS_PER_CHUNK, side="right"))
            last = min(n_side, max(last, first + 1))
            stop = min(int(ends[last - 1]), pos + RAYS_PER_CHUNK)   # a side of more rays: split
        else:                                      # the rest of a split side
            stop = min(int(ends[first]), pos + RAYS_PER_CHUNK)
        s = np.searchsorted(ends, np.arange(pos, stop), side="right")
        side = np.arange(s[0], s[-1] + 1)
        pos = stop
        patch = s // 2
        sign = np.where(s % 2 == 0, 1.0, -1.0)
        b = square_to_uniform_triangle(rng.random((s.size, 2)))
        c = patches.corners[patch]
        x = c[:, 0] + b[:, 0:1] * (c[:, 1] - c[:, 0]) + b[:, 1:2] * (c[:, 2] - c[:, 0])
        nrm = patches.normal[patch] * sign[:, None]
        d = Frame(nrm).to_world(square_to_cosine_hemisphere(rng.random((s.size, 2))))
        tri = patches.triangle[patch]
        le = scene.emission(tri, x, patches.normal[patch], -nrm)   # as a ray arriving on that side
        for ch in range(3):
            emission[side, ch] += np.pi * np.bincount(s - side[0], le[:, ch], side.size) / per_side[side]
        hit = tracer.intersect(x + eps * nrm, d)
        ok = hit.prim >= 0
        if not np.all(ok) and scene.environment is not None:
            l_env = np.zeros((s.size, 3))
            l_env[~ok] = scene.environment.radiance(d[~ok])
            for ch in range(3):
                env[side, ch] += np.pi * np.bincount(s - side[0], l_env[:, ch], side.size) / per_side[side]
        prim = hit.prim[ok]
        y = x[ok] + hit.t[ok, None] * d[ok]
        j = patches.locate(prim, _barycentrics(scene, prim, y))
        back = np.einsum("ij,ij->i", d[ok], tracer.triangle_normal[prim]) > 0.0
        # summed chunk by chunk: memory holds the distinct (i, j) pairs, not one entry per ray
        chunk = sp.coo_matrix((np.ones(int(ok.sum())), (s[ok], 2 * j + back)), shape=(n_side, n_side)).tocsr()
        counts = chunk if counts is None else counts + chunk
        if progress is not None:
            progress(stop, total)
    counts.sum_duplicates()
    return FormFactors(counts=counts, rays_per_side=per_side, area=area, env_irradiance=env,
                       emission=emission, rays=total)


# ---------------------------------------------------------------------------
# Solving

def solve_radiosity(matrix, reflectance, emission, *, solver: str = "jacobi", tol: float = 1e-6,
                    max_iterations: int = 10_000):
    """Solve ``(I - diag(rho) F) B = E`` for every RGB channel.

    Parameters
    ----------
    matrix : sparse or dense (n, n)
        Form factors ``F`` (rows sum to at most 1).
    reflectance : array_like, shape (n, 3)
        Diffuse albedo ``rho`` of every side, in [0, 1).
    emission : array_like, shape (n, 3)
        Source term ``E`` (exitant radiosity from emission, plus
        ``rho H_env`` when an environment lights the scene).
    solver : {'jacobi', 'direct'}
        ``'jacobi'``: ``B_{k+1} = E + rho F B_k`` from ``B_0 = E`` (the
        ``k``-th iterate holds the light of at most ``k`` bounces), until the
        residual ``max |E + rho F B_k - B_k| <= tol * max |B_k|``; converges
        since ``rho F`` has row sums below 1 (Cohen and Wallace, ch. 5).
        ``'direct'``: ``scipy.sparse.linalg.spsolve`` (SuperLU).
    tol : float
        Relative stopping residual of the Jacobi iteration, > 0.
    max_iterations : int
        ``ValueError`` if Jacobi has not met ``tol`` by then.

    Returns
    -------
    B : ndarray, shape (n, 3)
    iterations : int
        Jacobi iterations (0 for ``'direct'``).
    residual : float
        Final relative residual ``max |E + rho F B - B| / max |B|``.
    """
    solver = check_choice(solver, "solver", SOLVERS)
    tol = check_positive(tol, "tol")
    max_iterations = check_count(max_iterations, "max_iterations")
    f = sp.csr_matrix(matrix)
    n = f.shape[0]
    rho = as_array(reflectance, "reflectance", ndim=2, last=3, nonnegative=True)
    e = as_array(emission, "emission", ndim=2, last=3, nonnegative=True)
    if f.shape != (n, n) or rho.shape[0] != n or e.shape[0] != n:
        raise ValueError(f"matrix must be square and match reflectance and emission rows; got "
                         f"{f.shape}, {rho.shape}, {e.shape}")
    if not np.all(rho < 1.0):
        raise ValueError("reflectance must be < 1 for the radiosity system to have a solution")

    def residual(b):
        return e + rho * (f @ b) - b

    if solver == "direct":
        b = np.empty((n, 3))
        eye = sp.identity(n, format="csc")
        for c in range(3):
            b[:, c] = spla.spsolve((eye - sp.diags(rho[:, c]) @ f).tocsc(), e[:, c])
        scale = max(float(np.abs(b).max()), 1e-300)
        return b, 0, float(np.abs(residual(b)).max() / scale)
    b = e.copy()
    for it in range(1, max_iterations + 1):
        r = residual(b)
        scale = max(float(np.abs(b).max()), 1e-300)
        res = float(np.abs(r).max()) / scale
        if res <= tol:
            return b, it - 1, res
        b += r
    raise ValueError(f"Jacobi iteration did not reach tol={tol} in max_iterations={max_iterations} "
                     f"(relative residual {res:.3g}); raise max_iterations or use solver='direct'")


@dataclass(frozen=True, eq=False)
class Radiosity:
    """A solved radiosity system of a scene and its first-hit lookup.

    Attributes
    ----------
    patches : Patches
    form_factors : FormFactors
    reflectance : ndarray, shape (2n, 3)
    radiosity : ndarray, shape (2n, 3)
        Exitant radiosity ``B`` of every side (W/m^2 analogue; radiance ``B / pi``).
    irradiance : ndarray, shape (2n, 3)
        ``H = F B + H_env``, what the lookup reflects.
    iterations : int
    residual : float
    seconds : float
        Form factors plus solve.
    """

    patches: Patches
    form_factors: FormFactors
    reflectance: np.ndarray
    radiosity: np.ndarray
    irradiance: np.ndarray
    iterations: int
    residual: float
    seconds: float

    def radiance(self, scene: Scene, tracer: Tracer, origins, directions) -> np.ndarray:
        """Radiance towards the ray origins from the first hit of every ray, ``(n, 3)``.

        ``Le(hit) + rho / pi * H(patch side)``: the emission is exact at the
        hit (the light's edge stays sharp), the reflected part is flat over
        a patch. Misses see the environment (or black).
        """
        o = np.asarray(origins, dtype=np.float64)
        d = np.asarray(directions, dtype=np.float64)
        hit = tracer.intersect(o, d)
        out = np.zeros((o.shape[0], 3))
        ok = hit.prim >= 0
        if scene.environment is not None and not np.all(ok):
            out[~ok] = scene.environment.radiance(d[~ok])
        if not np.any(ok):
            return out
        prim = hit.prim[ok]
        y = o[ok] + hit.t[ok, None] * d[ok]
        j = self.patches.locate(prim, _barycentrics(scene, prim, y))
        back = np.einsum("ij,ij->i", d[ok], tracer.triangle_normal[prim]) > 0.0
        side = 2 * j + back
        n_g = tracer.triangle_normal[prim]
        out[ok] = scene.emission(prim, y, n_g, d[ok]) + self.reflectance[side] / np.pi * self.irradiance[side]
        return out


@dataclass(frozen=True)
class RadiositySettings:
    """The mesh, form-factor and solver settings of :func:`radiosity` (its keywords)."""

    patch_size: float = 40.0
    rays_per_side: int = 256
    emitter_rays: int = 1 << 20
    solver: str = "jacobi"
    tol: float = 1e-6


def radiosity(scene: Scene, settings: RadiositySettings | None = None, *, rng=None, tracer: Tracer | None = None,
              progress=None, **options) -> Radiosity:
    """Mesh, form factors and solve: the whole finite-element radiosity of ``scene``.

    Parameters
    ----------
    scene : Scene
        Lambertian triangles only (:func:`check_diffuse`).
    settings : RadiositySettings, optional
        ``patch_size``, ``rays_per_side``, ``emitter_rays``, ``solver`` and
        ``tol`` as one record; those keywords replace its fields.
    rng : None, int, SeedSequence or Generator
    tracer : Tracer, optional
    progress : callable, optional
        As in :func:`form_factors`.

    Other Parameters
    ----------------
    patch_size : float
        Longest sub-edge of a patch (scene units; default 40: 1 950 patches,
        3 900 sides in the Cornell box).
    rays_per_side, emitter_rays : int
        As in :func:`form_factors`.
    solver : {'jacobi', 'direct'}
        As in :func:`solve_radiosity`.
    tol : float
        As in :func:`solve_radiosity`.

    Returns
    -------
    Radiosity
    """
    opts = settings_with(RadiositySettings, settings, options, "radiosity")
    patch_size, rays_per_side, emitter_rays, solver, tol = (opts.patch_size, opts.rays_per_side,
                                                            opts.emitter_rays, opts.solver, opts.tol)
    check_diffuse(scene)
    _check_radiosity_budget(scene, patch_size, rays_per_side, emitter_rays)
    start = time.perf_counter()
    patches = mesh_patches(scene, patch_size)
    ff = form_factors(scene, patches, rays_per_side=rays_per_side, emitter_rays=emitter_rays, rng=rng,
                      tracer=tracer, progress=progress)
    f = ff.matrix
    albedo = np.array([np.asarray(m.albedo, dtype=np.float64) for m in scene.materials]).reshape(-1, 3)
    rho = np.repeat(albedo[scene.prim_material[patches.triangle]], 2, axis=0)
    source = ff.emission + rho * ff.env_irradiance
    b, its, res = solve_radiosity(f, rho, source, solver=solver, tol=tol)
    h = f @ b + ff.env_irradiance
    return Radiosity(patches=patches, form_factors=ff, reflectance=rho, radiosity=b, irradiance=h,
                     iterations=its, residual=res, seconds=time.perf_counter() - start)


# ---------------------------------------------------------------------------
# The registered method

def _radiosity_options(options) -> None:
    check_positive(options["patch_size"], "patch_size")
    check_count(options["rays_per_side"], "rays_per_side")
    check_count(options["emitter_rays"], "emitter_rays")
    check_choice(options["solver"], "solver", SOLVERS)


def _check_radiosity_budget(scene, patch_size, rays_per_side, emitter_rays) -> None:
    """The patches and the form-factor counts of a solve checked against the
    memory budget, before anything is meshed or traced."""
    m = check_count(rays_per_side, "rays_per_side")
    m_e = check_count(emitter_rays, "emitter_rays")
    n = patch_count(scene, patch_size)
    _check_patch_budget(n, patch_size)
    _check_counts_budget(2 * n, 2.0 * n * m + m_e, m, m_e, patch_size)


def _check_radiosity(scene, options) -> None:
    """``check_scene`` of ``radiosity``: Lambertian triangles only, valid options
    whose patches and form factors fit the memory budget."""
    _radiosity_options(options)
    check_diffuse(scene)
    _check_radiosity_budget(scene, options["patch_size"], options["rays_per_side"], options["emitter_rays"])


def _prepare_radiosity(scene, options, rng) -> Radiosity:
    """``prepare`` of ``radiosity``: the whole solve, once per render (the parent process)."""
    return radiosity(scene, patch_size=options["patch_size"], rays_per_side=options["rays_per_side"],
                     emitter_rays=options["emitter_rays"], solver=options["solver"], rng=rng)


def run_radiosity_batch(job: BatchJob) -> BatchResult:
    """``run_batch`` of ``radiosity``: look the solved radiosity up at every camera ray's first hit."""
    n = job.n_pixels * job.spp
    _, o, d, _ = camera_rays(job)
    o = np.ascontiguousarray(o)
    return camera_result(job, job.prepared.radiance(job.scene, job.tracer, o, d), n, "radiosity")


register(Method(
    "radiosity", "first_hit", run_radiosity_batch,
    "finite-element radiosity: patches, ray-cast form factors, (I - rho F) B = E, flat lookup at the first hit",
    options=dict(patch_size=70.0, rays_per_side=256, emitter_rays=1 << 18, solver="jacobi"),
    prepare=_prepare_radiosity, check_scene=_check_radiosity, uses_max_depth=False, lecture=("no", "no"),
    chart_row="Finite Element Radiosity",
    # the chart: patch size halves as the level quadruples; form-factor rays, emitter rays and pixel
    # samples refined with it (at fixed spp the pixel-sampling noise would hide the shrinking mesh bias)
    knob=scaled_knob("mesh refinement (patch size 280 / sqrt(level))", "radiosity",
                     {"spp": (4, 1), "patch_size": (280.0, -0.5), "rays_per_side": (16, 0.5),
                      "emitter_rays": (4096, 1)}),
    theory=("yes", "no", "radiosity's mesh: piecewise-constant patches bias the image; the bias falls only as "
                         "the mesh is refined (its knob here), never with spp")))
