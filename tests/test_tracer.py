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
