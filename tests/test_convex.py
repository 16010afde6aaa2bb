"""Convex shells (mcvar.convex) in the tracer: which sets are accepted, and that
the shells' closest hits are the triangle groups' answers."""
from __future__ import annotations

import numpy as np
import pytest

from mcvar import convex
from mcvar.integrators import render
from mcvar.scene import load_scene
from mcvar.tessellate import subdivide
from mcvar.tracer import Tracer

from cube_quads import unit_cube_quads

SEED = 20261202


def _cube_triangles(drop=(), dent=None):
    """The unit cube's 12 triangles (two per quad, sharing the diagonal q0 q2), some quads left out."""
    tris = []
    for k, q in enumerate(unit_cube_quads()):
        if k in drop:
            continue
        q = q.copy()
        if dent is not None and k == 0:
            q[1] = q[1] + dent
        tris += [q[[0, 1, 2]], q[[0, 2, 3]]]
    return np.array(tris)


def test_the_cornell_room_and_blocks_are_shells_and_the_light_a_parallelogram():
    scene = load_scene("cornell")
    tr = Tracer(scene)
    assert tr.accel == "shells"
    assert [s.shape for s in tr._shells] == [(1, 7), (2, 6)]          # the room; the two blocks
    light = np.flatnonzero(scene.prim_light[:scene.n_triangles] >= 0)
    assert sorted(tr._quads[2].ravel()) == sorted(light)                # the light: one parallelogram
    assert tr._closest_blocks == []
    assert Tracer(scene, accel="groups").accel == "groups"


def test_find_shell_accepts_exact_cases_and_refuses_the_others():
    cube = _cube_triangles()
    idx = np.arange(len(cube))
    closed = convex.find_shell(cube, idx)
    assert closed is not None and closed.n_planes == 6 and np.all(closed.code[:, 0] > 0)
    open_top = _cube_triangles(drop=(5,))
    shell = convex.find_shell(open_top, np.arange(10))
    assert shell is not None and shell.n_planes == 6
    assert np.count_nonzero(shell.code[:, 0] == 0) == 1                 # the open face: a hole plane
    # two adjacent faces missing: the open edges are not one planar loop
    assert convex.find_shell(_cube_triangles(drop=(4, 1)), np.arange(8)) is None
    # a dented corner: not convex
    assert convex.find_shell(_cube_triangles(dent=np.array([0.0, 0.2, 0.2])), idx) is None
    # faces of more than two triangles (a subdivided block), and too few triangles
    fine = subdivide(load_scene("cornell"), 2)
    block = np.flatnonzero(fine.prim_group[:fine.n_triangles] == 1)
    assert convex.find_shell(fine.triangles, block) is None
    assert convex.find_shell(cube, idx[:3]) is None
    # a face with an uncovered part: one triangle of a quad removed
    assert convex.find_shell(np.delete(cube, 0, axis=0), np.arange(11)) is None


def _edge_distance(p, tri):
    """Distance of points ``p`` (n, 3) to the nearest edge of their triangles ``tri`` (n, 3, 3)."""
    best = np.full(len(p), np.inf)
    for e in range(3):
        a, b = tri[:, e], tri[:, (e + 1) % 3]
        s = np.clip(np.einsum("ij,ij->i", p - a, b - a) / np.einsum("ij,ij->i", b - a, b - a), 0, 1)
        best = np.minimum(best, np.linalg.norm(p - a - s[:, None] * (b - a), axis=1))
    return best


def _rays(scene, rng, n):
    """Rays of six kinds: from inside the room, off surfaces (both sides), camera rays,
    from far outside, aimed at the triangles' edges and corners, and grazing."""
    tri = scene.triangles
    lo, hi = tri.reshape(-1, 3).min(axis=0), tri.reshape(-1, 3).max(axis=0)
    k = n // 6
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    o_inside = lo + (hi - lo) * rng.random((k, 3))
    j = rng.integers(0, len(tri), k)
    a, b = rng.random((2, k))
    flip = a + b > 1
    a, b = np.where(flip, 1 - a, a), np.where(flip, 1 - b, b)
    p = tri[j, 0] + a[:, None] * (tri[j, 1] - tri[j, 0]) + b[:, None] * (tri[j, 2] - tri[j, 0])
    nrm = np.cross(tri[j, 1] - tri[j, 0], tri[j, 2] - tri[j, 0])
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    side = rng.choice([-1.0, 1.0], k)[:, None]
    o_surface = p + side * scene.ray_epsilon * nrm
    d_surface = dirs[k:2 * k] * np.sign(np.einsum("ij,ij->i", dirs[k:2 * k], nrm * side))[:, None]
    cam = scene.camera
    pix = rng.integers(0, 64 * 64, k)
    d_cam = cam.ray_directions((64, 64), pix, rng.random((k, 2)))
    o_cam = np.broadcast_to(cam.position, d_cam.shape)
    o_far = (lo + hi) / 2 + 3 * (hi - lo).max() * dirs[3 * k:4 * k]
    target = lo + (hi - lo) * rng.random((k, 3))
    # edges and corners: a point on an edge of a random triangle, seen from inside
    j = rng.integers(0, len(tri), k)
    e = rng.integers(0, 3, k)
    s = rng.random(k)[:, None]
    on_edge = tri[j, e] + s * (tri[j, (e + 1) % 3] - tri[j, e])
    on_edge[: k // 4] = tri[j[: k // 4], e[: k // 4]]                  # corners
    o_edge = lo + (hi - lo) * rng.random((k, 3))
    # grazing: along a triangle's plane, just off it
    j = rng.integers(0, len(tri), k)
    nrm_g = np.cross(tri[j, 1] - tri[j, 0], tri[j, 2] - tri[j, 0])
    nrm_g /= np.linalg.norm(nrm_g, axis=1)[:, None]
    d_graze = dirs[5 * k:6 * k] - np.einsum("ij,ij->i", dirs[5 * k:6 * k], nrm_g)[:, None] * nrm_g
    d_graze += 1e-3 * rng.normal(size=(k, 3))
    o_graze = tri[j].mean(axis=1) + 2 * scene.ray_epsilon * nrm_g
    origins = np.concatenate([o_inside, o_surface, o_cam, o_far, o_edge, o_graze])
    directions = np.concatenate([dirs[:k], d_surface, d_cam, target - o_far, on_edge - o_edge, d_graze])
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    return origins, directions


def _dented_cornell():
    """The Cornell box with one corner of the tall block's top pushed down: that
    block is no shell, so it stays a boxed triangle group beside the shells."""
    import dataclasses
    scene = load_scene("cornell")
    tri = scene.triangles.copy()
    top = np.flatnonzero(scene.prim_group[:scene.n_triangles] == 2)[0]
    tri[top, 1] += [0.0, -40.0, 0.0]
    return dataclasses.replace(scene, triangles=tri)


def test_a_block_that_is_no_shell_stays_a_boxed_group():
    tr = Tracer(_dented_cornell())
    assert [s.shape for s in tr._shells] == [(1, 7), (1, 6)]
    assert len(tr._boxed[0]) == 1 and tr._boxed[0][0].k == 10


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("make", [lambda: load_scene("cornell"), _dented_cornell], ids=["cornell", "dented"])
def test_shells_give_the_triangle_groups_closest_hits(dtype, make):
    """Equal but for rays through an edge or a corner, which either triangle (or
    face) may claim and the triangle test may let through; elsewhere the same
    triangle at distances equal to the float rounding of the tests. The dented
    box takes the path with a boxed group beside the shells."""
    scene = make()
    rng = np.random.default_rng(SEED)
    o, d = _rays(scene, rng, 60_000)
    tmax = np.where(rng.random(len(o)) < 0.3, rng.uniform(1.0, 800.0, len(o)), np.inf)
    shells, groups = Tracer(scene, dtype=dtype), Tracer(scene, dtype=dtype, accel="groups")
    a, b = shells.intersect(o, d, tmax), groups.intersect(o, d, tmax)
    eps = np.finfo(dtype).eps
    scale = np.abs(scene.triangles).max()
    # hit against miss: only on an edge, through the crack of a shared edge
    # (which the triangles' barycentric test may leave open and the planes do
    # not) or along the rim of the room's open front (the last face or the hole)
    for one, other in ((a, b), (b, a)):
        crack = np.flatnonzero(np.isfinite(one.t) & ~np.isfinite(other.t))
        assert crack.size < 0.01 * len(o)                               # rays aimed at edges
        p = o[crack] + one.t[crack, None] * d[crack]
        cos = np.abs(np.einsum("ij,ij->i", d[crack], shells.triangle_normal[one.prim[crack]]))
        assert np.all(_edge_distance(p, scene.triangles[one.prim[crack]])
                      <= 64 * eps * scale / np.maximum(cos, 1e-3))
    same = a.prim == b.prim
    aimed = np.zeros(len(o), dtype=bool)
    aimed[4 * (len(o) // 6):5 * (len(o) // 6)] = True                  # the rays aimed at edges and corners
    assert same[~aimed].mean() > 0.999, same[~aimed].mean()
    hit = same & np.isfinite(a.t)
    # float rounding of the plane and the triangle test: a few eps of the scene's size, over |cos|
    cos = np.abs(np.einsum("ij,ij->i", d[hit], shells.triangle_normal[a.prim[hit]]))
    bound = 64 * eps * scale / np.maximum(cos, 1e-3)
    assert np.all(np.abs(a.t[hit] - b.t[hit]) <= bound)
    # where the triangles differ (rays aimed at edges only): the nearer answer is
    # on an edge of one of the two triangles (the farther one went through the
    # edge's crack, or took the neighbouring face)
    diff = np.flatnonzero(~same & np.isfinite(a.t) & np.isfinite(b.t))
    assert np.all(aimed[diff])
    near = np.where((a.t <= b.t)[diff], a.prim[diff], b.prim[diff])
    t_near = np.minimum(a.t, b.t)[diff]
    p = o[diff] + t_near[:, None] * d[diff]
    cos = np.abs(np.einsum("ij,ij->i", d[diff], shells.triangle_normal[near]))
    # (a tie on a block's foot, the floor's interior: on the edge of the other triangle)
    on_edge = np.minimum(_edge_distance(p, scene.triangles[a.prim[diff]]),
                         _edge_distance(p, scene.triangles[b.prim[diff]]))
    ratio = on_edge / (64 * eps * scale / np.maximum(cos, 1e-3))
    assert np.all(ratio <= 1), np.sort(ratio)[-4:]


def test_shells_on_a_closed_cube_and_an_open_box_match_brute_force():
    """The shells' own cases (a closed shell seen from inside and outside, a
    hole), on rays from everywhere, against the triangle groups."""
    rng = np.random.default_rng(SEED + 1)
    for tris in (_cube_triangles(), _cube_triangles(drop=(5,))):
        shell = convex.find_shell(tris, np.arange(len(tris)), dtype=np.float64)
        o = rng.uniform(-1.0, 2.0, (20_000, 3))
        d = rng.normal(size=(20_000, 3))
        d /= np.linalg.norm(d, axis=1)[:, None]
        o4 = np.concatenate([o.T, np.ones((1, len(o)))])
        stack = convex.ShellStack.of([shell])
        t, code = convex.shell_hits(stack, o4, d.T, 1e-6)
        # brute force: every triangle's hit by Moller-Trumbore in float64
        best = np.full(len(o), np.inf)
        for v0, v1, v2 in tris:
            e1, e2 = v1 - v0, v2 - v0
            pv = np.cross(d, e2)
            det = pv @ e1
            with np.errstate(divide="ignore", invalid="ignore"):
                inv = 1.0 / det
                tv = o - v0
                u = np.einsum("ij,ij->i", tv, pv) * inv
                qv = np.cross(tv, e1)
                v = np.einsum("ij,ij->i", d, qv) * inv
                tt = (qv @ e2) * inv
            ok = (u >= 0) & (v >= 0) & (u + v <= 1) & (tt > 1e-6) & (np.abs(det) > 0)
            best = np.where(ok & (tt < best), tt, best)
        finite = np.isfinite(best)
        assert np.mean(np.isfinite(t) != finite) < 1e-3                   # rays through an edge of the hole
        both = finite & np.isfinite(t)
        np.testing.assert_allclose(t[both], best[both], rtol=1e-9, atol=1e-9)
        assert np.all(code[both] > 0) and np.all(code[~np.isfinite(t)] == 0)


def test_the_image_is_the_triangle_groups_image():
    """Unbiased: the Cornell box rendered with shells and with triangle groups
    (independent seeds, random sampler, one worker), per-channel image means
    within 5 standard errors (Sidak over 3 channels asks for 2.9)."""
    import mcvar.tracer as T
    scene = load_scene("cornell")
    kw = dict(method="path", spp=32, res=16, sampler="random")
    orig = T.Tracer.__init__
    images = {}
    for accel, seed in (("shells", 1), ("groups", 2)):
        def init(self, sc, _accel=accel, **o):
            o.setdefault("accel", _accel)
            orig(self, sc, **o)
        T.Tracer.__init__ = init
        try:
            images[accel] = render(scene, rng=np.random.default_rng(SEED + seed), **kw)
        finally:
            T.Tracer.__init__ = orig
    a, b = images["shells"], images["groups"]
    n = 16 * 16
    se = np.sqrt((a.variance / a.spp).sum(axis=(0, 1)) + (b.variance / b.spp).sum(axis=(0, 1))) / n
    z = (a.image.mean(axis=(0, 1)) - b.image.mean(axis=(0, 1))) / se
    assert np.all(np.abs(z) < 5), z
