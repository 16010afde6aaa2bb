"""Finite-element radiosity: meshing, ray-cast form factors against Howell's
analytic values, row sums, reciprocity, the solvers, exact scenes, and the
Cornell box against path tracing.

Tolerances: Z = 5 standard errors, Sidak-corrected where a family of
comparisons is tested (per-test family alpha = 2 * norm.sf(5) = 5.7e-7).
Ray-cast form factors are binomial: a face's ``R`` rays that land on another
face with probability ``F`` give ``F_hat`` with standard error
``sqrt(F (1 - F) / R)``.
"""
import numpy as np
import pytest
from scipy import stats
from scipy.ndimage import binary_dilation

from mcvar.bsdf import Lambertian
from mcvar.integrators import render
from mcvar.integrators.radiosity import (check_diffuse, form_factors, mesh_patches, radiosity, solve_radiosity)
from mcvar.scene import Camera, Scene, load_scene
from mcvar.tracer import Tracer

SEED = 314159265358
ALPHA = 2 * stats.norm.sf(5.0)


def _z(n_tests):
    """Two-sided normal quantile of a family of ``n_tests`` at family level ALPHA (Sidak)."""
    return stats.norm.isf(0.5 * (1.0 - (1.0 - ALPHA) ** (1.0 / n_tests)))


def _cube(albedo=0.5, emission=0.0):
    """The closed unit cube [0, 1]^3, six faces as triangle pairs, normals inward."""
    quads = []
    for axis in range(3):
        for lo in (0.0, 1.0):
            a, b = (axis + 1) % 3, (axis + 2) % 3
            corners = []
            for u, v in ((0, 0), (1, 0), (1, 1), (0, 1)):
                p = np.zeros(3)
                p[axis], p[a], p[b] = lo, u, v
                corners.append(p)
            q = np.array(corners)
            n = np.cross(q[1] - q[0], q[2] - q[0])
            inward = np.zeros(3)
            inward[axis] = 1.0 if lo == 0.0 else -1.0
            if n @ inward < 0:
                q = q[::-1]
            quads.append(q)
    tris = np.array([[q[0], q[1], q[2]] for q in quads] + [[q[0], q[2], q[3]] for q in quads])
    tris = tris[np.argsort(np.r_[np.arange(6), np.arange(6)], kind="stable")]   # face f: triangles 2f, 2f+1
    return Scene(name="cube", triangles=tris, sphere_centers=np.zeros((0, 3)), sphere_radii=np.zeros(0),
                 prim_material=np.zeros(12, int), prim_emission=np.full((12, 3), float(emission)),
                 prim_two_sided_emission=np.zeros(12, bool), prim_light=np.full(12, -1),
                 prim_group=np.zeros(12, int), materials=(Lambertian(albedo),), material_names=("white",),
                 light_origin=np.zeros((0, 3)), light_edge1=np.zeros((0, 3)), light_edge2=np.zeros((0, 3)),
                 light_radiance=np.zeros((0, 3)),
                 camera=Camera((0.5, 0.5, 0.1), (0.5, 0.5, 1.0), (0.0, 1.0, 0.0), 60.0), ray_epsilon=1e-6)


def _howell_parallel(x, y):
    """Form factor between directly opposed x-by-y rectangles at distance 1 (Howell, C-11)."""
    a, b = 1 + x * x, 1 + y * y
    return 2 / (np.pi * x * y) * (np.log(np.sqrt(a * b / (1 + x * x + y * y)))
                                  + x * np.sqrt(b) * np.arctan(x / np.sqrt(b))
                                  + y * np.sqrt(a) * np.arctan(y / np.sqrt(a))
                                  - x * np.arctan(x) - y * np.arctan(y))


def _howell_perpendicular(h, w):
    """Form factor from a 1-by-w rectangle to a perpendicular h-by-w... with a common
    edge of length 1: Howell C-14, ``H = h / l``, ``W = w / l``."""
    H, W = h, w
    s = H * H + W * W
    log = np.log((1 + W * W) * (1 + H * H) / (1 + s)
                 * (W * W * (1 + s) / ((1 + W * W) * s)) ** (W * W)
                 * (H * H * (1 + s) / ((1 + H * H) * s)) ** (H * H))
    return (W * np.arctan(1 / W) + H * np.arctan(1 / H) - np.sqrt(s) * np.arctan(1 / np.sqrt(s))
            + 0.25 * log) / (np.pi * W)


@pytest.fixture(scope="module")
def cornell():
    return load_scene("cornell")


@pytest.fixture(scope="module")
def cube_ff():
    scene = _cube()
    patches = mesh_patches(scene, 0.5)
    return scene, patches, form_factors(scene, patches, rays_per_side=2048, rng=SEED)


def test_mesh_covers_every_triangle_and_locates_points(cornell):
    patches = mesh_patches(cornell, 70.0)
    tri = cornell.triangles
    areas = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    np.testing.assert_allclose(np.bincount(patches.triangle, patches.area), areas, rtol=1e-12)
    edges = np.linalg.norm(patches.corners[:, [1, 2, 0]] - patches.corners, axis=2)
    assert edges.max() <= 70.0 * (1 + 1e-9)
    # the centroid of every patch is located in that patch
    centroid_bary = np.zeros((patches.n, 2))
    for t in np.unique(patches.triangle):
        sel = patches.triangle == t
        v0, e1, e2 = tri[t, 0], tri[t, 1] - tri[t, 0], tri[t, 2] - tri[t, 0]
        c = patches.corners[sel].mean(axis=1) - v0
        centroid_bary[sel] = np.linalg.lstsq(np.stack([e1, e2], 1), c.T, rcond=None)[0].T
    np.testing.assert_array_equal(patches.locate(patches.triangle, centroid_bary), np.arange(patches.n))


def test_closed_cube_rows_sum_to_one_and_match_howell(cube_ff):
    scene, patches, ff = cube_ff
    inner = np.arange(0, 2 * patches.n, 2)           # normals point inwards: side 0 is inside
    # a closed room: every inner ray hits a wall (an escape would be a crack in the tracer)
    np.testing.assert_array_equal(ff.row_sums[inner], 1.0)
    np.testing.assert_array_equal(ff.row_sums[inner + 1], 0.0)   # outside: nothing to see
    face = patches.triangle // 2
    face_of_side = np.repeat(face, 2)
    counts = ff.counts.tocoo()
    hits = np.zeros((6, 6))
    np.add.at(hits, (face_of_side[counts.row], face_of_side[counts.col]), counts.data)
    rays = np.bincount(face_of_side[inner], ff.rays_per_side[inner], minlength=6)
    f_hat = hits / rays[:, None]
    par, perp = _howell_parallel(1.0, 1.0), _howell_perpendicular(1.0, 1.0)
    assert par + 4 * perp == pytest.approx(1.0, abs=1e-12)   # the catalogue's values close the cube
    axis = np.arange(6) // 2
    expected = np.where(axis[:, None] == axis[None, :], par, perp)
    np.fill_diagonal(expected, 0.0)
    se = np.sqrt(expected * (1 - expected) / rays[:, None])
    off = ~np.eye(6, dtype=bool)
    assert np.all(np.abs(f_hat - expected)[off] <= _z(30) * se[off])
    assert np.all(np.diag(hits) == 0)                 # a plane cannot see itself


def test_furnace_cube_solution_is_exact(cube_ff):
    scene, patches, ff = cube_ff
    rho, le = 0.5, 2.0
    e = np.zeros((2 * patches.n, 3))
    e[0::2] = np.pi * le
    r = np.full_like(e, rho)
    for solver in ("jacobi", "direct"):
        b, its, res = solve_radiosity(ff.one_way, r, e, solver=solver, tol=1e-10)
        assert res <= 1e-10
        np.testing.assert_allclose(b[0::2], np.pi * le / (1 - rho), rtol=1e-8)
        np.testing.assert_allclose(b[1::2], 0.0, atol=1e-12)
    # Jacobi iterate k holds k bounces: rho^k falls below tol after log(tol)/log(rho) steps
    _, its, _ = solve_radiosity(ff.one_way, r, e, solver="jacobi", tol=1e-6)
    # B_k = E (1 + rho + ... + rho^k), residual E rho^(k+1): the first k with
    # rho^(k+1) / (1 + ... + rho^k) <= 1e-6
    k = next(k for k in range(1000) if rho ** (k + 1) / sum(rho ** m for m in range(k + 1)) <= 1e-6)
    assert its == k


def test_cornell_rows_at_most_one_and_reciprocity(cornell):
    patches = mesh_patches(cornell, 140.0)
    ff = form_factors(cornell, patches, rays_per_side=1024, emitter_rays=1 << 16, rng=SEED)
    assert np.all(ff.row_sums <= 1.0)
    # open front: inner sides lose rays; the reflectances therefore never push B past E/(1-rho)
    # reciprocity A_I F_IJ = A_J F_JI aggregated over (quad, side), one-way estimates
    quad_side = 2 * (patches.triangle // 2)
    group = np.stack([quad_side, quad_side + 1], 1).reshape(-1)
    g = int(group.max()) + 1
    c = ff.counts.tocoo()
    w = ff.area / ff.rays_per_side                     # each ray of side i carries A_i / M_i
    est = np.zeros((g, g))
    np.add.at(est, (group[c.row], group[c.col]), w[c.row] * c.data)
    # variance of sum_i A_i C_iJ / M_i with C_iJ ~ Binomial(M_i, p_iJ), p plugged in per side
    per_side = np.zeros((2 * patches.n, g))
    np.add.at(per_side, (c.row, group[c.col]), c.data)
    p = per_side / ff.rays_per_side[:, None]
    var_side = (ff.area ** 2)[:, None] * p * (1 - p) / ff.rays_per_side[:, None]
    var = np.zeros((g, g))
    np.add.at(var, group, var_side)
    hits = np.zeros((g, g))
    np.add.at(hits, (group[c.row], group[c.col]), c.data)
    upper = np.triu(np.ones((g, g), bool), 1) & (hits >= 30) & (hits.T >= 30)
    assert upper.sum() >= 20
    z = np.abs(est - est.T)[upper] / np.sqrt(var + var.T)[upper]
    assert z.max() <= _z(int(upper.sum())), z.max()
    # the combined matrix is reciprocal by construction
    m = ff.matrix
    a = ff.area
    np.testing.assert_allclose((m.multiply(a[:, None])).toarray(), (m.multiply(a[:, None])).T.toarray(),
                               rtol=1e-12, atol=1e-12)


def test_quad_under_constant_sky_is_exact():
    scene = load_scene("quad-environment", albedo=0.3, radiance=2.0)
    r = radiosity(scene, patch_size=1.0, rays_per_side=64, rng=SEED)
    tracer = Tracer(scene)
    d = scene.camera.ray_directions((4, 4), np.arange(16), np.full((16, 2), 0.5))
    out = r.radiance(scene, tracer, np.broadcast_to(scene.camera.position, d.shape), d)
    np.testing.assert_allclose(out, 0.3 * 2.0, rtol=1e-12)


def _camera_rays(scene, res, spp, rng):
    w = h = res
    pix = np.repeat(np.arange(w * h), spp)
    d = scene.camera.ray_directions((w, h), pix, rng.random((pix.size, 2)))
    return np.broadcast_to(scene.camera.position, d.shape), d


def test_cornell_image_agrees_with_path_and_error_falls_with_patch_size(cornell):
    res, spp, ref_spp = 24, 16, 512
    ref = render(cornell, spp=ref_spp, res=res, rng=SEED)
    rng = np.random.default_rng(SEED + 1)
    o, d = _camera_rays(cornell, res, spp, rng)
    tracer = Tracer(cornell)
    hit = tracer.intersect(o, d)
    # pixels that see the light (or its edge) are set by pixel sampling, not by transport: masked
    sees_light = (hit.prim >= 0) & (cornell.prim_emission[hit.prim].sum(1) > 0)
    light = np.any(sees_light.reshape(res * res, spp), axis=1)
    keep = ~binary_dilation(light.reshape(res, res)).ravel()
    ref_pix = ref.image.reshape(-1, 3)[keep]
    ref_var = (ref.variance.reshape(-1, 3) / ref_spp)[keep]
    sqs, means = [], []
    for size in (280.0, 140.0, 70.0):
        sol = radiosity(cornell, patch_size=size, rays_per_side=256, emitter_rays=1 << 18, rng=SEED)
        img = sol.radiance(cornell, tracer, o, d).reshape(res * res, spp, 3).mean(1)[keep]
        sqs.append(((img - ref_pix) ** 2 - ref_var).mean(axis=1))   # unbiased squared error per pixel
        means.append(img.mean(0))
    # the error falls as patches shrink: per-pixel paired differences, each step
    # by more than Z standard errors of their mean (pixels as the sample)
    for k in range(2):
        diff = sqs[k] - sqs[k + 1]
        assert diff.mean() > _z(2) * diff.std(ddof=1) / np.sqrt(diff.size), [s.mean() for s in sqs]
    # image mean at the finest mesh: a few percent (3 %) plus Z standard errors of the reference
    ref_mean = ref_pix.mean(0)
    ref_se = np.sqrt(ref_var.sum(0)) / ref_pix.shape[0]
    assert np.all(np.abs(means[-1] - ref_mean) <= 0.03 * ref_mean + _z(3) * ref_se), (means[-1], ref_mean)


def test_solvers_agree(cornell):
    a = radiosity(cornell, patch_size=280.0, rays_per_side=64, emitter_rays=4096, rng=SEED, tol=1e-12)
    b = radiosity(cornell, patch_size=280.0, rays_per_side=64, emitter_rays=4096, rng=SEED, solver="direct")
    # Jacobi stops at a residual of 1e-12 * max B, so both agree to about 1/(1 - rho) times that
    np.testing.assert_allclose(a.radiosity, b.radiosity, rtol=0, atol=1e-10 * b.radiosity.max())
    assert a.iterations > 0 and b.iterations == 0


def test_bad_input(cornell):
    with pytest.raises(ValueError, match="mirror"):
        radiosity(load_scene("cornell-spheres"))
    with pytest.raises(ValueError, match="sphere"):
        check_diffuse(load_scene("furnace"))
    with pytest.raises(ValueError, match="patch_size"):
        mesh_patches(cornell, 0.0)
    with pytest.raises(ValueError, match="rays_per_side"):
        radiosity(cornell, rays_per_side=0)
    with pytest.raises(ValueError, match="solver"):
        radiosity(cornell, patch_size=280.0, rays_per_side=8, emitter_rays=8, solver="gauss")
    with pytest.raises(ValueError, match="reflectance"):
        solve_radiosity(np.eye(2) * 0.5, np.ones((2, 3)), np.ones((2, 3)))
    with pytest.raises(TypeError, match="Scene"):
        check_diffuse("cornell")


def test_registered_radiosity(cornell):
    from mcvar.integrators import METHODS

    m = METHODS["radiosity"]
    assert m.kind == "first_hit" and not m.uses_max_depth and m.lecture == ("no", "no")
    opts = dict(patch_size=140.0, rays_per_side=64, emitter_rays=1 << 14)
    a = render(cornell, integrator="radiosity", spp=4, res=8, rng=SEED, batch_spp=2, **opts)
    b = render(cornell, integrator="radiosity", spp=4, res=8, rng=SEED, batch_spp=2, workers=2, **opts)
    assert a.image.shape == (8, 8, 3) and np.all(np.isfinite(a.image))
    np.testing.assert_array_equal(a.image, b.image)     # the solve is seeded once, batches are per seed
    with pytest.raises(ValueError, match="mirror"):
        render(load_scene("cornell-spheres"), integrator="radiosity", spp=1, res=4)
    with pytest.raises(ValueError, match="patch_size"):
        render(cornell, integrator="radiosity", spp=1, res=4, patch_size=0.0)
    with pytest.raises(ValueError, match="solver"):
        render(cornell, integrator="radiosity", spp=1, res=4, solver="gauss")
