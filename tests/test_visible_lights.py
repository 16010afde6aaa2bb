"""Lights seen directly by the camera, integrated exactly over each pixel
(mcvar.integrators.VisibleLights, ``visible_lights='exact'``), the polygon
coverage it rests on (mcvar.geometry.polygon_pixel_coverage), and the
weight-window Russian roulette (``rr_threshold``): each checked against an
independent estimate with tolerances from standard errors."""
import dataclasses

import numpy as np
import pytest
from matplotlib.path import Path

from mcvar.geometry import polygon_pixel_coverage
from mcvar.integrators import VisibleLights, render, trace_paths
from mcvar.scene import Camera, load_scene

SEED = 20261202


@pytest.fixture(scope="module")
def cornell():
    return load_scene("cornell")


# -- polygon coverage ---------------------------------------------------------

def test_coverage_of_an_axis_aligned_square_is_exact():
    sq = np.array([[0.5, 0.5], [2.5, 0.5], [2.5, 2.5], [0.5, 2.5]])
    expected = np.zeros((4, 4))
    expected[:3, :3] = [[0.25, 0.5, 0.25], [0.5, 1.0, 0.5], [0.25, 0.5, 0.25]]
    np.testing.assert_allclose(polygon_pixel_coverage(sq, 4, 4), expected, atol=1e-15)
    np.testing.assert_allclose(polygon_pixel_coverage(sq[::-1], 4, 4), expected, atol=1e-15)


def test_coverage_sums_to_the_area_inside_the_raster():
    tri = np.array([[0.2, 0.3], [3.7, 1.1], [1.5, 3.9]])
    (ax, ay), (bx, by) = tri[1] - tri[0], tri[2] - tri[0]
    area = 0.5 * abs(ax * by - ay * bx)
    assert polygon_pixel_coverage(tri, 4, 4).sum() == pytest.approx(area, rel=1e-12)
    assert polygon_pixel_coverage(tri + 10.0, 4, 4).sum() == 0.0          # outside
    # a polygon larger than the raster covers every pixel fully
    big = np.array([[-5.0, -5.0], [9.0, -5.0], [9.0, 9.0], [-5.0, 9.0]])
    np.testing.assert_allclose(polygon_pixel_coverage(big, 3, 2), np.ones((2, 3)), rtol=1e-12)


def test_coverage_matches_monte_carlo_per_pixel():
    """Random points in the raster: the fraction inside the polygon per pixel
    agrees with the coverage within 5 binomial standard errors (Sidak over
    the pixels)."""
    rng = np.random.default_rng(SEED)
    poly = np.array([[0.3, 2.2], [2.9, 0.4], [5.6, 1.7], [4.8, 4.6], [1.1, 4.9]])   # convex pentagon
    w, h, n = 6, 5, 400_000
    cov = polygon_pixel_coverage(poly, w, h)
    pts = rng.random((n, 2)) * [w, h]
    inside = Path(poly).contains_points(pts)
    counts, totals = np.zeros((h, w)), np.zeros((h, w))
    np.add.at(counts, (pts[inside, 1].astype(int), pts[inside, 0].astype(int)), 1.0)
    np.add.at(totals, (pts[:, 1].astype(int), pts[:, 0].astype(int)), 1.0)
    frac = counts / totals
    se = np.sqrt(np.maximum(cov * (1 - cov), 1.0 / totals) / totals)
    assert np.all(np.abs(frac - cov) < 5 * se)
    # the raster has empty, partly and fully covered pixels
    assert (cov == 0).any() and ((cov > 0) & (cov < 1)).any() and cov.max() == pytest.approx(1.0)


def test_coverage_bad_input():
    with pytest.raises(ValueError, match="vertices"):
        polygon_pixel_coverage(np.zeros((4, 3)), 4, 4)
    with pytest.raises(ValueError, match="vertices"):
        polygon_pixel_coverage([[0.0, 0.0], [np.nan, 1.0], [1.0, 1.0]], 4, 4)
    with pytest.raises(ValueError, match="width"):
        polygon_pixel_coverage(np.zeros((3, 2)), 0, 4)


# -- the exact image against the rays that cross the light --------------------

def test_image_is_the_pixel_integral_of_crossing_the_light(cornell):
    """The exact image equals, per pixel, Le times the fraction of uniformly
    jittered camera rays that cross the light's emitting face (the ``g`` the
    samples subtract), within 5 binomial standard errors."""
    vis = VisibleLights(cornell)
    assert list(vis.lights) == [0]
    res = (32, 32)
    img = vis.image(res)
    lit = np.flatnonzero(img[:, 0] > 0)
    assert 4 < lit.size < 60
    rng = np.random.default_rng(SEED)
    n = 4000
    pixel = np.repeat(lit, n)
    d = cornell.camera.ray_directions_soa(res, pixel, rng.random((pixel.size, 2)))
    o = np.broadcast_to(cornell.camera.position[:, None], d.shape)
    g = vis.hidden(o, d, np.zeros(pixel.size), np.full(pixel.size, -1))   # every crossing counts
    frac = g[0].reshape(lit.size, n).mean(axis=1) / cornell.light_radiance[0, 0]
    cov = img[lit, 0] / cornell.light_radiance[0, 0]
    se = np.sqrt(np.maximum(cov * (1 - cov), 1.0 / n) / n)
    assert np.all(np.abs(frac - cov) < 5 * se)
    np.testing.assert_allclose(img[lit] / img[lit, :1], [cornell.light_radiance[0] / cornell.light_radiance[0, 0]]
                               * lit.size)


def _agree(a, b, mask):
    """Per-pixel z of two independent renders over ``mask``, all channels."""
    da = (a.image - b.image).reshape(-1, 3)[mask]
    va = (a.variance / a.spp + b.variance / b.spp).reshape(-1, 3)[mask]
    return da, va


@pytest.mark.parametrize("kernel", ["auto", "general"])
def test_exact_is_unbiased_against_sampled(cornell, kernel):
    """``path`` with the light integrated exactly against plain sampling
    (random sampler, independent seeds): per channel the image mean and the
    mean over the pixels the light touches agree within 5 standard errors;
    the light's full pixels have no variance left."""
    res, spp = 16, 64
    a = render(cornell, spp=spp, res=res, rng=SEED, visible_lights="exact", kernel=kernel)
    b = render(cornell, spp=spp, res=res, rng=SEED + 1, kernel=kernel)
    touched = VisibleLights(cornell).image((res, res))[:, 0] > 0
    full = VisibleLights(cornell).image((res, res))[:, 0] >= cornell.light_radiance[0, 0] * (1 - 1e-12)
    for mask in (np.ones(res * res, bool), touched):
        da, va = _agree(a, b, mask)
        k = mask.sum()
        assert np.all(np.abs(da.mean(axis=0)) < 5 * np.sqrt(va.sum(axis=0)) / k)
    if full.any():
        assert np.all(a.variance.reshape(-1, 3)[full] == 0.0)
    # and the exact image lowers the variance where the light's edge is
    assert (a.variance.reshape(-1, 3)[touched]).sum() < 0.2 * (b.variance.reshape(-1, 3)[touched]).sum()


def test_an_occluded_view_of_the_light_subtracts_what_is_hidden(cornell):
    """A camera on the floor behind the tall block looks up at the light: the
    block's top hides part of it. Rays that cross the light behind the block
    subtract its radiance (their ``g``), and the image still agrees with plain
    sampling within 5 standard errors, per pixel (Sidak over the pixels the
    light touches) and on average."""
    cam = Camera(position=[400.0, 10.0, 520.0], look_at=[278.0, 548.7, 280.0], up=[0.0, 0.0, 1.0],
                 fov_deg=cornell.camera.fov_deg)
    scene = dataclasses.replace(cornell, camera=cam, name="cornell-occluded")
    res, spp = 16, 256
    vis = VisibleLights(scene)
    touched = vis.image((res, res))[:, 0] > 0
    assert touched.sum() > 4
    # some camera rays do cross the light behind the block: the subtraction is exercised
    rng = np.random.default_rng(SEED)
    pix = np.repeat(np.flatnonzero(touched), 64)
    d = cam.ray_directions_soa((res, res), pix, rng.random((pix.size, 2)))
    o = np.broadcast_to(cam.position[:, None], d.shape)
    from mcvar.tracer import Tracer
    t, prim = Tracer(scene).closest_soa(o, d)
    hidden = vis.hidden(o, d, t, prim)[0] > 0
    assert 0 < hidden.mean() < 1
    a = render(scene, spp=spp, res=res, rng=SEED, visible_lights="exact")
    b = render(scene, spp=spp, res=res, rng=SEED + 1)
    da, va = _agree(a, b, touched)
    z = np.abs(da) / np.sqrt(np.where(va > 0, va, np.inf))
    assert z.max() < 5.0, z.max()
    assert np.all(np.abs(da.mean(axis=0)) < 5 * np.sqrt(va.sum(axis=0)) / touched.sum())


def test_lights_that_cannot_be_exact_stay_sampled(cornell):
    """A checker-textured light is not constant: nothing is handled exactly,
    and ``exact`` renders the same image as ``sampled`` for the same seed."""
    checker = load_scene("checkerboard") if "checkerboard" in _scenes() else None
    if checker is not None:
        assert not VisibleLights(checker)
    # a camera behind the one-sided light sees its back: not handled
    behind = dataclasses.replace(cornell, camera=Camera(position=[278.0, 700.0, 280.0],
                                                        look_at=[278.0, 548.0, 281.0], up=[0.0, 0.0, 1.0],
                                                        fov_deg=40.0))
    assert not VisibleLights(behind)
    a = render(behind, spp=4, res=8, rng=SEED, visible_lights="exact")
    b = render(behind, spp=4, res=8, rng=SEED)
    assert np.array_equal(a.image, b.image)


def _scenes():
    from mcvar.scene import SCENES
    return SCENES


def test_trace_paths_bad_visible_lights(cornell):
    o = np.broadcast_to(cornell.camera.position, (2, 3))
    d = np.array([[0.0, 0.0, 1.0], [0.0, 0.1, 0.995]])
    with pytest.raises(ValueError, match="visible_lights"):
        trace_paths(cornell, o, d, None, rng=SEED, visible_lights="analytic")
    with pytest.raises(ValueError, match="visible_lights"):
        render(cornell, spp=1, res=4, rng=SEED, visible_lights="yes")
    with pytest.raises(ValueError, match="camera rays"):
        trace_paths(cornell, o + 1.0, d, None, rng=SEED, visible_lights="exact")


# -- weight-window roulette ---------------------------------------------------

def test_weight_window_roulette_is_unbiased(cornell):
    """``rr_threshold=0.2`` against pbrt's rule: image means agree within 5
    standard errors per channel; the window traces more rays per path and
    has less variance."""
    res, spp = 16, 64
    a = render(cornell, spp=spp, res=res, rng=SEED, rr_threshold=0.2)
    b = render(cornell, spp=spp, res=res, rng=SEED + 1)
    da, va = _agree(a, b, np.ones(res * res, bool))
    assert np.all(np.abs(da.mean(axis=0)) < 5 * np.sqrt(va.sum(axis=0)) / res ** 2)
    assert a.rays > b.rays
    assert a.variance.sum() < b.variance.sum()


@pytest.mark.parametrize("bad, err", [(0.0, ValueError), (1.5, ValueError), (float("nan"), ValueError),
                                      ("0.2", TypeError), (True, TypeError)])
def test_bad_rr_threshold(cornell, bad, err):
    with pytest.raises(err, match="rr_threshold"):
        render(cornell, spp=1, res=4, rng=SEED, rr_threshold=bad)


# -- the Lambertian kernel's float32 sample stream ----------------------------

def test_float32_stream_is_u_rounded_then_rng_in_float32():
    """The float32 columns are ``u``'s values rounded (so a path stays a pure
    function of its row of ``u``), and dimensions beyond ``u`` come from the
    rng in float32, inside [0, 1)."""
    from mcvar.integrators.stream import SampleStream
    rng = np.random.default_rng(SEED)
    u = rng.random((1000, 6))
    u[0, 0] = np.nextafter(1.0, 0.0)                     # rounds to 1.0 in float32: still allowed
    s = SampleStream(u, np.random.default_rng(1), camera=True)
    idx = np.arange(0, 1000, 3)
    got = s.columns(0, 6, idx, np.float32)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, u[idx].T.astype(np.float32))
    extra = s.columns(4, 6, idx, np.float32)             # 2 columns of u, then 4 from the rng
    assert extra.dtype == np.float32
    np.testing.assert_array_equal(extra[:2], u[idx, 4:6].T.astype(np.float32))
    assert np.all((extra[2:] >= 0.0) & (extra[2:] < 1.0)) and np.unique(extra[2:]).size > 0.99 * extra[2:].size


# -- the Lambertian kernel's written-out MIS ----------------------------------

@pytest.mark.parametrize("heuristic", ["power", "balance"])
def test_lambertian_light_hits_weigh_like_the_general_loop(cornell, heuristic):
    """Rays from the floor that hit the light after a cosine-sampled bounce:
    the Lambertian kernel's written-out MIS weight (``_hit_light``) adds
    exactly what the general ``Transport.hit_emission`` adds (float32 state:
    to 1e-5 relative). A wrong light density (e.g. ``cos_l`` multiplied
    instead of divided) fails here."""
    from mcvar.integrators import PathSettings
    from mcvar.integrators.emitters import Emitters
    from mcvar.integrators.lambertian import _hit_light, _Tables
    from mcvar.integrators.settings import STRATEGIES
    from mcvar.integrators.state import PathState, SceneTables, Transport
    from mcvar.integrators.stream import SampleStream
    from mcvar.tracer import Tracer
    rng = np.random.default_rng(SEED)
    n = 400
    o = np.stack([rng.uniform(60, 500, n), np.full(n, 1e-3), rng.uniform(60, 500, n)])
    u = rng.random((2, n))
    target = (cornell.light_origin[0][:, None] + u[0] * cornell.light_edge1[0][:, None]
              + u[1] * cornell.light_edge2[0][:, None])
    d = target - o
    d /= np.linalg.norm(d, axis=0)
    tracer = Tracer(cornell)
    emitters = Emitters(cornell)
    tables = SceneTables(cornell, tracer, emitters)
    state = PathState(o, d, dtype=np.float32)
    state.prev_pdf[...] = d[1] / np.pi                    # the cosine density of the bounce that made them
    state.beta[...] = rng.uniform(0.2, 1.0, (3, n))
    t, prim = tracer.closest_soa(state.o, state.d)
    hits = np.take(tables.emits, prim)
    assert hits.mean() > 0.3                              # the rest hit the blocks
    p = state.d * t.astype(np.float32) + state.o

    def transport():
        return Transport(cornell, tracer, n, strategies=STRATEGIES["path"],
                         settings=PathSettings(heuristic=heuristic), stream=SampleStream(None, rng, camera=False),
                         tables=tables)
    general, kernel = transport(), transport()
    general.hit_emission(2, state, p, prim)
    _hit_light(kernel, _Tables(kernel), state, t.astype(np.float32), prim)
    assert np.count_nonzero(general.radiance[0]) == hits.sum()
    np.testing.assert_allclose(kernel.radiance, general.radiance, rtol=1e-5, atol=0)


@pytest.mark.parametrize("heuristic", ["power", "balance"])
def test_written_out_mis_weight_is_the_heuristic(heuristic):
    from mcvar.integrators import HEURISTICS
    from mcvar.integrators.lambertian import _mis_weight

    class T:
        mis_beta = 2.0 if heuristic == "power" else 1.0
    rng = np.random.default_rng(SEED)
    a, b = rng.lognormal(0, 3, 1000), rng.lognormal(0, 3, 1000)
    np.testing.assert_allclose(_mis_weight(T, a, b), HEURISTICS[heuristic](a, b), rtol=1e-12)
    np.testing.assert_allclose(_mis_weight(T, a, b) + _mis_weight(T, b, a), 1.0, rtol=1e-12)


def test_cached_image_is_the_image_and_the_pickled_scene_stays_small(cornell):
    """The cache on the scene (sparse) gives back exactly the image computed
    afresh, on every call; and the scene a batch pickles for a worker process
    does not grow with the image: after caching 256 x 256 (65,536 pixels,
    1.5 MB dense) it grows by less than the dense 64 x 64 image would add.
    A dense cache grew every batch's pickle to 1.7 MB at 256 x 256."""
    import pickle

    scene = dataclasses.replace(cornell)            # a fresh object: an empty cache
    bare = len(pickle.dumps(scene))
    vis = VisibleLights(scene)
    for res in ((256, 256), (64, 48), (256, 256)):
        img = vis.image(res)
        np.testing.assert_array_equal(img, vis._image(*res))
        assert img.shape == (res[0] * res[1], 3) and not img.flags.writeable
    grown = len(pickle.dumps(scene)) - bare
    assert 0 < grown < 64 * 64 * 3 * 8
    back = pickle.loads(pickle.dumps(scene))
    np.testing.assert_array_equal(VisibleLights(back).image((256, 256)), vis._image(256, 256))
