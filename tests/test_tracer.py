"""Ray intersection: exact hits, an independent brute-force oracle, culling
and chunking do not change results, spheres, shadow rays, bad input."""
import numpy as np
import pytest

from mcvar.scene import load_scene
from mcvar.tracer import Tracer

SEED = 8675309


def _oracle(triangles, o, d, eps):
    """Moller-Trumbore in float64, all rays x all triangles: (t of every triangle, best t, best prim)."""
    v0, v1, v2 = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    e1, e2 = v1 - v0, v2 - v0
    p = np.cross(d[:, None, :], e2[None])                    # (n, T, 3)
    det = np.einsum("ntk,tk->nt", p, e1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = o[:, None, :] - v0[None]
        b1 = np.einsum("ntk,ntk->nt", s, p) * inv
        q = np.cross(s, e1[None])
        b2 = np.einsum("nk,ntk->nt", d, q) * inv
        t = np.einsum("ntk,tk->nt", q, e2) * inv
    ok = (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1) & (t > eps) & np.isfinite(t)
    t = np.where(ok, t, np.inf)
    return t, t.min(axis=1), np.where(np.isfinite(t.min(axis=1)), t.argmin(axis=1), -1)


def _random_rays(n, rng):
    """Rays from random points inside the Cornell room in uniform directions."""
    o = rng.random((n, 3)) * [540.0, 530.0, 540.0] + [8.0, 8.0, 8.0]
    d = rng.normal(size=(n, 3))
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def test_single_triangle_exact_hit_and_misses():
    scene = load_scene("cornell")
    tr = Tracer(scene, dtype="float64")
    # straight down onto the floor at (100, 0, 100) from height 50
    hit = tr.intersect([[100.0, 50.0, 100.0]], [[0.0, -1.0, 0.0]])
    assert hit.t[0] == pytest.approx(50.0, rel=1e-12)
    assert hit.prim[0] in (0, 1)
    # a ray leaving through the open front (z < 0) hits nothing
    out = tr.intersect([[278.0, 273.0, 100.0]], [[0.0, 0.0, -1.0]])
    assert out.prim[0] == -1 and out.t[0] == np.inf


@pytest.mark.parametrize("dtype,rtol", [("float64", 1e-9), ("float32", 2e-4)])
def test_intersections_agree_with_brute_force_oracle(dtype, rtol):
    # float32 tolerance: unit roundoff 6e-8 times coordinates up to ~1400 over
    # distances down to ~1 (rays start anywhere in the room) gives ~1e-4.
    rng = np.random.default_rng(SEED)
    scene = load_scene("cornell")
    o, d = _random_rays(6000, rng)
    t_all, t_best, p_best = _oracle(scene.triangles, o, d, scene.ray_epsilon)
    hit = Tracer(scene, dtype=dtype).intersect(o, d)
    # rays through the open front (z < 0) miss; both must agree on which
    np.testing.assert_array_equal(hit.prim >= 0, p_best >= 0)
    assert 0 < np.mean(p_best < 0) < 0.5
    np.testing.assert_allclose(hit.t, t_best, rtol=rtol, atol=0)
    # the chosen triangle is the oracle's, or one the oracle finds equally close (shared edges)
    h = np.flatnonzero(hit.prim >= 0)
    np.testing.assert_allclose(t_all[h, hit.prim[h]], t_best[h], rtol=rtol)


def test_culling_and_chunking_do_not_change_hits():
    rng = np.random.default_rng(SEED + 1)
    scene = load_scene("cornell")
    o, d = _random_rays(5000, rng)
    ref = Tracer(scene, dtype="float64", cull=False, chunk=100000).intersect(o, d)
    for kw in ({"cull": True, "chunk": 2048}, {"cull": True, "chunk": 7}, {"cull": False, "chunk": 1}):
        hit = Tracer(scene, dtype="float64", **kw).intersect(o, d)
        # BLAS may sum the 3-term products in another order: a few ulps
        np.testing.assert_allclose(hit.t, ref.t, rtol=1e-13)
        np.testing.assert_array_equal(hit.prim, ref.prim)


def test_spheres_from_outside_and_inside():
    scene = load_scene("cornell-spheres")
    tr = Tracer(scene)
    c, r = scene.sphere_centers[0], scene.sphere_radii[0]
    o = c + np.array([0.0, 0.0, -300.0])
    hit = tr.intersect(o[None], [[0.0, 0.0, 1.0]])
    assert hit.t[0] == pytest.approx(300.0 - r, rel=1e-12)
    assert hit.prim[0] == scene.n_triangles
    n = tr.normals(hit.prim, o[None] + hit.t[:, None] * [[0.0, 0.0, 1.0]])
    np.testing.assert_allclose(n, [[0.0, 0.0, -1.0]], atol=1e-12)
    furnace = Tracer(load_scene("furnace"))
    rng = np.random.default_rng(SEED + 2)
    d = rng.normal(size=(100, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    inside = furnace.intersect(np.zeros((100, 3)), d)
    np.testing.assert_allclose(inside.t, 1.0, rtol=1e-12)


def test_shadow_rays_blocked_by_the_tall_block_and_not_by_the_light():
    scene = load_scene("cornell")
    tr = Tracer(scene)
    light_centre = scene.light_origin[0] + 0.5 * (scene.light_edge1[0] + scene.light_edge2[0])
    # a floor point under the tall block's top is shadowed; an open floor point is not
    points = np.array([[370.0, 0.01, 350.0], [100.0, 0.01, 450.0]])
    v = light_centre - points
    dist = np.linalg.norm(v, axis=1)
    blocked = tr.occluded(points, v / dist[:, None], dist - 2 * scene.ray_epsilon)
    assert blocked.tolist() == [True, False]


def test_tmax_and_self_intersection_epsilon():
    scene = load_scene("cornell")
    tr = Tracer(scene)
    o = np.array([[100.0, 50.0, 100.0]] * 2)
    d = np.array([[0.0, -1.0, 0.0]] * 2)
    hit = tr.intersect(o, d, tmax=np.array([49.0, 51.0]))
    assert hit.prim.tolist()[0] == -1 and hit.prim[1] >= 0
    # a ray starting on the floor does not hit the floor itself
    on = tr.intersect([[100.0, 0.0, 100.0]], [[0.0, 1.0, 0.0]])
    assert on.t[0] == pytest.approx(548.8, rel=1e-6)


def test_empty_input_and_bad_input():
    tr = Tracer(load_scene("cornell"))
    hit = tr.intersect(np.zeros((0, 3)), np.zeros((0, 3)))
    assert hit.t.shape == (0,) and hit.prim.shape == (0,)
    with pytest.raises(ValueError, match="same shape"):
        tr.intersect(np.zeros((2, 3)), np.ones((3, 3)))
    with pytest.raises(ValueError, match="origins must have shape"):
        tr.intersect(np.zeros((2, 2)), np.ones((2, 2)))
    with pytest.raises(ValueError, match="tmax must not be NaN"):
        tr.intersect(np.zeros((1, 3)), [[0.0, 1.0, 0.0]], tmax=np.nan)
    with pytest.raises(TypeError, match="scene must be"):
        Tracer("cornell")
    with pytest.raises(ValueError, match="dtype must be one of"):
        Tracer(load_scene("cornell"), dtype="float16")


def _shadow_rays(scene, tracer, n, rng):
    """Next-event shadow rays as the integrators build them: from random points
    of random triangles (either side), offset by ray_epsilon, to random points
    of the light; with their keys."""
    tri = scene.triangles
    ti = rng.integers(0, scene.n_triangles, n)
    a, b = rng.random(n), rng.random(n)
    swap = a + b > 1
    a[swap], b[swap] = 1 - a[swap], 1 - b[swap]
    # include points exactly on edges and corners (shared with walls' planes)
    a[:50], b[:50] = 0.0, 0.0
    a[50:100], b[50:100] = 1.0, 0.0
    p = tri[ti, 0] + a[:, None] * (tri[ti, 1] - tri[ti, 0]) + b[:, None] * (tri[ti, 2] - tri[ti, 0])
    u = rng.random((n, 2))
    x = scene.light_origin[0] + u[:, :1] * scene.light_edge1[0] + u[:, 1:] * scene.light_edge2[0]
    v = x - p
    dist = np.linalg.norm(v, axis=1)
    w = v / dist[:, None]
    ng = tracer.triangle_normal[ti]
    side = np.sign(np.einsum("ij,ij->i", w, ng))
    o = p + (scene.ray_epsilon * side)[:, None] * ng
    return o, w, dist - 2 * scene.ray_epsilon, tracer.shadow_keys(ti, side)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_any_hit_shadow_rays_equal_the_closest_hit_oracle(dtype):
    # The any-hit path (boxes first, early exit, triangles dropped by the
    # shadow-key table) must answer exactly as 'anything closer than tmax' of
    # the closest-hit query of the same precision, and as the float64
    # Moller-Trumbore oracle.
    rng = np.random.default_rng(SEED + 3)
    scene = load_scene("cornell")
    tr = Tracer(scene, dtype=dtype)
    o, w, tmax, keys = _shadow_rays(scene, tr, 20000, rng)
    closest = tr.intersect(o, w, tmax).prim >= 0
    with np.errstate(invalid="ignore"):          # the oracle's NaN for rays parallel to a plane
        t_all, _, _ = _oracle(scene.triangles, o, w, scene.ray_epsilon)
    oracle = np.any(t_all < tmax[:, None], axis=1)
    assert 0.05 < oracle.mean() < 0.95                  # both outcomes are exercised
    np.testing.assert_array_equal(tr.occluded(o, w, tmax), closest)
    np.testing.assert_array_equal(tr.occluded(o, w, tmax, keys=keys), closest)
    if dtype == "float64":
        # float32 rounding may flip rays that graze an edge they start on (a few
        # in 10^4 here); in float64 the kernel and the oracle agree exactly
        np.testing.assert_array_equal(closest, oracle)


def test_shadow_key_table_drops_the_walls_for_wall_points_only():
    scene = load_scene("cornell")
    tr = Tracer(scene)
    light_tris = np.flatnonzero(scene.prim_light >= 0)
    blocks = np.flatnonzero(scene.prim_group > 0)
    walls = np.setdiff1d(np.arange(scene.n_triangles), np.concatenate([light_tris, blocks]))
    # floor point lit from above: no wall, floor or ceiling can lie in between
    keep = tr._cand[tr.shadow_keys(np.array([0]), np.array([1]))[0]]
    assert not keep[walls].any() and keep[blocks].all() and keep[light_tris].all()
    # a ray without a key (e.g. towards the environment) keeps every triangle
    assert tr._cand[tr.shadow_keys(np.array([0]), np.array([1]), np.array([-1]))[0]].all()


def test_occluded_with_spheres_and_without_triangles():
    scene = load_scene("cornell-spheres")
    tr = Tracer(scene)
    rng = np.random.default_rng(SEED + 4)
    o, d = _random_rays(3000, rng)
    tmax = rng.random(3000) * 600.0
    np.testing.assert_array_equal(tr.occluded(o, d, tmax), tr.intersect(o, d, tmax).prim >= 0)
    furnace = Tracer(load_scene("furnace"))
    inside = furnace.occluded(np.zeros((2, 3)), [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]], [0.5, 2.0])
    assert inside.tolist() == [False, True]


@pytest.mark.parametrize("rows, inner, m", [(3, 4, 10), (3, 4, 70_000), (48, 4, 65_536), (6, 3, 43_691),
                                            (48, 3, 1_821), (48, 4, 1_366), (24, 4, 65_535), (96, 3, 3_000)])
def test_one_thread_product_is_the_matrix_product(rows, inner, m):
    """The tracer's block product in column chunks (OpenBLAS on one thread) gives
    exactly ``a @ b``, float32 and float64, for column counts just above a
    chunk (where a narrow last chunk would round differently)."""
    from mcvar.tracer import _BLAS_ONE_THREAD, _one_thread_product

    rng = np.random.default_rng(rows * m)
    for dtype in (np.float32, np.float64):
        a = rng.standard_normal((rows, inner)).astype(dtype)
        b = rng.standard_normal((inner, m)).astype(dtype)
        got = _one_thread_product(a, b)
        assert got.dtype == dtype and got.shape == (rows, m)
        np.testing.assert_array_equal(got, a @ b)
    assert (_BLAS_ONE_THREAD - 1) // (rows * inner) * rows * inner < _BLAS_ONE_THREAD   # one thread per chunk
