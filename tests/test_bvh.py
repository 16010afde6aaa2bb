"""The BVH (mcvar.bvh): its structure, and closest / any-hit answers equal to
brute force on random rays and scenes; the subdivided Cornell box renders the
coarse box's image; memory grows linearly with the triangle count."""
import numpy as np
import pytest

from mcvar import bvh as B
from mcvar.integrators import render
from mcvar.scene import load_scene
from mcvar.tessellate import subdivide, subdivide_triangle
from mcvar.tracer import BVH_MIN_TRIANGLES, Tracer

SEED = 20261201


def _room_rays(n, rng):
    o = rng.random((n, 3)) * [540.0, 530.0, 540.0] + [8.0, 8.0, 8.0]
    d = rng.normal(size=(n, 3))
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def _soup(n, rng):
    """Random small triangles in a unit cube, plus a stack of coincident ones
    (equal centroids: the build's fallback split)."""
    c = rng.random((n, 1, 3))
    tri = c + 0.05 * rng.normal(size=(n, 3, 3))
    same = np.repeat(tri[:1], 40, axis=0) + 1e-9 * rng.random((40, 3, 3))
    return np.concatenate([tri, same])


def test_structure_every_triangle_once_and_boxes_nest():
    rng = np.random.default_rng(SEED)
    tri = _soup(3000, rng)
    b = B.build_bvh(tri, leaf_size=4)
    leaf = b.child < 0
    # every triangle in exactly one leaf
    owned = np.concatenate([b.order[s:s + c] for s, c in zip(b.start[leaf], b.count[leaf])])
    np.testing.assert_array_equal(np.sort(owned), np.arange(tri.shape[0]))
    # leaves are small unless their triangles could not be separated at all
    assert np.all(b.count[leaf] <= 4) or b.depth == 60
    # a node's box holds its triangles, and its children's boxes
    for i in range(b.n_nodes):
        ids = b.order[b.start[i]:b.start[i] + b.count[i]]
        assert np.all(tri[ids].min(axis=(0, 1)) >= b.lo[i]) and np.all(tri[ids].max(axis=(0, 1)) <= b.hi[i])
    inner = np.flatnonzero(~leaf)
    for c in (b.child[inner], b.child[inner] + 1):
        assert np.all(b.lo[c] >= b.lo[inner]) and np.all(b.hi[c] <= b.hi[inner])
        # children split the parent's run
    np.testing.assert_array_equal(b.count[b.child[inner]] + b.count[b.child[inner] + 1], b.count[inner])
    np.testing.assert_array_equal(b.start[b.child[inner]], b.start[inner])


@pytest.mark.parametrize("k", [1, 3, 8])
def test_closest_hits_equal_brute_force_in_the_subdivided_room(k):
    rng = np.random.default_rng(SEED + k)
    scene = subdivide(load_scene("cornell-spheres"), k)
    o, d = _room_rays(4000, rng)
    tmax = np.where(rng.random(4000) < 0.3, rng.random(4000) * 300.0, np.inf)
    for dtype in ("float32", "float64"):
        ref = Tracer(scene, dtype="float64", accel="groups").intersect(o, d, tmax)
        hit = Tracer(scene, dtype=dtype, accel="bvh").intersect(o, d, tmax)
        np.testing.assert_array_equal(hit.prim >= 0, ref.prim >= 0)
        h = hit.prim >= 0
        # the documented float32 tolerance of the triangle test (tests/test_tracer.py)
        np.testing.assert_allclose(hit.t[h], ref.t[h], rtol=2e-4 if dtype == "float32" else 1e-9)
        same = hit.prim == ref.prim
        # a different primitive only where two are hit at the same distance (shared edges)
        assert np.mean(same) > 0.995
        if dtype == "float64":
            np.testing.assert_allclose(hit.t[~same & h], ref.t[~same & h], rtol=1e-9)


def _oracle(tri, o, d, eps):
    """Moller-Trumbore in float64, every ray against every triangle: (t, prim) of the closest."""
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(d[:, None], e2[None])
    det = np.einsum("ntk,tk->nt", p, e1)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = o[:, None] - v0[None]
        b1 = np.einsum("ntk,ntk->nt", s, p) / det
        q = np.cross(s, e1[None])
        b2 = np.einsum("nk,ntk->nt", d, q) / det
        tt = np.einsum("ntk,tk->nt", q, e2) / det
    ok = (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1) & (tt > eps) & np.isfinite(tt)
    tt = np.where(ok, tt, np.inf)
    t = tt.min(axis=1)
    return t, np.where(np.isfinite(t), tt.argmin(axis=1), -1)


def _cube_rays(n, rng):
    o = rng.random((n, 3)) * 1.4 - 0.2
    d = rng.normal(size=(n, 3))
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("width", [2, 4, 8, 16])
def test_closest_and_any_hit_equal_the_oracle_on_random_soups(width):
    """Every width of the wide tree, float64: the closest hit's distance
    equals brute force to rounding, and the any-hit answer is the closest
    hit's ``t < tmax`` exactly."""
    rng = np.random.default_rng(SEED + 10 + width)
    tri = _soup(3000, rng)
    n = 3000
    o, d = _cube_rays(n, rng)
    b = B.build_bvh(tri, dtype="float64", width=width, leaf_size=width)
    t, prim = B.closest(b, o.T, d.T, np.full(n, np.inf), 1e-6)
    assert 0.1 < np.mean(prim >= 0) < 0.9
    t_or, p_or = _oracle(tri, o, d, 1e-6)
    np.testing.assert_allclose(t, t_or, rtol=1e-9)
    assert np.mean(prim == p_or) > 0.999           # ties: a shared edge or the coincident stack
    tmax = rng.random(n) * 1.5
    occ = B.occluded(b, o.T, d.T, tmax, 1e-6)
    np.testing.assert_array_equal(occ, t < tmax)
    # float32: the documented tolerance of the triangle test (mcvar.bvh: 2e-4 relative,
    # and an absolute 1e-6 of the scene's size for hits just beyond the epsilon)
    b32 = B.build_bvh(tri, width=width, leaf_size=width)
    t32, p32 = B.closest(b32, o.T, d.T, np.full(n, np.inf), 1e-6)
    h = np.isfinite(t_or)
    assert np.mean(np.isfinite(t32) == h) > 0.999   # rays grazing an edge may differ in float32
    both = h & np.isfinite(t32)
    np.testing.assert_allclose(t32[both], t_or[both], rtol=2e-4, atol=1e-6 * 1.4)


def test_single_triangle_degenerate_triangles_and_empty_input():
    rng = np.random.default_rng(SEED + 20)
    one = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    b = B.build_bvh(one, dtype="float64")
    o = np.array([[0.25, 0.25, 1.0], [0.75, 0.75, 1.0], [0.25, 0.25, -1.0], [0.1, 0.1, 1.0]])
    d = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    t, prim = B.closest(b, o.T, d.T, np.full(4, np.inf), 1e-6)
    np.testing.assert_array_equal(prim, [0, -1, 0, -1])
    np.testing.assert_array_equal(t, [1.0, np.inf, 1.0, np.inf])          # exact: axis-aligned
    np.testing.assert_array_equal(B.occluded(b, o.T, d.T, np.array([1.5, 9, 0.5, 9]), 1e-6),
                                  [True, False, False, False])
    # zero-area triangles (a repeated vertex, collinear vertices) are kept in the tree and never hit
    soup = _soup(500, rng)
    bad = np.concatenate([np.repeat(soup[:50, :1], 3, axis=1),
                          soup[50:100, :1] + np.array([0.0, 0.5, 1.0])[None, :, None] * (soup[50:100, 1:2]
                                                                                         - soup[50:100, :1])])
    mixed = np.concatenate([soup, bad])
    n = 2000
    o, d = _cube_rays(n, rng)
    t, prim = B.closest(B.build_bvh(mixed, dtype="float64"), o.T, d.T, np.full(n, np.inf), 1e-6)
    t_or, _ = _oracle(soup, o, d, 1e-6)
    np.testing.assert_allclose(t, t_or, rtol=1e-9)
    assert np.all(prim < soup.shape[0])
    # no rays: empty answers
    t0, p0 = B.closest(b, np.zeros((3, 0)), np.zeros((3, 0)), np.zeros(0), 1e-6)
    assert t0.shape == p0.shape == (0,)
    assert B.occluded(b, np.zeros((3, 0)), np.zeros((3, 0)), np.zeros(0), 1e-6).shape == (0,)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_rays_leaving_surfaces_equal_brute_force(dtype):
    """Rays from points on the subdivided room's triangles, offset by
    +-ray_epsilon along the normal or not at all (the self-intersection
    epsilon must reject the start triangle and its neighbours, never a
    surface farther than it), closest and shadow rays against brute force."""
    rng = np.random.default_rng(SEED + 30)
    scene = subdivide(load_scene("cornell"), 4)
    ref = Tracer(scene, dtype="float64", accel="groups")
    tr = Tracer(scene, dtype=dtype, accel="bvh")
    n = 4000
    src = rng.integers(0, scene.n_triangles, n)
    tri = scene.triangles[src]
    u = rng.random((n, 2))
    flip = u.sum(axis=1) > 1
    u[flip] = 1 - u[flip]
    p = tri[:, 0] + u[:, :1] * (tri[:, 1] - tri[:, 0]) + u[:, 1:] * (tri[:, 2] - tri[:, 0])
    nrm = ref.triangle_normal[src]
    side = rng.integers(-1, 2, n)[:, None]
    o = p + side * scene.ray_epsilon * nrm
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    a, b = ref.intersect(o, d), tr.intersect(o, d)
    same = (a.prim >= 0) == (b.prim >= 0)
    assert np.mean(same) > (0.999 if dtype == "float32" else 1.0 - 1e-12)
    h = (a.prim >= 0) & (b.prim >= 0)
    if dtype == "float64":
        np.testing.assert_allclose(b.t[h], a.t[h], rtol=1e-9)
    else:
        # float32 geometry: rounding the origin moves it by up to an ulp of the
        # scene's size off the plane, which a ray at angle theta to the hit
        # surface turns into |dt| = ulp / |cos theta| (measured: 1.2 ulp at most)
        cos = np.abs(np.einsum("ij,ij->i", d[h], ref.triangle_normal[a.prim[h]]))
        bound = 2e-4 * a.t[h] + 4 * np.spacing(np.float32(556.0)) / cos
        assert np.all(np.abs(b.t[h] - a.t[h]) <= bound)
    # shadow rays from the same points to random points of the room
    q = rng.random((n, 3)) * [540.0, 530.0, 540.0] + [8.0, 8.0, 8.0]
    dist = np.linalg.norm(q - o, axis=1)
    ds = (q - o) / dist[:, None]
    occ_a = ref.occluded(o, ds, dist - scene.ray_epsilon)
    occ_b = tr.occluded(o, ds, dist - scene.ray_epsilon)
    assert np.mean(occ_a == occ_b) > (0.999 if dtype == "float32" else 1.0 - 1e-12)


def test_auto_chooses_the_bvh_above_the_threshold_only():
    coarse = load_scene("cornell")
    assert coarse.n_triangles <= BVH_MIN_TRIANGLES
    seen = set()
    for k in range(1, 9):                                            # 32 to 1,922 triangles
        scene = subdivide(coarse, k)
        # the coarse box's room and blocks are convex shells (mcvar.convex); subdivided
        # faces hold more than two triangles, so brute force over groups below the BVH
        want = "bvh" if scene.n_triangles > BVH_MIN_TRIANGLES else "shells" if k == 1 else "groups"
        assert Tracer(scene).accel == want, (scene.n_triangles, BVH_MIN_TRIANGLES)
        seen.add(want)
    assert seen == {"bvh", "groups", "shells"}
    assert Tracer(coarse, accel="bvh").accel == "bvh"
    with pytest.raises(ValueError, match="accel"):
        Tracer(coarse, accel="octree")


def test_subdivision_keeps_the_surface():
    rng = np.random.default_rng(SEED + 3)
    tri = rng.normal(size=(3, 3))
    pieces = subdivide_triangle(tri, 5)
    assert pieces.shape == (25, 3, 3)
    n0 = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    n = np.cross(pieces[:, 1] - pieces[:, 0], pieces[:, 2] - pieces[:, 0])
    np.testing.assert_allclose(n.sum(axis=0), n0, rtol=1e-12)          # areas and orientation add up
    np.testing.assert_allclose(n, np.broadcast_to(n0 / 25, n.shape), rtol=1e-9, atol=1e-12)
    scene = load_scene("cornell")
    fine = subdivide(scene, 3)
    emit = np.any(scene.prim_emission[:scene.n_triangles] > 0, axis=1)
    assert fine.n_triangles == int(emit.sum() + 9 * (~emit).sum())


def test_bvh_renders_brute_force_image_and_subdivision_the_coarse_one(monkeypatch):
    """Unbiased: the subdivided box (482 triangles) rendered with the BVH and
    with brute force over groups, and the coarse box, with independent
    seeds; per-channel image means within 5 standard errors of each other
    (Sidak over 2 comparisons x 3 channels asks for only 3.4)."""
    import mcvar.tracer as T
    coarse = load_scene("cornell")
    fine = subdivide(coarse, 4)
    kw = dict(integrator="path", spp=32, res=16, sampler="random")
    runs = {}
    for name, scene, threshold, seed in (("coarse", coarse, 10 ** 9, 0), ("groups", fine, 10 ** 9, 1),
                                         ("bvh", fine, 0, 2)):
        monkeypatch.setattr(T, "BVH_MIN_TRIANGLES", threshold)
        assert Tracer(scene).accel == ("bvh" if threshold == 0 else "shells" if name == "coarse" else "groups")
        runs[name] = render(scene, rng=np.random.default_rng(SEED + seed), **kw)
        assert np.all(np.isfinite(runs[name].image))
    n = 16 * 16
    for a, b in (("bvh", "groups"), ("groups", "coarse")):
        ra, rb = runs[a], runs[b]
        se = np.sqrt(ra.variance.sum(axis=(0, 1)) / n ** 2 + rb.variance.sum(axis=(0, 1)) / n ** 2)
        z = (ra.image.mean(axis=(0, 1)) - rb.image.mean(axis=(0, 1))) / se
        assert np.all(np.abs(z) < 5), (a, b, z)


def test_memory_grows_linearly_and_100k_triangles_build():
    import tracemalloc
    scene = subdivide(load_scene("cornell"), 56)       # 94 082 triangles
    tracemalloc.start()
    tr = Tracer(scene)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert tr.accel == "bvh"
    # the old shadow table needed one byte per (key, triangle): 3 T^2 = 26 GB here;
    # the documented budgets: a build peak under 2 KB and a tree under 256 bytes a triangle
    assert peak < 2048 * scene.n_triangles, peak
    assert tr._bvh.nbytes < 256 * scene.n_triangles, tr._bvh.nbytes
    # linear: bytes per triangle of a 16x smaller scene within 25% of this one's
    small = Tracer(subdivide(load_scene("cornell"), 14))._bvh
    per_small = small.nbytes / subdivide(load_scene("cornell"), 14).n_triangles
    assert abs(per_small / (tr._bvh.nbytes / scene.n_triangles) - 1) < 0.25
    rng = np.random.default_rng(SEED + 4)
    o, d = _room_rays(2000, rng)
    ref = Tracer(subdivide(load_scene("cornell"), 1), dtype="float64").intersect(o, d)
    hit = tr.intersect(o, d)
    np.testing.assert_allclose(hit.t, ref.t, rtol=2e-4)


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="triangles"):
        B.build_bvh(np.zeros((4, 3)))
    with pytest.raises(ValueError, match="leaf_size"):
        B.build_bvh(np.random.default_rng(0).random((8, 3, 3)), leaf_size=0)
    with pytest.raises(ValueError, match="triangles"):
        B.build_bvh(np.zeros((0, 3, 3)))
    tri = np.random.default_rng(0).random((8, 3, 3))
    with pytest.raises(ValueError, match="finite"):
        B.build_bvh(np.where(np.arange(72).reshape(8, 3, 3) == 5, np.nan, tri))
    with pytest.raises(ValueError, match="width"):
        B.build_bvh(tri, width=3)
    with pytest.raises(ValueError, match="leaf_size"):
        B.build_bvh(tri, width=4, leaf_size=8)
    with pytest.raises(ValueError, match="dtype"):
        B.build_bvh(tri, dtype="float16")
    with pytest.raises(ValueError, match=r"\(3, n\)"):
        B.closest(B.build_bvh(tri), np.zeros((5, 3)), np.zeros((5, 3)), np.inf, 1e-6)
    with pytest.raises(ValueError, match=r"tmax must be a scalar or of shape \(3,\)"):
        B.occluded(B.build_bvh(tri), np.zeros((3, 3)), np.ones((3, 3)), np.ones(2), 1e-6)
    with pytest.raises(ValueError, match="k"):
        subdivide(load_scene("cornell"), 0)


def _mixed_nodes(b, plane):
    """Binary nodes whose triangles lie in more than one plane, and leaves among them."""
    lab = plane[b.order]
    lo = np.array([lab[s:s + c].min() for s, c in zip(b.start, b.count)])
    hi = np.array([lab[s:s + c].max() for s, c in zip(b.start, b.count)])
    mixed = lo != hi
    return int(mixed.sum()), int((mixed & (b.child < 0)).sum())


def test_planes_are_kept_whole_near_the_top():
    """The build bins the planes' centroids while a node holds several planes
    (the subdivided box: 17 planes of 2 to 6,272 triangles), so the tree's top
    is a tree over the planes, and below it every node is flat: of the ~70,000
    nodes at most a few dozen mix planes (an object split mixes thousands)."""
    scene = subdivide(load_scene("cornell"), 16)               # 7,682 triangles
    tri = scene.triangles[:scene.n_triangles]
    plane, cent = B._planes(np.asarray(tri, float), tri.min(axis=1), tri.max(axis=1))
    assert plane.shape == (tri.shape[0],) and cent.shape == (17, 3)
    # coplanar: every plane's triangles have one normal
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    for p in range(17):
        n = nrm[plane == p]
        assert np.allclose(np.abs(n @ n[0]), 1.0, atol=1e-9)
    b = B.build_bvh(tri)
    mixed, mixed_leaves = _mixed_nodes(b, plane)
    # a binary tree over 17 planes has 16 inner nodes; a plane pair with one
    # centroid (the two halves of a non-planar quad) may add a few more
    assert mixed <= 4 * 17, mixed
    assert mixed_leaves <= 4, mixed_leaves


def test_a_bvh_tracer_keeps_no_brute_force_maps():
    # the per-triangle maps serve only the groups' blocks; a BVH tracer crosses to worker
    # processes inside every batch, so it carries only what its traversal reads
    scene = subdivide(load_scene("cornell"), 8)
    bvh, groups = Tracer(scene, accel="bvh"), Tracer(scene, accel="groups")
    for name in ("_inv", "_inv_o", "_offset"):
        assert not hasattr(bvh, name) and hasattr(groups, name)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_shadow_keys_skip_plane_classes_and_answer_as_brute_force(dtype):
    """Next-event shadow rays with their keys (from either side of random points of
    the subdivided box, edges and corners included, to the light): the BVH skips the
    plane classes that cannot lie between origin and light, and answers as without
    keys and as its own closest-hit query; in float64 as brute force over groups. The
    keys do skip: a floor point lit from above skips the walls, the floor and the
    ceiling but keeps every block face; a ray without a key skips nothing."""
    from test_tracer import _shadow_rays

    rng = np.random.default_rng(SEED + 40)
    scene = subdivide(load_scene("cornell"), 8)                   # 1,922 triangles
    tr = Tracer(scene, dtype=dtype, accel="bvh")
    o, w, tmax, keys = _shadow_rays(scene, tr, 20000, rng)
    closest = tr.intersect(o, w, tmax).prim >= 0
    assert 0.05 < closest.mean() < 0.95
    np.testing.assert_array_equal(tr.occluded(o, w, tmax, keys=keys), closest)
    np.testing.assert_array_equal(tr.occluded(o, w, tmax), closest)
    if dtype == "float64":
        brute = Tracer(scene, dtype="float64", accel="groups")
        np.testing.assert_array_equal(tr.occluded(o, w, tmax, keys=keys), brute.occluded(o, w, tmax))
    # what the keys skip: classes as bits of the BVH's uint64 masks
    cls = tr._bvh.tri_class
    group = scene.prim_group[:scene.n_triangles]
    light = scene.prim_light[:scene.n_triangles] >= 0
    floor = int(np.flatnonzero((np.abs(scene.triangles[:, :, 1]).max(axis=1) < 1e-9) & ~light)[0])
    key = tr.shadow_keys(np.array([floor]), np.array([1]))[0]
    keep = int(tr._shadow_keep[key])
    kept = {c for c in range(B.CLASSES) if keep >> c & 1}
    assert set(cls[group > 0]) <= kept                                       # block faces may occlude
    assert not set(cls[(group == 0) & ~light]) & kept, kept                  # no wall, floor or ceiling
    assert int(tr._shadow_keep[tr.shadow_keys(np.array([floor]), np.array([1]), np.array([-1]))[0]]) == 2 ** 64 - 1
    # every class of more than one triangle is one plane; the rest share the last class
    assert cls.max() < B.CLASSES and len(set(cls)) == 17


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_a_rays_answer_depends_on_that_ray_alone(dtype):
    """The wavefront prunes a ray's (ray, node) pairs by that ray's own closest hit
    so far, and a ray's pairs keep the tree's order whatever rays share its chunk:
    so a ray's closest hit (distance and triangle, ties included) and its shadow
    answer are the same bit for bit for every chunk length (one ray a chunk: no
    other ray at all) and any order of the rays. The rays leave the subdivided
    box's surfaces (many shared edges, so ties are met), a third with a finite tmax."""
    from test_tracer import _shadow_rays

    rng = np.random.default_rng(SEED + 50)
    scene = subdivide(load_scene("cornell"), 8)                   # 1,922 triangles
    tr = Tracer(scene, dtype=dtype, accel="bvh")
    b, eps, n = tr._bvh, tr.epsilon, 3000
    src = rng.integers(0, scene.n_triangles, n)
    u = rng.random((n, 2))
    u = np.where(u.sum(axis=1, keepdims=True) > 1, 1 - u, u)
    tri = scene.triangles[src]
    o = tri[:, 0] + u[:, :1] * (tri[:, 1] - tri[:, 0]) + u[:, 1:] * (tri[:, 2] - tri[:, 0])
    o += scene.ray_epsilon * tr.triangle_normal[src] * rng.integers(-1, 2, (n, 1))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    tmax = np.where(rng.random(n) < 1 / 3, rng.random(n) * 400.0, np.inf)
    t_ref, p_ref = B.closest(b, o.T, d.T, tmax, eps)
    assert 0.5 < np.mean(p_ref >= 0) < 1.0
    perm = rng.permutation(n)
    for chunk in (1, 37, 1000):
        t, p = B.closest(b, o.T, d.T, tmax, eps, chunk=chunk)
        np.testing.assert_array_equal(t, t_ref)
        np.testing.assert_array_equal(p, p_ref)
    t, p = B.closest(b, o[perm].T, d[perm].T, tmax[perm], eps)
    np.testing.assert_array_equal(t, t_ref[perm])
    np.testing.assert_array_equal(p, p_ref[perm])
    # shadow rays with their plane-class keys
    so, sw, stmax, keys = _shadow_rays(scene, tr, 4000, rng)
    keep = np.take(tr._shadow_keep, keys)
    occ_ref = B.occluded(b, so.T, sw.T, stmax, eps, keep=keep)
    assert 0.05 < occ_ref.mean() < 0.95
    for chunk in (1, 37, 1000):
        np.testing.assert_array_equal(B.occluded(b, so.T, sw.T, stmax, eps, chunk=chunk, keep=keep), occ_ref)
    perm = rng.permutation(so.shape[0])
    np.testing.assert_array_equal(B.occluded(b, so[perm].T, sw[perm].T, stmax[perm], eps, keep=keep[perm]),
                                  occ_ref[perm])
