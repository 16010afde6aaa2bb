"""Integrators: analytic scenes (furnace, quad under a constant sky), the
estimators' agreement in expectation, the lecture's spp / depth comparisons,
determinism, processes, interruption and bad input.

Tolerances: Z = 5 standard errors (two-sided alpha = 5.7e-7 for a normal
mean); for means over R replicates, Student's t with R - 1 degrees of
freedom at 5 gives alpha = 1.6e-4 for R = 16. Standard errors of pixel
means come from the render's own per-sample variance (iid 'random' sampler:
pixels are independent, so an image mean's variance is the sum of the pixel
variances over n_pixels^2).
"""
import dataclasses
import numpy as np
import pytest

from mcvar.integrators import INTEGRATORS, render, trace_paths
from mcvar.scene import load_scene

Z = 5.0
SEED = 271828182845


def _mean_and_se(r):
    """Image mean per channel and its standard error from the per-pixel variances."""
    n_pix = r.image.shape[0] * r.image.shape[1]
    mean = r.image.mean(axis=(0, 1))
    se = np.sqrt(r.variance.sum(axis=(0, 1)) / r.spp) / n_pix
    return mean, se


def _replicates(scene, integrator, R, seed, **kw):
    """Image means of R independent renders: (R, 3)."""
    streams = np.random.default_rng(seed).spawn(R)
    return np.array([render(scene, integrator=integrator, rng=s, **kw).image.mean(axis=(0, 1))
                     for s in streams])


@pytest.fixture(scope="module")
def cornell():
    return load_scene("cornell")


# -- analytic scenes -------------------------------------------------------

RHO = np.array([0.3, 0.5, 0.8])


@pytest.mark.parametrize("integrator", ["path", "path_bsdf"])
def test_furnace_with_russian_roulette_converges_to_le_over_one_minus_rho(integrator):
    scene = load_scene("furnace", albedo=RHO, emission=1.5)
    r = render(scene, integrator=integrator, spp=64, res=8, rng=SEED)
    mean, se = _mean_and_se(r)
    expected = 1.5 / (1.0 - RHO)
    assert np.all(np.abs(mean - expected) < Z * se), (mean, expected, se)


@pytest.mark.parametrize("depth", [1, 2, 3, 7])
def test_furnace_fixed_depth_is_the_truncated_geometric_sum_exactly(depth):
    # Cosine sampling of a Lambertian BSDF has weight rho exactly and Le is the
    # same everywhere, so with a fixed depth every sample is Le sum_{k<d} rho^k:
    # zero variance, an exact check.
    scene = load_scene("furnace", albedo=RHO, emission=2.0)
    r = render(scene, integrator="path", spp=4, res=4, rng=SEED, max_depth=depth)
    expected = 2.0 * (1.0 - RHO ** depth) / (1.0 - RHO)
    np.testing.assert_allclose(r.image, np.broadcast_to(expected, r.image.shape), rtol=1e-12)


def test_quad_under_constant_environment_reflects_rho_times_l():
    pytest.importorskip("mcvar.envmap")
    rho, sky = np.array([0.2, 0.5, 0.9]), np.array([1.0, 2.0, 0.5])
    scene = load_scene("quad-environment", albedo=rho, radiance=sky)
    # BSDF sampling of a Lambertian quad under a constant sky: weight rho, radiance L: exact
    r = render(scene, integrator="direct_bsdf", spp=4, res=4, rng=SEED)
    np.testing.assert_allclose(r.image, np.broadcast_to(rho * sky, r.image.shape), rtol=1e-12)
    for integrator in ("direct", "direct_light", "path"):
        r = render(scene, integrator=integrator, spp=64, res=8, rng=SEED)
        mean, se = _mean_and_se(r)
        assert np.all(np.abs(mean - rho * sky) <= Z * se + 1e-12), (integrator, mean, se)


def test_every_integrator_shows_the_light_at_its_radiance(cornell):
    # pixel (row 9, column 32) of a 64 x 64 image lies wholly on the light quad
    # (rows 8..10, columns 27..37 by the camera formula): emission seen directly,
    # the same for every light-transport integrator and for 'raster'.
    for integrator in ("path", "path_bsdf", "direct", "direct_light", "direct_bsdf", "raster"):
        r = render(cornell, integrator=integrator, spp=2, res=64, rng=SEED)
        np.testing.assert_allclose(r.image[9, 32], [17.0, 12.0, 4.0], rtol=1e-12, err_msg=integrator)


def test_checkerboard_is_the_same_image_plane_integral_for_every_integrator():
    scene = load_scene("checkerboard")
    a = render(scene, integrator="path", spp=4, res=16, rng=SEED).image
    b = render(scene, integrator="raster", spp=4, res=16, rng=SEED).image
    np.testing.assert_array_equal(a, b)           # same pixel positions, emission only
    assert a.min() >= 0.0 and a.max() <= 1.0
    assert 0.2 < a[8:].mean() < 0.8               # the ground half shows both colours


def test_aovs_on_the_red_wall(cornell):
    # pixel (8, 1) of a 16 x 16 image sees only the red wall (column 0 also sees
    # past the open front: at z = 0 it spans x = 528 ... 564 > 556)
    alb = render(cornell, integrator="albedo", spp=4, res=16, rng=SEED).image
    np.testing.assert_allclose(alb[8, 1], [0.63, 0.065, 0.05], rtol=1e-12)
    nrm = render(cornell, integrator="normal", spp=4, res=16, rng=SEED).image
    assert nrm[8, 1] @ [-1.0, 0.0, 0.0] > 0.999   # facing the inside of the room
    dep = render(cornell, integrator="depth", spp=4, res=16, rng=SEED).image
    # the wall lies beyond the open front z = 0, more than 800 from the camera;
    # rays that leave the room read 0
    assert dep[8, 1, 0] > 800.0 and np.all(dep >= 0.0)


# -- estimators agree in expectation; MIS is no worse ------------------------

def test_direct_strategies_agree_and_mis_variance_is_no_worse(cornell):
    R = 16
    kw = dict(spp=8, res=8)
    means = {k: _replicates(cornell, k, R, SEED + i, **kw)
             for i, k in enumerate(("direct", "direct_light", "direct_bsdf"))}
    m = {k: v.mean(axis=0) for k, v in means.items()}
    se = {k: v.std(axis=0, ddof=1) / np.sqrt(R) for k, v in means.items()}
    for other in ("direct_light", "direct_bsdf"):
        diff = np.abs(m["direct"] - m[other])
        assert np.all(diff < Z * np.hypot(se["direct"], se[other])), (other, m, se)
    # per-sample pixel variance, averaged over pixels, with its own replicate error
    var = {}
    for i, k in enumerate(("direct", "direct_light", "direct_bsdf")):
        v = np.array([render(cornell, integrator=k, spp=16, res=8, rng=s).variance.mean()
                      for s in np.random.default_rng(SEED + 10 + i).spawn(8)])
        var[k] = (v.mean(), v.std(ddof=1) / np.sqrt(len(v)))
    worse = max(var["direct_light"][0], var["direct_bsdf"][0])
    worse_se = var["direct_light"][1] if var["direct_light"][0] > var["direct_bsdf"][0] else var["direct_bsdf"][1]
    assert var["direct"][0] <= worse + Z * np.hypot(var["direct"][1], worse_se), var


@pytest.mark.parametrize("heuristic", ["power", "balance"])
def test_russian_roulette_agrees_with_a_deep_fixed_depth(cornell, heuristic):
    # 0.725^40 < 1e-5: light beyond 40 segments is far below the standard error
    R = 16
    rr = _replicates(cornell, "path", R, SEED + 20, spp=4, res=8, heuristic=heuristic)
    deep = _replicates(cornell, "path", R, SEED + 21, spp=4, res=8, heuristic=heuristic, max_depth=40)
    diff = np.abs(rr.mean(0) - deep.mean(0))
    se = np.hypot(rr.std(0, ddof=1), deep.std(0, ddof=1)) / np.sqrt(R)
    assert np.all(diff < Z * se), (rr.mean(0), deep.mean(0), se)


def test_path_with_and_without_light_connection_agree(cornell):
    a = render(cornell, integrator="path", spp=32, res=8, rng=SEED + 30)
    b = render(cornell, integrator="path_bsdf", spp=32, res=8, rng=SEED + 31)
    (ma, sa), (mb, sb) = _mean_and_se(a), _mean_and_se(b)
    assert np.all(np.abs(ma - mb) < Z * np.hypot(sa, sb))
    # connecting to the light pays: lower per-sample variance
    assert a.variance.mean() < b.variance.mean()


#: every loop the driver can choose for the Cornell box (the 'kernel' option)
KERNELS = ["lambertian", "general"]


@pytest.mark.parametrize("kernel", KERNELS)
def test_image_mean_matches_the_specification(cornell, kernel):
    # CORNELL.md: the converged 64 x 64 image mean is roughly (0.196, 0.127, 0.036),
    # given to 3 decimals (+- 0.0005 rounding) on top of our standard error.
    r = render(cornell, integrator="path", spp=32, res=64, rng=SEED + 40, kernel=kernel)
    mean, se = _mean_and_se(r)
    assert np.all(np.abs(mean - [0.196, 0.127, 0.036]) < Z * se + 0.0005), (mean, se)


def test_float32_geometry_does_not_bias_the_image(cornell):
    a = render(cornell, integrator="path", spp=16, res=16, rng=SEED + 50, precision="float32")
    b = render(cornell, integrator="path", spp=16, res=16, rng=SEED + 51, precision="float64")
    (ma, sa), (mb, sb) = _mean_and_se(a), _mean_and_se(b)
    assert np.all(np.abs(ma - mb) < Z * np.hypot(sa, sb)), (ma, mb)


# -- the lecture's comparisons ----------------------------------------------

@pytest.mark.parametrize("kernel", KERNELS)
def test_depth_8_is_brighter_than_depth_2(cornell, kernel):
    # 'Number of Ray Bounces': depth 2 is direct light only; depth 8 adds indirect light
    a = render(cornell, integrator="path", spp=256, res=16, rng=SEED + 60, max_depth=2, kernel=kernel)
    b = render(cornell, integrator="path", spp=256, res=16, rng=SEED + 61, max_depth=8, kernel=kernel)
    (ma, sa), (mb, sb) = _mean_and_se(a), _mean_and_se(b)
    # on the sum of the channels; its SE is at most the sum of the channels' SEs
    assert mb.sum() - ma.sum() > Z * np.hypot(sa.sum(), sb.sum()), (ma, mb)
    # the ceiling (top row, middle) is never lit directly (the light faces down,
    # below it): black at depth 2, lit by bounces at depth 8
    assert a.image[0, 8].max() == 0.0 and b.image[0, 8].min() > 0.0


def test_16_spp_is_closer_to_the_reference_than_1_spp(cornell):
    # 'Number of Ray Samples': per pixel squared error against a reference. A
    # sign test (fireflies make the errors heavy-tailed): if 16 spp were no
    # better, the count of pixels where it is closer would be Binomial(n, 1/2).
    ref = render(cornell, integrator="path", spp=256, res=16, rng=SEED + 70).image
    one = render(cornell, integrator="path", spp=1, res=16, rng=SEED + 71).image
    six = render(cornell, integrator="path", spp=16, res=16, rng=SEED + 72).image
    d = ((one - ref) ** 2).sum(-1).ravel() - ((six - ref) ** 2).sum(-1).ravel()
    d = d[d != 0]                                  # the light's pixels are exact in both
    assert np.sum(d > 0) > d.size / 2 + Z * np.sqrt(d.size) / 2
    assert np.mean(one.max(-1) == 0) > np.mean(six.max(-1) == 0)


# -- determinism, processes, interruption ------------------------------------

def test_same_seed_same_image_other_seed_other_image(cornell):
    a = render(cornell, spp=4, res=8, rng=123456789, sampler="sobol")
    b = render(cornell, spp=4, res=8, rng=123456789, sampler="sobol")
    c = render(cornell, spp=4, res=8, rng=123456790, sampler="sobol")
    np.testing.assert_array_equal(a.image, b.image)
    assert not np.array_equal(a.image, c.image)


def test_two_workers_give_the_same_image_as_one(cornell):
    a = render(cornell, spp=8, res=8, rng=SEED, batch_spp=2, workers=1)
    b = render(cornell, spp=8, res=8, rng=SEED, batch_spp=2, workers=2)
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.variance, b.variance)
    assert b.spp == 8 and not b.interrupted


def test_kept_worker_pool_renders_each_scene_with_its_own_tracer(cornell):
    # the worker processes outlive a render; the next render's batches must
    # use the next scene (tracers are keyed by a per-render token)
    spheres = load_scene("cornell-spheres")
    for scene in (cornell, spheres, cornell):
        a = render(scene, spp=4, res=8, rng=SEED + 90, batch_spp=1, workers=1)
        b = render(scene, spp=4, res=8, rng=SEED + 90, batch_spp=1, workers=2)
        np.testing.assert_array_equal(a.image, b.image)


def test_interrupted_render_keeps_the_finished_batches(cornell):
    calls = []

    def stop_after_two(done, total):
        calls.append(done)
        if len(calls) == 2:
            raise KeyboardInterrupt

    r = render(cornell, spp=12, res=8, rng=SEED, batch_spp=3, progress=stop_after_two)
    assert r.interrupted and r.spp == 6 and calls == [3, 6]
    # batch k uses stream k whatever the total: the same as asking for 6 spp
    full = render(cornell, spp=6, res=8, rng=SEED, batch_spp=3)
    np.testing.assert_array_equal(r.image, full.image)
    assert np.all(np.isfinite(r.image))


def test_batches_bound_memory_without_changing_the_estimate(cornell):
    a = render(cornell, spp=16, res=8, rng=SEED + 80, batch_spp=1)
    b = render(cornell, spp=16, res=8, rng=SEED + 81, batch_spp=16)
    (ma, sa), (mb, sb) = _mean_and_se(a), _mean_and_se(b)
    assert a.batch_spp == 1 and np.all(np.abs(ma - mb) < Z * np.hypot(sa, sb))


def test_trace_paths_empty_batch(cornell):
    rad, rays = trace_paths(cornell, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4)))
    assert rad.shape == (0, 3) and rays == 0


# -- bad input ---------------------------------------------------------------

@pytest.mark.parametrize("kwargs,match", [
    ({"spp": 0}, "spp must be >= 1"),
    ({"spp": -3}, "spp must be >= 1"),
    ({"integrator": "whitted"}, "method must be one of"),
    ({"sampler": "dart"}, "sampler must be one of"),
    ({"res": 0}, "res must be >= 1"),
    ({"res": (8, 0)}, "height"),
    ({"max_depth": 0}, "max_depth must be >= 1"),
    ({"heuristic": "max"}, "heuristic must be one of"),
    ({"integrator": "direct", "max_depth": 3}, "max_depth must be None or 2"),
    ({"integrator": "depth", "max_depth": 3}, "does not apply"),
    ({"workers": 0}, "workers must be >= 1"),
])
def test_bad_input_names_the_argument(cornell, kwargs, match):
    with pytest.raises(ValueError, match=match):
        render(cornell, **kwargs)


def test_bad_types(cornell):
    with pytest.raises(TypeError, match="scene must be"):
        render("cornell")
    with pytest.raises(TypeError, match="res must be"):
        render(cornell, res="64")
    with pytest.raises(TypeError, match="spp must be an integer"):
        render(cornell, spp=4.0)


def test_integrator_names_are_the_documented_ones():
    # the core's methods; every other registered method is tested in its own module
    assert {"path", "path_bsdf", "direct", "direct_light", "direct_bsdf",
                                "albedo", "normal", "depth", "raster", "position"} <= set(INTEGRATORS)


def test_shadow_rays_stop_short_of_the_light_plane_at_grazing_angles():
    # Floor points (normal +y) lit by samples on a light plane y = 548.7 facing
    # down, seen at angles down to ~2 degrees above the horizon. A shadow ray
    # aimed along w from the offset origin would end past the light's plane
    # whenever cos(theta_light) < 1/2, so the emitter would shadow itself.
    from mcvar.integrators import _shadow_rays

    rng = np.random.default_rng(4417)
    m, eps, light_y = 2000, 1.0, 548.7
    p = np.stack([rng.uniform(-1.5e4, 1.5e4, m), np.zeros(m), rng.uniform(-1.5e4, 1.5e4, m)])
    light = np.stack([rng.uniform(213, 343, m), np.full(m, light_y), rng.uniform(227, 332, m)])
    to_light = light - p
    dist = np.linalg.norm(to_light, axis=0)
    w = to_light / dist
    assert np.mean(w[1] < 0.5) > 0.9  # the test covers the grazing cases
    ng = np.tile([[0.0], [1.0], [0.0]], (1, m))
    origin, d, tmax = _shadow_rays(p, ng, np.ones(m), w, dist, eps)
    end = origin + d * tmax
    np.testing.assert_allclose(np.linalg.norm(d, axis=0), 1.0, atol=1e-12)
    assert np.all(end[1] < light_y)
    # the segment ends 2 eps before the light sample, along the line to it
    np.testing.assert_allclose(np.linalg.norm(light - end, axis=0), 2 * eps, rtol=1e-9)


def test_shadow_rays_to_infinitely_far_samples_keep_their_direction():
    from mcvar.integrators import _shadow_rays

    w = np.array([[0.6], [0.8], [0.0]])
    origin, d, tmax = _shadow_rays(np.zeros((3, 1)), np.array([[0.0], [1.0], [0.0]]), np.ones(1),
                                   w, np.array([np.inf]), 1e-3)
    np.testing.assert_array_equal(d, w)
    assert tmax[0] == np.inf and np.all(np.isfinite(origin))


@pytest.mark.parametrize("integrator,max_depth", [("path", None), ("path", 3), ("direct", None),
                                                  ("direct_light", None), ("direct_bsdf", None),
                                                  ("path_bsdf", None)])
def test_trusted_lambertian_loop_agrees_with_the_general_loop(cornell, integrator, max_depth):
    # The Cornell box (Lambertian triangles, one quad light) runs the
    # Lambertian kernel by default; the general loop (material sort, BSDF
    # calls) must give the same image in expectation. Compared on the rows
    # below the light (rows 4..15 of 16; the light and its edge pixels, whose
    # 0-or-17 samples would dominate the standard error, lie in rows 1..3):
    # per-channel means within Z combined standard errors; and the same rays
    # per path to ~Z binomial-ish noise (both trace the same kinds of rays).
    a = render(cornell, integrator=integrator, spp=16, res=16, rng=SEED + 130, max_depth=max_depth,
               kernel="lambertian")
    b = render(cornell, integrator=integrator, spp=16, res=16, rng=SEED + 131, max_depth=max_depth,
               kernel="general")

    def lower(r):
        img, var = r.image[4:], r.variance[4:]
        n = img.shape[0] * img.shape[1]
        return img.mean(axis=(0, 1)), np.sqrt(var.sum(axis=(0, 1)) / r.spp) / n

    (ma, sa), (mb, sb) = lower(a), lower(b)
    assert np.all(np.abs(ma - mb) < Z * np.hypot(sa, sb)), (ma, mb, sa, sb)
    # rays per path: each path traces between 1 and 2 * depth rays, so its
    # standard deviation is at most depth (half the range, Popoviciu) and
    # the difference of two means of n paths has SE <= depth * sqrt(2 / n)
    depth = 2 if integrator.startswith("direct") else max_depth
    if depth is not None:
        n = 16 * 16 * 16
        assert abs(a.rays - b.rays) / n < Z * depth * np.sqrt(2.0 / n), (a.rays, b.rays)


def test_batch_sizes_the_sampler_cannot_make_fail_before_any_work(cornell):
    # 128 is not a perfect square: the jittered sampler cannot stratify a batch
    # of it, and render says so up front, not from inside a worker process.
    calls = []
    with pytest.raises(ValueError, match=r"perfect square.*spp=128"):
        render(cornell, spp=256, res=4, sampler="jittered", batch_spp=128, rng=1,
               progress=lambda done, total: calls.append(done))
    assert calls == []


def test_batches_trace_slices_of_one_stratified_set_per_pixel():
    # A 64-spp Sobol render traced in four 16-spp batches must still see each
    # pixel's 64 points as one (0, 6, 2)-net, not four unrelated 16-point nets.
    from mcvar.discrepancy import is_net
    from mcvar.integrators import WHOLE_SET_FLOATS, _whole_pattern

    rng = np.random.default_rng(60606)
    whole = _whole_pattern("sobol", 5, 64, 4, 6, rng)      # batches slice it: whole[:, 16 b:16 (b + 1)]
    assert whole.shape == (5, 64, 6)
    for pixel in whole:
        assert is_net(pixel[:, 0:2], 6)  # the pixel-position pair
        assert is_net(pixel[:, 2:4], 6)  # and a padded pair
    # iid points have nothing to keep, one batch needs no pattern, and sets
    # past the budget are drawn per batch
    assert _whole_pattern("random", 5, 64, 4, 6, rng) is None
    assert _whole_pattern("sobol", 5, 64, 1, 6, rng) is None
    n_pix = WHOLE_SET_FLOATS // 64 // 2 + 1      # not even one pair of dimensions fits
    assert _whole_pattern("sobol", n_pix, 64, 4, 6, rng) is None


def test_camera_soa_directions_are_the_public_ones_transposed():
    # render() builds camera rays with Camera.ray_directions_soa (3, n); it must be
    # exactly the public (n, 3) ray_directions, on a non-square image and at the
    # pixel-sample extremes u, v in {0, 1}
    cam = load_scene("cornell").camera
    rng = np.random.default_rng(20241122)
    res = (8, 4)
    pix = np.concatenate([[0, 31, 7, 24], rng.integers(0, 32, 200)])
    uv = rng.random((pix.size, 2))
    uv[:4] = [(0.0, 0.0), (1.0, 1.0), (1.0, 0.0), (0.0, 1.0)]
    soa = cam.ray_directions_soa(res, pix, uv)
    assert soa.shape == (3, pix.size) and soa.flags.c_contiguous
    np.testing.assert_array_equal(soa.T, cam.ray_directions(res, pix, uv))
    # unit length to float64 rounding (3 products and a square root: a few ulp)
    np.testing.assert_allclose(np.einsum("kn,kn->n", soa, soa), 1.0, rtol=0, atol=8 * np.finfo(float).eps)


def test_nee_density_equals_the_density_of_hitting_the_same_light_point():
    # The pdf NEE hands to the MIS weight (Emitters.sample_li, solid angle) must
    # be the pdf the MIS weight of a BSDF-sampled hit uses for the same light
    # point (Emitters.pdf_li): trace the NEE direction, hit the light, compare.
    from mcvar.integrators import Emitters
    from mcvar.tracer import Tracer

    scene = load_scene("cornell")
    em, tracer = Emitters(scene), Tracer(scene, dtype="float64")
    rng = np.random.default_rng(8080)
    m = 4000
    p = np.stack([rng.uniform(10, 540, m), rng.uniform(1, 540, m), rng.uniform(10, 550, m)])
    w, dist, le, pdf, light = em.sample_li(p, rng.random((2, m)), None)
    assert np.all(light == 0) and np.mean(pdf > 0) > 0.99
    hit = tracer.intersect(p.T, w.T)
    on = (hit.prim >= 0) & (np.take(scene.prim_light, np.maximum(hit.prim, 0)) == 0) & (pdf > 0)
    assert on.mean() > 0.3                       # many rays reach the light unoccluded
    x = p.T[on] + hit.t[on, None] * w.T[on]
    np.testing.assert_allclose(hit.t[on], dist[on], rtol=1e-9)
    np.testing.assert_allclose(em.pdf_li(hit.prim[on], p.T[on], x), pdf[on], rtol=1e-9)
    # the environment: sample_li's density is environment_pdf of the same direction
    env_scene = load_scene("quad-environment")
    em = Emitters(env_scene)
    w, dist, le, pdf, light = em.sample_li(np.zeros((3, 500)), rng.random((2, 500)), rng.random(500))
    assert np.all(np.isinf(dist)) and np.all(light == -1)
    np.testing.assert_allclose(em.environment_pdf(w.T), pdf, rtol=1e-12)


# -- sample streams --------------------------------------------------------------

def test_a_camera_path_is_a_pure_function_of_its_sample_vector(cornell):
    # with u as wide as stream_dim(max_depth), no number comes from rng: two
    # different rngs give bit-identical radiance; a narrower u does not
    from mcvar.integrators import stream_dim, trace_camera_paths

    rng = np.random.default_rng(99)
    n, depth = 3000, 5
    pixel = rng.integers(0, 16 * 16, n)
    u = rng.random((n, stream_dim(depth)))
    assert u.shape[1] == 2 + 6 * (depth - 1)
    for kernel in KERNELS:
        a, _ = trace_camera_paths(cornell, (16, 16), pixel, u, max_depth=depth, rng=1, kernel=kernel)
        b, _ = trace_camera_paths(cornell, (16, 16), pixel, u, max_depth=depth, rng=2, kernel=kernel)
        np.testing.assert_array_equal(a, b)
        c, _ = trace_camera_paths(cornell, (16, 16), pixel, u[:, :-6], max_depth=depth, rng=2, kernel=kernel)
        assert not np.array_equal(a, c)
    # the columns are consumed in the documented order: the BSDF pair of vertex 1
    # (columns 4, 5) changes indirect light only, never the emission seen directly
    u2 = u.copy()
    u2[:, 4:6] = rng.random((n, 2))
    d1, _ = trace_camera_paths(cornell, (16, 16), pixel, u, max_depth=1)
    d2, _ = trace_camera_paths(cornell, (16, 16), pixel, u2, max_depth=1)
    np.testing.assert_array_equal(d1, d2)
    e1, _ = trace_camera_paths(cornell, (16, 16), pixel, u, max_depth=3)
    e2, _ = trace_camera_paths(cornell, (16, 16), pixel, u2, max_depth=3)
    assert not np.array_equal(e1, e2)


def test_padded_pairs_are_randomized_independently():
    # pixel_samples gives every 2-D pair of the stream its own randomization:
    # the pairs of one pixel are not copies, and across pixels the first
    # coordinates of two pairs are uncorrelated (|r| < Z / sqrt(n) for n pairs)
    from mcvar.samplers import pixel_samples

    for name in ("sobol", "multi_jittered", "jittered"):
        u = pixel_samples(name, 400, 16, dim=8, rng=31337)
        assert not np.array_equal(u[:, :, 2:4], u[:, :, 4:6])
        x = u[:, :, 0::2].reshape(-1, 4)
        r = np.corrcoef(x.T)[np.triu_indices(4, 1)]
        assert np.all(np.abs(r) < Z / np.sqrt(x.shape[0])), (name, r)


# -- executors and memory --------------------------------------------------------

def test_any_executor_renders_the_same_image(cornell):
    # the batches are picklable descriptions and results are added in batch
    # order: a Dask cluster, a kept WorkerPool and one process give one image
    distributed = pytest.importorskip("dask.distributed")
    from mcvar.integrators import WorkerPool

    kw = dict(spp=8, res=8, rng=SEED + 140, batch_spp=2, sampler="sobol")
    a = render(cornell, **kw)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        b = render(cornell, executor=client.get_executor(), **kw)
    with WorkerPool(2) as pool:
        c = render(cornell, executor=pool, **kw)
        d = render(cornell, executor=pool, **kw)       # the pool outlives a render
    for other in (b, c, d):
        np.testing.assert_array_equal(a.image, other.image)
        np.testing.assert_array_equal(a.variance, other.variance)
    with pytest.raises(TypeError, match="executor must have a submit"):
        render(cornell, executor=4)


def _batch_recording_who(folder, parent, job):
    """``path``'s run_batch, leaving a file ``<batch>-<pid>``; the pool process's
    first batch sleeps, so that the pool holds a second batch queued behind it."""
    import os
    import time
    from pathlib import Path

    from mcvar.integrators.path import run_path_batch

    i = job.rng.bit_generator.seed_seq.spawn_key[-1]          # the batch's index in its stage
    if os.getpid() != parent and not any(f.name.endswith(f"-{os.getpid()}") for f in Path(folder).iterdir()):
        time.sleep(1.5)
    (Path(folder) / f"{i}-{os.getpid()}").touch()
    return run_path_batch("path", job)


def test_the_caller_takes_a_batch_the_pool_has_queued_but_not_started(cornell, tmp_path):
    """Twenty batches, two workers: the pool process's first batch is slow, with
    the next one already in its process's queue (ProcessPoolExecutor: no longer
    cancellable); the caller takes the batches no worker has received, claims
    the queued one (:class:`_Claims`), so the pool skips it, and keeps submitting
    and running new batches while the slow one runs (the window counts batches
    without a result). So every batch runs once and the pool runs exactly one;
    the image is that of one worker."""
    import os
    from functools import partial

    from mcvar.integrators import METHODS
    from mcvar.integrators.driver import _Claims, _pool_context

    claims = _Claims(_pool_context())
    a, b = claims.number(), claims.number()
    assert claims.claim(b) and not claims.claim(b) and claims.claim(a) and not claims.claim(a)
    assert claims.claim(b + _Claims.RING)                     # a later batch in the same slot

    method = dataclasses.replace(METHODS["path"], run_batch=partial(_batch_recording_who, str(tmp_path),
                                                                    os.getpid()))
    kw = dict(spp=20, res=8, rng=SEED + 160, batch_spp=1, sampler="sobol")
    two = render(cornell, method=method, workers=2, **kw)
    runs = [f.name.split("-") for f in tmp_path.iterdir()]
    assert sorted(int(i) for i, _ in runs) == list(range(20)), runs   # each batch once
    in_pool = [i for i, pid in runs if pid != str(os.getpid())]
    assert len(in_pool) == 1, runs                                    # the slow one; the caller the others
    np.testing.assert_array_equal(two.image, render(cornell, **kw).image)


def test_the_render_pool_receives_the_tracer_once_not_with_every_batch(cornell, monkeypatch):
    """A pool's processes get the render's scene, tracer and prepared data when they
    start; a batch then pickles them as a token, so what is submitted per batch is a
    small fraction of the tracer (a per-batch pickled tracer, the old behaviour, sends
    at least the tracer's bytes every time; a kept pool started for another render still
    does, and is measured here to show the count would see it). Same image throughout."""
    import pickle

    from mcvar.integrators import WorkerPool
    from mcvar.integrators.driver import _WorkerSlot
    from mcvar.tessellate import subdivide
    from mcvar.tracer import Tracer

    scene = subdivide(cornell, 8)                        # 1,922 triangles: a BVH tracer
    tracer_bytes = len(pickle.dumps(Tracer(scene)))
    assert tracer_bytes > 100_000
    sizes = []
    submit = WorkerPool.submit

    def counting(self, fn, *args, **kwargs):
        sizes.append(len(pickle.dumps((fn, args, kwargs))))
        return submit(self, fn, *args, **kwargs)

    monkeypatch.setattr(WorkerPool, "submit", counting)
    kw = dict(spp=4, res=8, rng=SEED + 150, batch_spp=1, sampler="sobol")
    one = render(scene, **kw)
    two = render(scene, workers=2, **kw)                 # the render's own pool
    own = list(sizes)
    with WorkerPool(1) as pool:
        first = render(scene, executor=pool, **kw)       # a kept pool, not yet started: bound to this render
        bound = sizes[len(own):]
        second = render(scene, executor=pool, **kw)      # started for another render: full batches
        full = sizes[len(own) + len(bound):]
    for r in (two, first, second):
        np.testing.assert_array_equal(one.image, r.image)
        np.testing.assert_array_equal(one.variance, r.variance)
    assert own and bound and full
    # a batch's own data (its pixels' slice of the sample pattern) is ~10 kB here
    assert max(own) < tracer_bytes / 10 and max(bound) < tracer_bytes / 10, (max(own), max(bound), tracer_bytes)
    assert min(full) - max(bound) > 0.9 * tracer_bytes, (min(full), max(bound), tracer_bytes)
    with pytest.raises(RuntimeError, match="was not started with"):
        _WorkerSlot.get("not-a-render")               # this process holds no render's data


def test_a_render_too_big_for_memory_is_refused_before_any_work(cornell):
    from mcvar.integrators import MAX_RENDER_BYTES, estimate_render_bytes

    calls = []
    with pytest.raises(ValueError, match=r"needs about .* GiB.*max_memory"):
        render(cornell, res=10 ** 6, spp=1, progress=lambda d, t: calls.append(d))
    assert calls == []
    # the estimate is at least the film's four float64 (n_pix, 3) arrays
    assert estimate_render_bytes(10 ** 12, 10 ** 12, 2) >= 96 * 10 ** 12 > MAX_RENDER_BYTES
    # the limit is documented and overridable, both ways
    with pytest.raises(ValueError, match="max_memory"):
        render(cornell, res=8, spp=1, max_memory=1000)
    assert render(cornell, res=8, spp=1, rng=1, max_memory=MAX_RENDER_BYTES * 2).spp == 1


def test_sampler_dim_says_how_many_stream_columns_the_sampler_feeds(cornell):
    # sampler_dim=2 stratifies only the pixel position; the default also feeds
    # the vertices. Both are unbiased: image means agree within Z standard errors
    # (per-sample variances of iid-or-better pixels bound the standard error).
    a = render(cornell, spp=16, res=8, rng=SEED + 150, sampler="sobol", sampler_dim=2)
    b = render(cornell, spp=16, res=8, rng=SEED + 151, sampler="sobol")
    (ma, sa), (mb, sb) = _mean_and_se(a), _mean_and_se(b)
    assert np.all(np.abs(ma - mb) < Z * np.hypot(sa, sb)), (ma, mb)
    assert not np.array_equal(a.image, render(cornell, spp=16, res=8, rng=SEED + 150, sampler="sobol").image)
    with pytest.raises(ValueError, match="sampler_dim must be >= 1"):
        render(cornell, sampler_dim=0)


# -- the film ----------------------------------------------------------------------

def test_splat_adds_repeated_pixels_and_rejects_pixels_outside():
    from mcvar.integrators import splat

    acc = np.zeros((5, 3))
    splat(acc, [4, 0, 4, 4], np.arange(12.0).reshape(4, 3))
    np.testing.assert_array_equal(acc[4], [0 + 6 + 9, 1 + 7 + 10, 2 + 8 + 11])
    np.testing.assert_array_equal(acc[0], [3, 4, 5])
    assert not acc[1:4].any()
    with pytest.raises(ValueError, match="pixel_index must lie in"):
        splat(acc, [5], np.ones((1, 3)))


def test_film_variance_from_independent_batches_is_the_per_sample_variance():
    # Splat / chain batches: batch b's image I_b has variance sigma^2 / n_b; the
    # film's s^2 = sum n_b (I_b - I)^2 / (B - 1) is unbiased for sigma^2 even
    # for unequal n_b. Over P pixels-channels the mean of s^2 / sigma^2 is a
    # chi^2_{B-1} / (B - 1) average: its SE is sqrt(2 / ((B - 1) P)).
    from mcvar.integrators import BatchResult, Film

    rng = np.random.default_rng(5150)
    n_pix, sigma, mu = 4000, 0.7, 2.0
    sizes = [4, 4, 4, 2, 1]
    film = Film(n_pix, per_sample=False)
    for n_b in sizes:
        image = mu + sigma / np.sqrt(n_b) * rng.standard_normal((n_pix, 3))
        film.add(BatchResult(sum=image * n_b, sum_sq=None, rays=0), n_b)
    var = film.variance((n_pix, 1))
    ratio = var.mean() / sigma ** 2
    se = np.sqrt(2.0 / ((len(sizes) - 1) * 3 * n_pix))
    assert abs(ratio - 1.0) < Z * se, (ratio, se)
    np.testing.assert_allclose(film.image((n_pix, 1)).mean(), mu, atol=Z * sigma / np.sqrt(3 * n_pix * sum(sizes)))
    one = Film(3, per_sample=False)
    one.add(BatchResult(np.ones((3, 3)), None, 0), 2)
    assert one.variance((3, 1)) is None               # one batch: no spread to measure


# ---------------------------------------------------------------------------
# The one driver (issue 20): settings, names, stream dimensions, lazy batches

def test_path_settings_are_validated_once_naming_the_field():
    from mcvar.integrators import PathSettings

    bad = [({"max_depth": 0}, ValueError, "max_depth"), ({"max_depth": True}, TypeError, "max_depth"),
           ({"max_depth": 2.0}, TypeError, "max_depth"), ({"heuristic": "cutoff"}, ValueError, "heuristic"),
           ({"kernel": 1}, TypeError, "kernel"), ({"light_sampling": "sphere"}, ValueError, "light_sampling"),
           ({"rr_depth": -1}, ValueError, "rr_depth"), ({"rr_threshold": 0.0}, ValueError, "rr_threshold"),
           ({"rr_threshold": float("nan")}, ValueError, "rr_threshold"),
           ({"rr_threshold": np.bool_(True)}, TypeError, "rr_threshold"),
           ({"visible_lights": "analytic"}, ValueError, "visible_lights")]
    for kw, exc, name in bad:
        with pytest.raises(exc, match=name):
            PathSettings(**kw)
    s = PathSettings(max_depth=np.int64(3), rr_threshold=np.float32(0.5))
    assert type(s.max_depth) is int and s.max_depth == 3 and type(s.rr_threshold) is float
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.max_depth = 4


def test_path_settings_object_gives_the_image_of_its_keywords(cornell):
    from mcvar.integrators import PathSettings

    kw = dict(spp=4, res=8, rng=SEED, sampler="sobol")
    a = render(cornell, max_depth=3, kernel="general", rr_threshold=0.5, **kw)
    b = render(cornell, settings=PathSettings(max_depth=3, kernel="general", rr_threshold=0.5), **kw)
    assert np.array_equal(a.image, b.image)
    with pytest.raises(ValueError, match="not both"):
        render(cornell, settings=PathSettings(max_depth=3), max_depth=3, **kw)
    with pytest.raises(ValueError, match="does not take.*kernel"):      # light does not read the path kernel
        render(cornell, method="light", settings=PathSettings(kernel="general"), **kw)
    # trace_paths takes the record or its fields, the same radiance
    rng = np.random.default_rng(SEED)
    d = cornell.camera.ray_directions((8, 8), np.arange(64), rng.random((64, 2)))
    o = np.broadcast_to(cornell.camera.position, d.shape)
    u = rng.random((64, 30))
    r1, _ = trace_paths(cornell, o, d, u, rng=1, max_depth=4, heuristic="balance")
    r2, _ = trace_paths(cornell, o, d, u, rng=1, settings=PathSettings(max_depth=4, heuristic="balance"))
    assert np.array_equal(r1, r2)
    with pytest.raises(TypeError, match="unexpected keyword"):
        trace_paths(cornell, o, d, u, rng=1, depth=4)


def test_method_is_the_name_and_integrator_its_alias(cornell):
    kw = dict(spp=2, res=4, rng=SEED)
    a = render(cornell, method="direct", **kw)
    b = render(cornell, integrator="direct", **kw)
    assert np.array_equal(a.image, b.image) and a.method == a.integrator == "direct"
    with pytest.raises(ValueError, match="not both"):
        render(cornell, method="direct", integrator="path", **kw)


def _recording(seen, run, job):
    seen.append(None if job.u is None else job.u.shape[1])
    return run(job)


@pytest.mark.parametrize("name, columns", [("path", 20), ("direct", 8), ("albedo", 2), ("photon", 2),
                                           ("pssmlt", None), ("bdpt", 2)])
def test_the_driver_draws_only_the_columns_a_method_reads(cornell, name, columns):
    """Method.stream_dims: the sampler feeds path's 20 columns (SAMPLER_DIM),
    direct's depth-2 8, the camera columns of first-hit, photon and bdpt, and
    none for pssmlt (its chains draw their own states: job.u is None)."""
    from functools import partial

    from mcvar.integrators import METHODS

    seen = []
    m = METHODS[name]
    method = dataclasses.replace(m, run_batch=partial(_recording, seen, m.run_batch))
    render(cornell, method=method, spp=4, res=4, sampler="sobol", rng=SEED)
    assert seen and set(seen) == {columns}


def test_a_huge_spp_starts_at_once_and_stops_on_ctrl_c(cornell):
    """spp = 2^40 at 4 x 4 is 2^28 batches of 4096 spp: they are described lazily
    (no list of batches, no spawn of 2^28 generators), so the first batch runs at
    once with bounded memory; a KeyboardInterrupt from the progress callback
    keeps it. Adaptive allocation too (a pixel's 2^35 pilot samples cut into
    batches of PILOT_PATHS_PER_BATCH paths)."""
    import tracemalloc

    from mcvar.integrators import PATHS_PER_BATCH

    def stop(done, total):
        raise KeyboardInterrupt

    tracemalloc.start()
    try:
        r = render(cornell, spp=2 ** 40, res=4, rng=SEED, progress=stop)
        a = render(cornell, spp=2 ** 40, res=4, rng=SEED, progress=stop, allocation="adaptive")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert r.interrupted and r.spp == PATHS_PER_BATCH // 16
    assert a.interrupted and np.all(np.isfinite(a.image))
    assert peak < 200 * 2 ** 20
