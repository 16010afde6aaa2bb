"""The general wavefront loop (issue 27): its rewrite without the per-bounce
material sort, with Lambertian materials written out and the other BSDFs
called unchecked on their rows, traces the same paths as the loop it
replaced.

``tests/data/general_loop_f9ebaa9.npz`` holds the per-path radiance of the
old loop (commit f9ebaa9, float64 geometry) for sample vectors as wide as
the paths (so no number comes from ``rng``: each path is a pure function of
its row of ``u``). The same rows must give the same radiance to rounding and
the same number of rays: an identity between two implementations of one
estimator, stronger than any statistical test of the two.
"""
from pathlib import Path

import numpy as np
import pytest

from mcvar.integrators import stream_dim, trace_camera_paths
from mcvar.scene import load_scene
from mcvar.tracer import Tracer

GOLDEN = Path(__file__).parent / "data" / "general_loop_f9ebaa9.npz"
N, DEPTH, RES = 1500, 6, (16, 16)
SCENES = ("cornell-spheres", "cornell-point", "quad-environment", "furnace")


def _inputs(s):
    # the generator of tests/data's fixture: the same seeds, the same draws
    rng = np.random.default_rng(2027 + s)
    pixel = rng.integers(0, RES[0] * RES[1], N)
    return pixel, rng.random((N, stream_dim(DEPTH)))


@pytest.mark.parametrize("method", ["path", "direct_light"])
@pytest.mark.parametrize("s,name", list(enumerate(SCENES)))
def test_general_loop_traces_the_paths_of_the_sorted_loop(s, name, method):
    scene = load_scene(name)
    pixel, u = _inputs(s)
    rad, rays = trace_camera_paths(scene, RES, pixel, u, max_depth=DEPTH if method == "path" else None,
                                   method=method, rng=0, tracer=Tracer(scene, dtype="float64"), kernel="general")
    with np.load(GOLDEN) as g:
        ref, ref_rays = g[f"{name}/{method}/radiance"], int(g[f"{name}/{method}/rays"])
    assert ref.any()                       # the fixture sees light (path_bsdf at a point light would not)
    assert rays == ref_rays
    np.testing.assert_allclose(rad, ref, rtol=1e-12, atol=1e-15)


def _means(r, rows=slice(None)):
    """Per-channel image mean over ``rows`` and its standard error (random sampler: iid samples)."""
    img, var = r.image[rows], r.variance[rows]
    n = img.shape[0] * img.shape[1]
    return img.mean(axis=(0, 1)), np.sqrt(var.sum(axis=(0, 1)) / r.spp) / n


@pytest.mark.parametrize("name,depth,rows", [("cornell-spheres", None, slice(None)),
                                             # the point light's ceiling spot (irradiance I / 1^2) makes the
                                             # full image heavy-tailed: direct light on the lower half instead
                                             ("cornell-point", 2, slice(16, 32))])
def test_float32_path_state_agrees_with_float64(name, depth, rows):
    # The general loop keeps its path state in the tracer's precision (float32
    # by default; sphere intersections stay float64): the image must agree
    # with the float64 loop's in expectation. Independent seeds, random
    # sampler; per channel within 5 combined standard errors, Sidak-corrected
    # over the 3 channels.
    from scipy.stats import norm

    from mcvar.integrators import render
    from mcvar.testing import sidak_significance

    scene = load_scene(name)
    kw = dict(spp=64, res=32, sampler="random", kernel="general", max_depth=depth)
    a = render(scene, rng=11, precision="float64", **kw)
    b = render(scene, rng=12, precision="float32", **kw)
    (ma, sa), (mb, sb) = _means(a, rows), _means(b, rows)
    z = norm.isf(0.5 * sidak_significance(2 * norm.sf(5.0), 3))
    assert np.all(np.abs(ma - mb) < z * np.hypot(sa, sb)), (ma, mb, sa, sb)
    assert ma.min() > 10 * sa.max()        # the comparison sees light, not noise


def test_two_workers_give_the_image_of_one_on_the_spheres():
    # the general loop's image is a pure function of the seed: batches draw their
    # own numbers, whichever process runs them (the pool, or the caller stealing
    # from the queue's end); the pilot's allocation then decides the same batches
    from mcvar.adaptive import render_adaptive

    scene = load_scene("cornell-spheres")
    kw = dict(spp=128, res=32, sampler="sobol", rng=2027)      # 2^17 paths: several batches per stage
    a = render_adaptive(scene, workers=1, **kw)
    b = render_adaptive(scene, workers=2, **kw)
    assert a.image.any() and len(np.unique(a.spp_map)) > 1
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.spp_map, b.spp_map)


@pytest.mark.parametrize("radius,offset", [(100.0, 0.0), (0.01, 1000.0), (3.0, -5e4)])
def test_sphere_hits_of_float32_rays_equal_their_float64_solution(radius, offset):
    # float32 rays are screened by a float32 discriminant and solved in float64:
    # the answers must be those of the same rays converted to float64 exactly,
    # also for near-tangent rays, origins on the sphere and tiny spheres far
    # from the origin (the screen's error is relative to |o - c|, not to |o|)
    from mcvar.scene import Scene
    from mcvar.bsdf import Lambertian
    from mcvar.scene import Camera

    rng = np.random.default_rng(31)
    centres = np.array([[offset, 0.0, 0.0], [offset + 3 * radius, radius, 0.0]])
    scene = Scene(name="balls", description="two spheres", triangles=np.zeros((0, 3, 3)),
                  sphere_centers=centres, sphere_radii=np.array([radius, 0.5 * radius]),
                  prim_material=[0, 0], prim_emission=np.zeros((2, 3)),
                  prim_two_sided_emission=np.zeros(2, dtype=bool), prim_light=[-1, -1], prim_group=[0, 0],
                  materials=(Lambertian(),), material_names=("white",),
                  light_origin=np.zeros((0, 3)), light_edge1=np.zeros((0, 3)), light_edge2=np.zeros((0, 3)),
                  light_radiance=np.zeros((0, 3)), camera=Camera((offset, 0, -10 * radius), (offset, 0, 0),
                                                                 (0, 1, 0), 40.0),
                  ray_epsilon=1e-4 * radius)
    tracer = Tracer(scene)
    n = 20000
    # origins around the spheres, on the first sphere's surface, and aimed near its rim
    o = centres[0] + radius * rng.normal(size=(n, 3)) * 3
    on = rng.random(n) < 0.3
    v = rng.normal(size=(n, 3))
    o[on] = centres[0] + radius * v[on] / np.linalg.norm(v[on], axis=1, keepdims=True)
    rim = centres[0] + radius * v / np.linalg.norm(v, axis=1, keepdims=True) * (1 + 1e-7 * rng.normal(size=(n, 1)))
    d = np.where(rng.random((n, 1)) < 0.5, rim - o, rng.normal(size=(n, 3)))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o32, d32 = o.T.astype(np.float32), d.T.astype(np.float32)
    t32, p32 = tracer.closest_soa(o32, d32)
    t64, p64 = tracer.closest_soa(o32.astype(np.float64), d32.astype(np.float64))
    assert 0.2 < np.mean(p64 >= 0) < 0.9
    np.testing.assert_array_equal(p32, p64)
    np.testing.assert_array_equal(t32, t64)
    tm = np.where(np.isfinite(t64), 0.5 * t64, 1e9 * radius)
    np.testing.assert_array_equal(tracer.occluded_soa(o32, d32, tm), tracer.occluded_soa(
        o32.astype(np.float64), d32.astype(np.float64), tm))


def test_float32_directions_reach_the_materials_as_float64_unit_vectors():
    # a float32 direction after two frame changes can be 1e-6 off unit length,
    # which Glass's refract (as_unit_directions) refuses: unit64 renormalises
    from mcvar.bsdf import Glass
    from mcvar.integrators.directions import unchecked, unit64

    rng = np.random.default_rng(5)
    v = rng.normal(size=(3, 1000))
    v /= np.sqrt((v * v).sum(axis=0))
    v = (v * (1.0 + 2e-6)).astype(np.float32)           # what a long float32 chain can leave
    with pytest.raises(ValueError, match="unit vectors"):
        Glass().sample(v.T.astype(np.float64), rng.random((1000, 2)))
    w = unit64(v)
    assert w.dtype == np.float64 and w.shape == (1000, 3)
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(w, v.T / (1.0 + 2e-6), rtol=1e-6)     # the direction kept
    wi, weight, pdf, delta = unchecked(Glass(), "sample")(w, rng.random((1000, 2)))
    assert np.all(delta) and np.all(np.isfinite(wi))


# -- caustics by light tracing ---------------------------------------------------

def test_caustics_by_light_tracing_agree_with_path_tracing():
    # caustics='light' partitions the paths: path tracing drops E D S+ L, light
    # tracing adds exactly those; the image must agree with path tracing's in
    # expectation, over the image and over the caustic under the glass sphere
    # (where the paths moved), per channel within 5 combined standard errors
    # (Sidak over 3 channels x 2 regions). Random sampler: iid standard errors.
    from scipy.stats import norm

    from mcvar.experiments.compare import CAUSTIC_REGION
    from mcvar.integrators import render
    from mcvar.testing import sidak_significance

    scene = load_scene("cornell-spheres")
    res = 16
    kw = dict(spp=1024, res=res, sampler="random")
    a = render(scene, rng=21, caustics="path", **kw)
    b = render(scene, rng=22, caustics="light", **kw)
    r0, r1, c0, c1 = (int(round(f * res)) for f in CAUSTIC_REGION)
    z = norm.isf(0.5 * sidak_significance(2 * norm.sf(5.0), 6))
    for rows, cols in ((slice(None), slice(None)), (slice(r0, r1), slice(c0, c1))):
        (ma, sa), (mb, sb) = _means_region(a, rows, cols), _means_region(b, rows, cols)
        assert np.all(np.abs(ma - mb) < z * np.hypot(sa, sb)), (rows, ma, mb, sa, sb)
    # the caustic's standard error falls: the light tracer finds those paths better
    (_, sa), (_, sb) = _means_region(a, slice(r0, r1), slice(c0, c1)), _means_region(b, slice(r0, r1), slice(c0, c1))
    assert np.all(sb < 0.8 * sa), (sa, sb)


def _means_region(r, rows, cols):
    img, var = r.image[rows, cols], r.variance[rows, cols]
    n = img.shape[0] * img.shape[1]
    return img.mean(axis=(0, 1)), np.sqrt(var.sum(axis=(0, 1)) / r.spp) / n


def test_caustics_setting_changes_nothing_where_it_does_not_apply():
    # no specular material (the Cornell box), or a point light (cornell-point):
    # path tracing keeps every path and no light path is traced: the same image
    from mcvar.integrators import render
    from mcvar.integrators.state import light_caustics_apply

    for name in ("cornell", "cornell-point"):
        scene = load_scene(name)
        assert not light_caustics_apply(scene)
        kw = dict(spp=16, res=16, sampler="sobol", rng=3, kernel="general")
        a, b = render(scene, caustics="path", **kw), render(scene, caustics="light", **kw)
        np.testing.assert_array_equal(a.image, b.image)
        assert a.rays == b.rays
    assert light_caustics_apply(load_scene("cornell-spheres"))


def test_caustic_light_paths_give_the_image_of_one_worker_on_two():
    from mcvar.adaptive import render_adaptive

    scene = load_scene("cornell-spheres")
    kw = dict(spp=64, res=32, sampler="sobol", rng=9, caustics="light")
    a, b = render_adaptive(scene, workers=1, **kw), render_adaptive(scene, workers=2, **kw)
    np.testing.assert_array_equal(a.image, b.image)
    c = render_adaptive(scene, workers=1, **{**kw, "caustics": "path"})
    assert not np.array_equal(a.image, c.image)


@pytest.mark.parametrize("name", ["cornell", "cornell-spheres", "cornell-point"])
def test_one_tracer_builds_its_scene_tables_once_and_traces_the_same_paths(name):
    """SceneTables are cached on the tracer (per light sampling): a second batch through the same
    tracer reads the first batch's tables and gives, path by path, what a fresh tracer gives."""
    from mcvar.integrators.state import SceneTables

    scene = load_scene(name)
    pixel, u = _inputs(0)
    shared = Tracer(scene)
    first, _ = trace_camera_paths(scene, RES, pixel, u, rng=1, tracer=shared)
    tables = SceneTables.of(scene, shared, "area")
    again, _ = trace_camera_paths(scene, RES, pixel, u, rng=1, tracer=shared)
    fresh, _ = trace_camera_paths(scene, RES, pixel, u, rng=1, tracer=Tracer(scene))
    assert SceneTables.of(scene, shared, "area") is tables
    assert SceneTables.of(scene, shared, "solid_angle") is not tables
    assert SceneTables.of(load_scene(name), shared, "area") is not tables     # another scene object
    np.testing.assert_array_equal(again, first)
    np.testing.assert_array_equal(fresh, first)


def test_a_pickled_tracer_leaves_its_cached_tables_behind():
    # batches carry the tracer to worker processes: the cache must not ride along
    import pickle

    from mcvar.integrators.state import SceneTables

    scene = load_scene("cornell-spheres")
    tracer = Tracer(scene)
    bare = len(pickle.dumps(tracer))
    SceneTables.of(scene, tracer, "area")
    assert "_scene_tables" in vars(tracer)
    copy = pickle.loads(pickle.dumps(tracer))
    assert "_scene_tables" not in vars(copy) and len(pickle.dumps(tracer)) == bare
    assert "_scene_tables" in vars(tracer)                 # the original keeps its cache
