"""Photon mapping and SPPM: photon power bookkeeping in a closed room, the
density estimate's bias against path tracing as the radius shrinks, SPPM's
falling MSE and its bias at few iterations, bad input; and on the caustic
(issue 21): the k-d tree's pairs against the brute-force distance matrix (an
identity), the pixels that see a light through glass, SPPM's per-block bias on
``cornell-caustic`` falling as its radius shrinks.

Statistics: replicates are independent photon maps / SPPM runs (fixed
seeds). Squared bias and MSE per pixel come with the jackknife standard
error over replicates (the same estimator as mcvar.experiments), which holds
although one photon map correlates all pixels. Tolerances: Z = 5 for
'agrees'; for 'is detected' with R replicates a one-sided Student t
quantile with R - 1 degrees of freedom at alpha = 1e-3.
"""
import numpy as np
import pytest
from scipy import stats
from scipy.ndimage import binary_dilation

from mcvar.bsdf import Lambertian
from mcvar.integrators import render, trace_paths
from mcvar.integrators.photon import build_photon_map, photon_map_radiance, trace_photons, visible_points
from mcvar.integrators.sppm import sppm
from mcvar.scene import Camera, Scene, load_scene
from mcvar.tracer import Tracer

from cube_quads import unit_cube_quads  # tests/cube_quads.py

SEED = 161803398874
Z = 5.0


def _lit_cube(albedo=0.5):
    """Closed unit cube, inward normals, every surface Lambertian ``albedo``, and a
    0.2 x 0.2 area light facing down 0.01 below the ceiling (also of that albedo)."""
    quads = unit_cube_quads()
    origin, e1, e2 = np.array([0.4, 0.99, 0.4]), np.array([0.2, 0, 0]), np.array([0, 0, 0.2])
    if np.cross(e1, e2)[1] > 0:        # emit downwards
        e1, e2 = e2, e1
    quads.append(np.array([origin, origin + e1, origin + e1 + e2, origin + e2]))
    tris = np.array([t for q in quads for t in ([q[0], q[1], q[2]], [q[0], q[2], q[3]])])
    n = tris.shape[0]
    emission = np.zeros((n, 3))
    emission[-2:] = 5.0
    light = np.full(n, -1)
    light[-2:] = 0
    return Scene(name="lit-cube", triangles=tris, sphere_centers=np.zeros((0, 3)), sphere_radii=np.zeros(0),
                 prim_material=np.zeros(n, int), prim_emission=emission,
                 prim_two_sided_emission=np.zeros(n, bool), prim_light=light, prim_group=np.zeros(n, int),
                 materials=(Lambertian(albedo),), material_names=("white",), light_origin=origin[None],
                 light_edge1=e1[None], light_edge2=e2[None], light_radiance=np.full((1, 3), 5.0),
                 camera=Camera((0.5, 0.5, 0.1), (0.5, 0.5, 1.0), (0.0, 1.0, 0.0), 60.0), ray_epsilon=1e-6)


def _jackknife(x, ref, ref_var):
    """Squared bias and MSE per pixel of replicates ``x`` (R, P) against ``ref`` and
    their jackknife standard errors over replicates (mcvar.experiments' estimator)."""
    def moments(y):
        r = y.shape[0]
        s2 = y.var(axis=0, ddof=1)
        b = y.mean(axis=0) - ref
        bias2 = np.mean(b * b - s2 / r - ref_var)
        return np.array([bias2, s2.mean() + bias2])
    r = x.shape[0]
    est = moments(x)
    jack = np.array([moments(np.delete(x, i, axis=0)) for i in range(r)])
    se = np.sqrt((r - 1) / r * np.sum((jack - jack.mean(axis=0)) ** 2, axis=0))
    return est, se


def test_photon_power_in_a_closed_room_sums_to_the_geometric_series():
    rho = 0.5
    scene = _lit_cube(rho)
    phi = np.pi * 0.04 * 5.0                             # pi A Le: the light's power
    batches = list(trace_photons(scene, 1 << 15, rng=SEED, batch=1 << 10))
    direct = np.array([b.power[b.depth == 1].sum(axis=0) for b in batches]).sum(axis=0)
    # every photon's first hit is stored (closed room, nothing delta) with its full power
    np.testing.assert_allclose(direct, phi, rtol=1e-9)
    # all depths: E = phi (1 + rho + rho^2 + ...) = phi / (1 - rho), Russian roulette unbiased
    totals = np.array([b.power.sum(axis=0) for b in batches])      # iid per emission batch
    mean = totals.sum(axis=0)
    se = totals.std(axis=0, ddof=1) * np.sqrt(len(batches))
    assert np.all(np.abs(mean - phi / (1 - rho)) <= Z * se), (mean, phi / (1 - rho), se)


def test_point_light_photons_carry_its_power():
    import dataclasses

    rho = 0.5
    cube = _lit_cube(rho)
    n = cube.triangles.shape[0]
    intensity = np.array([3.0, 2.0, 1.0])
    scene = dataclasses.replace(cube, prim_emission=np.zeros((n, 3)), prim_light=np.full(n, -1),
                                light_origin=np.zeros((0, 3)), light_edge1=np.zeros((0, 3)),
                                light_edge2=np.zeros((0, 3)), light_radiance=np.zeros((0, 3)),
                                point_light_position=np.array([[0.5, 0.5, 0.5]]),
                                point_light_intensity=intensity[None])
    batches = list(trace_photons(scene, 1 << 14, rng=SEED, batch=1 << 10))
    direct = np.array([b.power[b.depth == 1].sum(axis=0) for b in batches]).sum(axis=0)
    # a closed room: every photon lands, each with 4 pi I / N
    np.testing.assert_allclose(direct, 4 * np.pi * intensity, rtol=1e-9)
    totals = np.array([b.power.sum(axis=0) for b in batches])
    se = totals.std(axis=0, ddof=1) * np.sqrt(len(batches))
    assert np.all(np.abs(totals.sum(axis=0) - 4 * np.pi * intensity / (1 - rho)) <= Z * se)


@pytest.fixture(scope="module")
def cornell_rays():
    """16 x 16 Cornell camera rays (4 per pixel) and a path-traced reference for
    exactly these rays (256 paths each), so pixel sampling cancels."""
    scene = load_scene("cornell")
    tracer = Tracer(scene)
    rng = np.random.default_rng(SEED)
    res, spp, k = 16, 4, 256
    pix = np.repeat(np.arange(res * res), spp)
    d = scene.camera.ray_directions((res, res), pix, rng.random((pix.size, 2)))
    o = np.broadcast_to(scene.camera.position, d.shape)
    rad, _ = trace_paths(scene, np.repeat(o, k, 0), np.repeat(d, k, 0), rng.random((pix.size * k, 4)),
                         rng=rng, tracer=tracer)
    rad = rad.reshape(pix.size, k, 3)
    return scene, tracer, o, d, rad.mean(1), rad.var(1, ddof=1) / k


def test_photon_map_bias_shrinks_with_radius_and_agrees_with_path(cornell_rays):
    scene, tracer, o, d, ref, ref_var = cornell_rays
    vp = visible_points(scene, tracer, o, d, rng=SEED)
    keep = vp.emitted.sum(axis=1) == 0              # rays that see the light itself: no estimate involved
    maps = [build_photon_map(scene, 1 << 15, rng=s, tracer=tracer)
            for s in np.random.default_rng(SEED).spawn(6)]
    est = {}
    for radius in (40.0, 10.0):
        x = np.array([photon_map_radiance(scene, pm, vp, radius=radius)[keep] for pm in maps])
        est[radius] = (x.reshape(len(maps), -1), *_jackknife(x.reshape(len(maps), -1), ref[keep].ravel(),
                                                             ref_var[keep].ravel()))
    big, small = est[40.0], est[10.0]
    # the squared bias (blur, corners) is detected at radius 40 and falls at radius 10
    t = stats.t.isf(1e-3, len(maps) - 1)
    assert big[1][0] > t * big[2][0], big[1:]
    diff = big[1][0] - small[1][0]
    assert diff > t * np.hypot(big[2][0], small[2][0]), (big[1:], small[1:])
    # away from corners at the small radius the image agrees with path: the mean over
    # pixels whose 4 rays hit one quad, Welch t over the replicate means
    quad = np.where(tracer.intersect(o, d).prim >= 0, tracer.intersect(o, d).prim // 2, -1).reshape(-1, 4)
    flat = binary_dilation((quad != quad[:, :1]).any(1).reshape(16, 16)).ravel()
    ok = np.repeat(~flat, 4)[keep]
    per_rep = small[0].reshape(len(maps), -1, 3)[:, ok].mean(axis=1)
    ref_mean = ref[keep][ok].mean(0)
    se = np.sqrt(per_rep.var(0, ddof=1) / len(maps) + ref_var[keep][ok].sum(0) / ok.sum() ** 2)
    assert np.all(np.abs(per_rep.mean(0) - ref_mean) <= Z * se), (per_rep.mean(0), ref_mean, se)


def test_fixed_radius_estimate_does_not_depend_on_its_chunks(cornell_rays, monkeypatch):
    import mcvar.integrators.photon as photon

    scene, tracer, o, d, _, _ = cornell_rays
    vp = visible_points(scene, tracer, o, d, rng=SEED)
    pm = build_photon_map(scene, 1 << 13, rng=SEED, tracer=tracer)
    whole = photon_map_radiance(scene, pm, vp, radius=30.0)
    monkeypatch.setattr(photon, "PAIRS_PER_CHUNK", 1000)       # hundreds of chunks
    np.testing.assert_allclose(photon_map_radiance(scene, pm, vp, radius=30.0), whole, rtol=1e-12, atol=0)


def test_k_nearest_bias_shrinks_with_k(cornell_rays):
    scene, tracer, o, d, ref, ref_var = cornell_rays
    vp = visible_points(scene, tracer, o, d, rng=SEED)
    keep = vp.emitted.sum(axis=1) == 0
    maps = [build_photon_map(scene, 1 << 14, rng=s, tracer=tracer)
            for s in np.random.default_rng(SEED + 1).spawn(6)]
    est = {}
    for k in (400, 25):
        x = np.array([photon_map_radiance(scene, pm, vp, k=k)[keep] for pm in maps]).reshape(len(maps), -1)
        est[k] = _jackknife(x, ref[keep].ravel(), ref_var[keep].ravel())
    t = stats.t.isf(1e-3, len(maps) - 1)
    (b_big, _), (se_big, _) = est[400]
    (b_small, _), (se_small, _) = est[25]
    assert b_big > t * se_big and b_big - b_small > t * np.hypot(se_big, se_small), est


def test_sppm_mse_falls_and_bias_is_detected_at_few_iterations():
    scene = load_scene("cornell")
    tracer = Tracer(scene)
    res = 16
    ref_r = render(scene, spp=2048, res=res, rng=SEED)
    # pixels that see the light (their emission is plain Monte Carlo, no photons) are left out
    g = (np.arange(8) + 0.5) / 8
    off = np.tile(np.stack(np.meshgrid(g, g), -1).reshape(-1, 2), (res * res, 1))
    d = scene.camera.ray_directions((res, res), np.repeat(np.arange(res * res), 64), off)
    h = tracer.intersect(np.broadcast_to(scene.camera.position, d.shape), d)
    lit = ((h.prim >= 0) & (scene.prim_emission[h.prim].sum(1) > 0)).reshape(-1, 64).any(1)
    keep = ~binary_dilation(lit.reshape(res, res))
    ref = ref_r.image[keep].ravel()
    ref_var = (ref_r.variance / ref_r.spp)[keep].ravel()
    R, iters = 8, (1, 2, 4, 8, 16)
    snaps = np.zeros((R, len(iters), ref.size))
    for r, stream in enumerate(np.random.default_rng(SEED).spawn(R)):
        def keep_snapshot(i, img, r=r):
            if i in iters:
                snaps[r, iters.index(i)] = img[keep].ravel()
        sppm(scene, res=res, iterations=iters[-1], photons_per_iteration=1 << 12, radius=50.0,
             rng=stream, tracer=tracer, callback=keep_snapshot)
    rows = [_jackknife(snaps[:, k], ref, ref_var) for k in range(len(iters))]
    bias2 = np.array([e[0] for e, _ in rows])
    bias2_se = np.array([s[0] for _, s in rows])
    mse = np.array([e[1] for e, _ in rows])
    t = stats.t.isf(1e-3, R - 1)
    # biased at a finite iteration count: detected at 4 iterations
    assert bias2[2] > t * bias2_se[2], (bias2, bias2_se)
    # consistent: the MSE falls with iterations, log-log slope negative by a t test
    fit = stats.linregress(np.log(iters), np.log(mse))
    assert fit.slope < 0 and fit.slope / fit.stderr < -stats.t.isf(1e-3, len(iters) - 2), (fit, mse)
    assert mse[-1] < mse[0]


def test_bad_input():
    scene = load_scene("cornell")
    with pytest.raises(ValueError, match="radius"):
        sppm(scene, res=4, iterations=1, radius=0.0)
    with pytest.raises(ValueError, match="radius"):
        sppm(scene, res=4, iterations=1, radius=-1.0)
    for alpha in (0.0, 1.0, 1.5, -0.2):
        with pytest.raises(ValueError, match="alpha"):
            sppm(scene, res=4, iterations=1, alpha=alpha)
    with pytest.raises(ValueError, match="photons"):
        sppm(scene, res=4, iterations=1, photons_per_iteration=0)
    with pytest.raises(ValueError, match="photons"):
        build_photon_map(scene, 0)
    pm = build_photon_map(scene, 64, rng=1)
    tracer = Tracer(scene)
    vp = visible_points(scene, tracer, np.array([scene.camera.position]), np.array([[0.0, 0.0, 1.0]]))
    with pytest.raises(ValueError, match="radius"):
        photon_map_radiance(scene, pm, vp, radius=0.0)
    with pytest.raises(ValueError, match="k"):
        photon_map_radiance(scene, pm, vp, k=0)
    with pytest.raises(ValueError, match="exactly one"):
        photon_map_radiance(scene, pm, vp, k=4, radius=1.0)
    with pytest.raises(ValueError, match="no area light|belong to no area light"):
        build_photon_map(load_scene("furnace"), 16)
    with pytest.raises(ValueError, match="no emitter to emit photons from"):
        build_photon_map(load_scene("quad-environment", radiance=0.0), 16)
    assert build_photon_map(load_scene("quad-environment"), 64, rng=1) is not None    # issue 26: env photons


def test_registered_methods_render_and_reject_bad_options():
    from mcvar.integrators import METHODS

    scene = load_scene("cornell")
    assert METHODS["photon"].kind == "camera" and METHODS["sppm"].kind == "chain"
    ref = render(scene, spp=64, res=8, rng=SEED)
    ref_mean = ref.image.mean(axis=(0, 1))
    ref_se = np.sqrt(ref.variance.sum(axis=(0, 1)) / ref.spp) / 64
    for name, kw in (("photon", dict(photons=1 << 15)), ("sppm", dict(photons=1 << 12))):
        a = render(scene, integrator=name, spp=8, res=8, rng=SEED, **kw)
        b = render(scene, integrator=name, spp=8, res=8, rng=SEED, **kw)
        np.testing.assert_array_equal(a.image, b.image)           # the seed fixes the image
        assert a.spp == 8 and np.all(np.isfinite(a.image))
        # the biased estimates stay within a few percent of path tracing in the image mean
        # (measured: about 1 %); 8 x 8 pixels at 8 spp: their pixel noise is the bulk of it
        se = np.sqrt(ref_se ** 2 + (a.variance.sum(axis=(0, 1)) / a.spp / 64 ** 2 if a.variance is not None
                                    else 0.0))
        assert np.all(np.abs(a.image.mean(axis=(0, 1)) - ref_mean) <= 0.05 * ref_mean + Z * se), name
    for bad, match in ((dict(integrator="photon", radius=0.0), "radius"),
                       (dict(integrator="photon", radius=-2.0), "radius"),
                       (dict(integrator="sppm", radius=0.0), "radius"),
                       (dict(integrator="sppm", alpha=0.0), "alpha"),
                       (dict(integrator="sppm", alpha=1.0), "alpha"),
                       (dict(integrator="sppm", alpha=1.5), "alpha"),
                       (dict(integrator="photon", photons=0), "photons"),
                       (dict(integrator="sppm", photons=0), "photons"),
                       (dict(integrator="photon", k=0), "k"),
                       (dict(integrator="photon", k=4, radius=2.0), "exactly one")):
        with pytest.raises(ValueError, match=match):
            render(scene, spp=1, res=4, rng=1, **bad)
    with pytest.raises(ValueError, match="max_depth"):
        render(scene, integrator="photon", spp=1, res=4, max_depth=3)


# ---------------------------------------------------------------------------
# issue 21: photons on the caustic

def test_pairs_within_are_exactly_the_pairs_of_the_distance_matrix():
    """An identity: the k-d tree's pairs (tree over the larger set, chunked by a
    count pass) are the (point, photon) pairs whose brute-force distance is
    within the point's own radius, each once, whichever set is larger and
    however small the chunks."""
    from mcvar.integrators.photon import pairs_within

    rng = np.random.default_rng(SEED)
    for n, m in ((40, 300), (300, 40), (1, 1), (25, 25)):
        x, y = rng.random((n, 3)), rng.random((m, 3))
        r = rng.uniform(0.01, 0.3, n)
        dist = np.linalg.norm(x[:, None] - y[None], axis=2)
        want = {tuple(p) for p in np.argwhere(dist <= r[:, None])}
        for max_pairs in (None, 7, 1):
            got = [tuple(p) for i, j in pairs_within(x, r, y, max_pairs=max_pairs) for p in zip(i, j)]
            assert len(got) == len(set(got)), (n, m, max_pairs)           # no pair twice
            assert set(got) == want, (n, m, max_pairs)
    assert list(pairs_within(np.zeros((0, 3)), np.zeros(0), rng.random((5, 3)))) == []
    with pytest.raises(ValueError, match="radii"):
        list(pairs_within(rng.random((4, 3)), np.ones(3), rng.random((5, 3))))
    with pytest.raises(ValueError, match="radii"):
        list(pairs_within(rng.random((4, 3)), np.array([1.0, 0.0, 1.0, 1.0]), rng.random((5, 3))))


def test_sees_emitters_flags_the_light_and_its_image_in_the_glass():
    """``cornell-caustic``: every pixel that sees the light directly (the chart's
    ``emitter_pixels``, an independent first-hit test) is flagged, and so are pixels
    whose first hit is the glass sphere (the light seen through it); nothing on the
    floor far from the sphere is."""
    from mcvar.experiments.chart import emitter_pixels
    from mcvar.integrators.photon import sees_emitters

    scene, res = load_scene("cornell-caustic"), 32
    flagged = sees_emitters(scene, res)
    direct = emitter_pixels(scene, res)
    assert direct.any() and np.all(flagged[direct])
    pix = np.arange(res * res)
    d = scene.camera.ray_directions((res, res), pix, np.full((pix.size, 2), 0.5))
    first = Tracer(scene).intersect(np.broadcast_to(scene.camera.position, d.shape), d).prim.reshape(res, res)
    sphere = first == scene.n_triangles
    assert np.any(flagged & sphere & ~binary_dilation(direct))
    assert flagged.sum() <= 0.05 * res * res
    with pytest.raises(ValueError, match="res"):
        sees_emitters(scene, 0)


def _block_bias2(x, ref, ref_var, keep, block):
    """Squared bias of the block means of replicates ``x``: the mean over blocks of
    ``d_b^2 - s_b^2 / R - v_b`` (replicate and reference noise removed), and its
    jackknife standard error over the replicates."""
    h = ref.shape[0] // block
    n = keep.reshape(h, block, h, block).sum(axis=(1, 3))
    ok = n > 0

    def blocks(a):
        return (a * keep).reshape(*a.shape[:-2], h, block, h, block).sum(axis=(-3, -1)) / np.maximum(n, 1)

    yref, vref, y = blocks(ref), blocks(ref_var) / np.maximum(n, 1), blocks(x)

    def bias2(yy):
        d = yy.mean(axis=0) - yref
        return float(np.mean((d * d - yy.var(axis=0, ddof=1) / yy.shape[0] - vref)[ok]))

    r = y.shape[0]
    jack = np.array([bias2(np.delete(y, i, axis=0)) for i in range(r)])
    return bias2(y), float(np.sqrt((r - 1) / r * np.sum((jack - jack.mean()) ** 2)))


def test_sppm_converges_per_block_on_the_caustic_as_its_radius_shrinks():
    """SPPM on ``cornell-caustic`` (16 x 16, 16384 photons per pass; 24 runs of one
    pass, 8 of 12) against a BDPT reference of 8 chunks (path tracing is heavy-tailed
    on this scene, tests/test_cornell_caustic.py; BDPT agrees with light tracing and
    with path tracing under the full-size light there), pixels that see the light
    directly or through the glass left out (``sees_emitters``). Replicates are
    independent runs (fixed seeds). Measured: squared block bias 6.2e-5 +- 3.5e-6
    after one pass, 1.9e-5 +- 2.5e-6 after 12 (t = 10.2 against 4.8). The block bias test
    (``block_bias_test``, 2 x 2 blocks, Sidak-corrected) detects the bias of the
    first pass (the caustic and the sphere's shadow blurred over the initial
    radius); the radius shrinks where photons arrive and stays where none do; and
    the blocks' squared bias (noise removed) falls from the first pass to the
    last by a one-sided t margin at 1e-3."""
    from mcvar.experiments.analysis import block_bias_test
    from mcvar.integrators.photon import sees_emitters

    scene = load_scene("cornell-caustic")
    tracer = Tracer(scene)
    # a large initial radius and alpha = 0.5 (the radius halves its area in the first pass):
    # a bias large against one pass's noise, and shrinking fast enough to measure in 12;
    # 2 x 2 blocks, as a blur over pixels 35 units wide cancels in
    # larger ones (150 units: 4 pixels)
    res, block, chunks, R, iters, r0, alpha = 16, 2, 8, 8, 12, 150.0, 0.5
    R1 = 3 * R                     # one-pass runs are cheap: more of them for the noisier end
    streams = np.random.SeedSequence(SEED).spawn(chunks + R + R1)
    refs = np.stack([render(scene, integrator="bdpt", spp=128, res=res, rng=s, progress=False).image
                     for s in streams[:chunks]]).mean(axis=3)
    ref, ref_var = refs.mean(axis=0), refs.var(axis=0, ddof=1) / chunks
    keep = ~sees_emitters(scene, res)

    def run(stream, n):
        return sppm(scene, res=res, iterations=n, photons_per_iteration=1 << 14, radius=r0, alpha=alpha,
                    rng=np.random.default_rng(stream), tracer=tracer)

    one = [run(s, 1) for s in streams[chunks + R:]]
    many = [run(s, iters) for s in streams[chunks:chunks + R]]
    for out in one + many:
        got = out.photon_count > 0
        assert np.all(out.radius[got] < r0) and np.all(out.radius[~got] == r0)
    x1 = np.stack([o.image.mean(axis=2) for o in one])
    x2 = np.stack([o.image.mean(axis=2) for o in many])
    first = block_bias_test(x1, ref, ref_var, chunks, block=block, mask=keep)
    assert first.pvalue < 1e-3, first
    (b1, s1), (b2, s2) = (_block_bias2(x, ref, ref_var, keep, block) for x in (x1, x2))
    dof = min(R, R1) - 1
    assert b1 - b2 > stats.t.isf(1e-3, dof) * np.hypot(s1, s2), (b1, s1, b2, s2, first)
    radius = [o.radius for o in many]
    assert np.median(radius) < 0.5 * r0
