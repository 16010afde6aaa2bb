"""Path reuse (:mod:`mcvar.integrators.reuse`): exact, unbiased against Mitsuba 3, active
where it applies and off where it must be.

Unbiasedness is checked against the stored Mitsuba references of
``tests/test_mitsuba_reference.py`` (per 4 x 4 block and for the image mean,
Welch t, Sidak-corrected), with a wavefront small enough that tiles cross
refills (where a tile split between two loads was biased before
:meth:`PathReuse.aligned`), and exactly: a path's radiance is a function of
its tile's rows of ``u``, whatever the wavefront.
"""
from __future__ import annotations

import numpy as np
import pytest

from mcvar.adaptive import render_adaptive
from mcvar.integrators import lambertian, render
from mcvar.integrators.path import trace_camera_paths
from mcvar.integrators.reuse import PathReuse
from mcvar.integrators.settings import PathSettings
from mcvar.integrators.stream import stream_dim
from mcvar.scene import load_scene

from test_mitsuba_reference import RES, assert_agrees, mcvar_replicates, scene_of

SPP = 16


def _paths(seed=5, spp=SPP, res=16, depth=5):
    pixel = np.repeat(np.arange(res * res), spp)
    u = np.random.default_rng(seed).random((pixel.size, stream_dim(depth)))
    return (res, res), pixel, u, (spp, res * res)


def test_radiance_does_not_depend_on_the_wavefront(monkeypatch):
    # every number from u: a path is a function of its tile's rows, in one load or many
    scene = load_scene("cornell")
    res, pixel, u, layout = _paths()
    out = []
    for slots in (1 << 16, 512, 192):            # 192: not a multiple of a tile's 64 rows
        monkeypatch.setattr(lambertian, "WAVEFRONT_PATHS", slots)
        out.append(trace_camera_paths(scene, res, pixel, u, rng=1, max_depth=5, reuse=4)[0])
    assert np.array_equal(out[0], out[1]) and np.array_equal(out[0], out[2])
    plain = trace_camera_paths(scene, res, pixel, u, rng=1, max_depth=5)[0]
    assert not np.allclose(plain, out[0])        # reuse did something


def test_balance_weights_of_a_second_vertex_sum_to_one(monkeypatch):
    # the identity that makes the estimator unbiased: over a tile's techniques, per x2
    seen = []
    finish = PathReuse.finish
    monkeypatch.setattr(PathReuse, "finish", lambda self, tr: seen.append(list(self.pairs)) or finish(self, tr))
    scene = load_scene("cornell")
    res, pixel, u, layout = _paths()
    trace_camera_paths(scene, res, pixel, u, rng=1, max_depth=4, reuse=4)
    to = np.concatenate([q[0] for q in seen[0]])
    sub = np.concatenate([q[1] for q in seen[0]])
    frac = np.concatenate([q[2] for q in seen[0]]).astype(np.float64)
    sums = np.bincount(sub, weights=frac, minlength=pixel.size)[np.unique(sub)]
    assert np.allclose(sums, 1.0, rtol=0, atol=4 * 4 * np.finfo(np.float32).eps)
    assert np.all(to // SPP // 4 == sub // SPP // 4)          # only within a tile
    assert np.all(to % SPP == sub % SPP)                      # of one sample number
    assert (to != sub).mean() > 0.5                           # mostly other pixels' paths


@pytest.mark.parametrize("options", [dict(rr_depth=1), dict(max_depth=2), dict(kernel="general")])
def test_off_where_its_densities_are_not_the_sampled_ones(options):
    scene = load_scene("cornell")
    a = render(scene, spp=16, res=16, rng=3, sampler="sobol", reuse=4, **options).image
    b = render(scene, spp=16, res=16, rng=3, sampler="sobol", **options).image
    assert np.array_equal(a, b)


def test_render_passes_its_tiles_and_the_variance_falls():
    # the driver gives the kernel its batch layout; on the box the per-pixel variance of the
    # image at least halves once pixels are small enough for indirect light to dominate it
    # (0.39x measured here, 0.30x at 128 x 128, docs/performance.md 'Path reuse'); the mean of
    # 6,912 per-pixel variance estimates of 64 samples is within a few percent of its expectation
    scene = load_scene("cornell")
    on = render(scene, spp=64, res=48, rng=4, sampler="sobol", visible_lights="exact", reuse=4)
    off = render(scene, spp=64, res=48, rng=4, sampler="sobol", visible_lights="exact")
    assert on.variance.mean() < 0.5 * off.variance.mean()


@pytest.mark.parametrize("depth,case", [(3, "cornell-d3"), (None, "cornell")])
def test_reuse_agrees_with_mitsuba_across_refills(monkeypatch, depth, case):
    monkeypatch.setattr(lambertian, "WAVEFRONT_PATHS", 1000)      # tiles of 256 rows cross the refills
    images = mcvar_replicates("cornell", "path", 64, 16, max_depth=depth, reuse=4)
    assert_agrees(images, case, f"path reuse=4, max_depth={depth} (16 x 64 spp) on cornell")


def test_adaptive_default_agrees_with_mitsuba(monkeypatch):
    # render_adaptive's default (2 x 2 tiles of one level's pixels) against the reference
    monkeypatch.setattr(lambertian, "WAVEFRONT_PATHS", 1000)
    scene = scene_of("cornell")
    streams = np.random.default_rng(27).spawn(16)
    images = np.stack([render_adaptive(scene, spp=64, res=RES, rng=s).image for s in streams])
    assert_agrees(images, "cornell", "render_adaptive default (16 x 64 spp) on cornell")


@pytest.mark.parametrize("value,exc", [(0, ValueError), (-2, ValueError), (2.5, TypeError), ("4", TypeError),
                                       (17, ValueError), (True, TypeError)])
def test_bad_reuse_is_refused_by_name(value, exc):
    with pytest.raises(exc, match="reuse"):
        PathSettings(reuse=value)


def test_paths_not_in_pixel_runs_are_not_reused():
    # tiles need each pixel's samples together; shuffled paths are traced without reuse
    scene = load_scene("cornell")
    res, pixel, u, _ = _paths(depth=4)
    perm = np.random.default_rng(2).permutation(pixel.size)
    a = trace_camera_paths(scene, res, pixel[perm], u[perm], rng=1, max_depth=4, reuse=4)[0]
    b = trace_camera_paths(scene, res, pixel[perm], u[perm], rng=1, max_depth=4)[0]
    assert np.array_equal(a, b)


def test_weights_equal_an_independent_recomputation(monkeypatch):
    # every balance weight recomputed in float64 from the recorded vertices, visibility by
    # another accelerator's closest hits (the BVH, public Tracer.intersect) instead of the
    # render's any-hit shadow rays: equal to float32 rounding, the set of visible pairs equal
    from mcvar.tracer import Tracer
    calls = []
    connect = PathReuse.connect

    def spy(self, tr, state, at, p, fn, sgn, prim):
        n0 = len(self.pairs)
        rec = (state.idx[at].copy(), p[:, at].astype(np.float64), (fn[:, at] * sgn[at]).astype(np.float64))
        connect(self, tr, state, at, p, fn, sgn, prim)
        calls.append(rec + (self.pairs[n0:], self.first.astype(np.float64)))

    monkeypatch.setattr(PathReuse, "connect", spy)
    scene = load_scene("cornell")
    res, pixel, u, layout = _paths(spp=4, res=16)
    trace_camera_paths(scene, res, pixel, u, rng=1, max_depth=4, reuse=4)
    ref_tracer = Tracer(scene, accel="bvh")
    eps, spp, K = scene.ray_epsilon, 4, 4
    blocked_pairs = checked = 0
    for rows, x2, n2s, pairs, first in calls:
        got = {}
        for to, sub, frac in pairs:
            got.update(zip(zip(to.tolist(), sub.tolist()), frac.tolist()))
        pix = rows // spp
        mem = (pix - pix % K)[None] + np.arange(K)[:, None]
        valid = mem < 256
        mrow = np.where(valid, mem * spp + (rows % spp)[None], 0)
        x1, n1, draws = first[0:3][:, mrow], first[3:6][:, mrow], first[9][mrow] > 0
        v = x1 - x2[:, None]
        dist = np.sqrt((v * v).sum(0))
        cos1 = -(v * n1).sum(0) / dist
        cos2 = (v * n2s[:, None]).sum(0) / dist
        ok = valid & draws & (cos1 > 0) & (cos2 > 0)
        origin = (x2 + eps * n2s)[:, None] + 0 * v
        to_x1 = x1 - origin
        length = np.sqrt((to_x1 * to_x1).sum(0))
        hit = ref_tracer.intersect(origin.reshape(3, -1).T, (to_x1 / length).reshape(3, -1).T,
                                   (length - 2 * eps).ravel())
        vis = ~np.isfinite(hit.t).reshape(ok.shape) | (mrow == rows[None])
        blocked_pairs += int((ok & ~vis).sum())
        dens = np.where(ok & vis, cos1 * cos2 / (np.pi * dist ** 2), 0.0)
        frac = dens / dens.sum(0)
        for a in range(K):
            for j in np.flatnonzero(frac[a] > 0):
                key = (int(mrow[a, j]), int(rows[j]))
                assert key in got, f"pair {key} visible to the BVH, missing in the render's weights"
                assert abs(got.pop(key) - frac[a, j]) <= 1e-4 * frac[a, j] + 1e-6
                checked += 1
        assert not got, f"pairs weighted by the render but not visible to the BVH: {list(got)[:5]}"
    assert checked > 1000 and blocked_pairs > 0.01 * checked      # the occlusion was exercised
