"""The Mitsuba 3 exporter, element by element (deterministic checks; issue 26).

Each mapping of docs/mitsuba.md is checked by evaluating *Mitsuba's* loaded
plugin and mcvar's function for the same arguments: the camera's primary
rays, every exported BSDF's value and sampling weight, the environment map's
lookup, the checker texture; and what has no counterpart must be a
``ValueError`` naming it. The images of whole scenes are compared in
``test_mitsuba_reference.py``.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (pip install 'mcvar[mitsuba]')")

from mcvar.bsdf import Conductor, Glass, Lambertian, Microfacet, Mirror, Plastic, Refractive  # noqa: E402
from mcvar.envmap import sparse_lights  # noqa: E402
from mcvar.interop.mitsuba import (  # noqa: E402
    _envmap_bitmap,
    render_mitsuba,
    scene_fingerprint,
    to_mitsuba,
)
from mcvar.scene import load_scene  # noqa: E402


@pytest.fixture(autouse=True)
def _scalar_rgb():
    mi.set_variant("scalar_rgb")


def _directions(rng, n):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 1] = np.abs(v[:, 1]) + 0.05
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _local(v):
    """mcvar's local frame (normal +y) to Mitsuba's (normal +z)."""
    return mi.Vector3f(float(v[0]), float(v[2]), float(v[1]))


def _si(wo):
    si = mi.SurfaceInteraction3f()
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.n = mi.Vector3f(0, 0, 1)
    si.wi = _local(wo)
    return si


def _mitsuba_bsdf(material):
    scene = dataclasses.replace(load_scene("furnace"), materials=(material,), material_names=("m",),
                                prim_emission=np.zeros((1, 3)))
    d = to_mitsuba(scene, res=4, spp=1)
    return mi.load_dict(d["bsdf_0_m"])


def test_camera_rays_are_mcvar_rays():
    # non-square film: fov is horizontal in both, pixels square, row 0 at the top
    scene = load_scene("checkerboard")
    w, h = 24, 16
    sensor = mi.load_dict(to_mitsuba(scene, res=(w, h), spp=1)).sensors()[0]
    rng = np.random.default_rng(3)
    pixel, offset = rng.integers(0, w * h, 64), rng.random((64, 2))
    ours = scene.camera.ray_directions((w, h), pixel, offset)
    row, col = np.divmod(pixel, w)
    theirs = np.array([np.array(sensor.sample_ray(0.0, 0.5, mi.Point2f((c + u) / w, (r + v) / h),
                                                  mi.Point2f(0.5, 0.5))[0].d)
                       for r, c, (u, v) in zip(row, col, offset)])
    np.testing.assert_allclose(theirs, ours, atol=2e-6)


def test_diffuse_bsdf_is_two_sided_lambertian():
    rng = np.random.default_rng(1)
    wo, wi = _directions(rng, 32), _directions(rng, 32)
    albedo = (0.7, 0.3, 0.1)
    b = _mitsuba_bsdf(Lambertian(albedo))
    ctx = mi.BSDFContext()
    for o, i in zip(wo, wi):
        f = np.array(b.eval(ctx, _si(o), _local(i))) / i[1]
        np.testing.assert_allclose(f, np.array(albedo) / np.pi, rtol=1e-5)
        back = _si(o * [1, -1, 1])           # seen from below: mcvar flips the normal, twosided does too
        f = np.array(b.eval(ctx, back, _local(i * [1, -1, 1]))) / i[1]
        np.testing.assert_allclose(f, np.array(albedo) / np.pi, rtol=1e-5)


@pytest.mark.parametrize("material", [Mirror((0.9, 0.5, 0.2)), Conductor.preset("copper"), Conductor.preset("gold")],
                         ids=["mirror", "copper", "gold"])
def test_specular_reflection_weights_are_mcvar_weights(material):
    rng = np.random.default_rng(2)
    wo = _directions(rng, 24)
    b = _mitsuba_bsdf(material)
    ctx = mi.BSDFContext()
    wi_ours, weight_ours, _ = material.sample(wo, rng.random((24, 2)))
    for o, wi, w in zip(wo, wi_ours, weight_ours):
        bs, weight = b.sample(ctx, _si(o), 0.5, mi.Point2f(0.5, 0.5))
        np.testing.assert_allclose(np.array(bs.wo)[[0, 2, 1]], wi, atol=1e-6)
        np.testing.assert_allclose(np.array(weight), w, rtol=2e-5)


def test_glass_chooses_reflection_with_mcvars_fresnel():
    glass = Glass(1.5)
    b = _mitsuba_bsdf(glass)
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(4)
    wo = _directions(rng, 16)
    wo[8:, 1] *= -1                                      # inside the glass: wo below the surface
    f = glass.reflectance_probability(wo[:, 1])
    for o, fr in zip(wo, f):
        for u, want_reflect in ((fr * 0.999, True), (min(fr * 1.001 + 1e-6, 0.999999), fr >= 1.0)):
            bs, _ = b.sample(ctx, _si(o), float(u), mi.Point2f(0.5, 0.5))
            reflected = np.sign(float(bs.wo[2])) == np.sign(o[1])
            assert reflected == want_reflect, (o, fr, u)


@pytest.mark.parametrize("material,name", [
    (Conductor.preset("copper", alpha_x=0.3), "rough Conductor"),
    (Microfacet(0.3), "Microfacet"),
    (Plastic(0.5), "Plastic"),
    (Plastic(0.5, alpha=0.2), "Plastic"),
    (Glass(1.5, fresnel="schlick"), "schlick"),
    (Refractive(1.5), "Refractive"),
])
def test_models_without_a_mitsuba_counterpart_are_refused(material, name):
    scene = dataclasses.replace(load_scene("furnace"), materials=(material,), material_names=("m",))
    with pytest.raises(ValueError, match=name):
        to_mitsuba(scene, res=4, spp=1)


def test_the_refused_models_really_differ_in_mitsuba():
    # the reasons given above, measured: rough conductor (separable Smith masking) and plastic
    rng = np.random.default_rng(5)
    wo, wi = _directions(rng, 32), _directions(rng, 32)
    ctx = mi.BSDFContext()
    cu = Conductor.preset("copper", alpha_x=0.5)
    rough = mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": 0.5,
                          "eta": {"type": "rgb", "value": cu.eta.tolist()},
                          "k": {"type": "rgb", "value": cu.k.tolist()}})
    ratio = [float(np.array(rough.eval(ctx, _si(o), _local(i)))[0] / i[1] / cu.eval(o[None], i[None])[0, 0])
             for o, i in zip(wo, wi)]
    assert max(abs(np.array(ratio) - 1)) > 0.05
    # ... and the difference is exactly the masking: alpha, D and the Fresnel term are the same
    from mcvar.bsdf import _smith_lambda

    lo, li = _smith_lambda(wo, 0.5, 0.5, "ggx"), _smith_lambda(wi, 0.5, 0.5, "ggx")
    np.testing.assert_allclose(ratio, (1 + lo + li) / ((1 + lo) * (1 + li)), rtol=1e-4)
    pl = mi.load_dict({"type": "plastic", "diffuse_reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]},
                       "int_ior": 1.5, "ext_ior": 1.0})
    ours = Plastic(0.5).eval(wo[:1], wi[:1])[0, 0]
    assert abs(float(np.array(pl.eval(ctx, _si(wo[0]), _local(wi[0])))[0]) / wi[0, 1] / ours - 1) > 0.05


def test_envmap_lookup_is_mcvars_away_from_pixel_edges():
    env = sparse_lights(height=32, width=64, background=0.05)
    scene = dataclasses.replace(load_scene("quad-environment"), environment=env)
    d = to_mitsuba(scene, res=4, spp=1)
    em = mi.load_dict(d["environment"])
    rng = np.random.default_rng(6)
    v = rng.normal(size=(4000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    theta = np.arccos(np.clip(v[:, 1], -1, 1))
    phi = np.mod(np.arctan2(v[:, 2], v[:, 0]), 2 * np.pi)
    # farther than one fine texel from any mcvar pixel edge: no blending there
    fu, fv = phi / (2 * np.pi) * env.width, theta / np.pi * env.height
    far = (np.abs(fu - np.round(fu)) > 0.3) & (np.abs(fv - np.round(fv)) > 0.3)
    ours = env.radiance(v[far])
    theirs = []
    for x in v[far]:
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*(-x))
        theirs.append(np.array(em.eval(si)))
    np.testing.assert_allclose(np.array(theirs), ours, rtol=1e-5, atol=1e-7)
    assert np.any(ours[:, 0] > 1.0), "the test must see some of the bright lights"


def test_envmap_resampling_keeps_each_row_and_column_integral():
    env = sparse_lights(height=16, width=32)
    fine = _envmap_bitmap(env).astype(np.float64)
    k = fine.shape[1] // env.width
    assert fine.shape[0] == k * env.height + 1
    # columns: the fine texels of column j are mcvar's column j
    np.testing.assert_array_equal(fine[1:k, ::k], np.broadcast_to(env.image[0].astype(np.float32), (k - 1, env.width, 3)))
    # rows: hat functions at v = i / (H' - 1) of cell means integrate to mcvar's row means
    hat = np.full(fine.shape[0], 1.0)
    hat[[0, -1]] = 0.5
    np.testing.assert_allclose((hat[:, None, None] * fine).sum(axis=0) / (fine.shape[0] - 1),
                               np.repeat(env.image.mean(axis=0), k, axis=0), rtol=1e-6)


def test_checker_texture_is_mcvars_pattern():
    scene = load_scene("checkerboard", period=0.5)
    d = to_mitsuba(scene, res=4, spp=1)
    tex = mi.load_dict(d["mesh0_black"]["emitter"]["radiance"])
    rng = np.random.default_rng(7)
    x, z = rng.uniform(-5, 5, (2, 200))
    ours = (np.floor(x / 0.5) + np.floor(z / 0.5)) % 2
    for a, b, want in zip(x, z, ours):
        si = mi.SurfaceInteraction3f()
        si.uv = mi.Point2f(a / 1.0, b / 1.0)             # (x, z) / (2 period)
        assert float(np.array(tex.eval(si))[0]) == want


def test_two_sided_emission_seen_from_both_sides_is_refused():
    scene = load_scene("checkerboard")
    pos = np.array([0.0, -2.0, 0.0])                    # a point light under the plane: both sides matter
    under = dataclasses.replace(scene, point_light_position=pos[None], point_light_intensity=np.ones((1, 3)))
    with pytest.raises(ValueError, match="two-sided emission"):
        to_mitsuba(under, res=4, spp=1)
    inside = dataclasses.replace(load_scene("furnace"), point_light_position=np.array([[0.0, 0.0, 5.0]]),
                                 point_light_intensity=np.ones((1, 3)))
    with pytest.raises(ValueError, match="two-sided emission on sphere"):
        to_mitsuba(inside, res=4, spp=1)


def test_a_light_without_primitives_is_refused():
    scene = load_scene("cornell")
    tri = scene.prim_light >= 0
    dark = dataclasses.replace(scene, prim_light=np.where(tri, -1, scene.prim_light))
    with pytest.raises(ValueError, match="parallelogram light 0 has no primitives"):
        to_mitsuba(dark, res=4, spp=1)


@pytest.mark.parametrize("kwargs,match", [
    (dict(res=0, spp=1), "res"), (dict(res=4, spp=0), "spp"), (dict(res=4, spp=1, integrator="bdpt"), "integrator"),
    (dict(res=4, spp=1, max_depth=0), "max_depth"), (dict(res=4, spp=1, integrator="direct", max_depth=3), "direct"),
])
def test_bad_arguments_are_named(kwargs, match):
    with pytest.raises((ValueError, TypeError), match=match):
        to_mitsuba(load_scene("cornell"), **kwargs)
    with pytest.raises(TypeError, match="scene"):
        to_mitsuba("cornell", res=4, spp=1)


def test_render_mitsuba_checks_its_variant_and_is_seeded():
    scene = load_scene("cornell")
    with pytest.raises(ValueError, match="variant"):
        render_mitsuba(scene, res=4, spp=1, variant="scalar_spectral")
    a = render_mitsuba(scene, res=8, spp=4, rng=1)
    b = render_mitsuba(scene, res=8, spp=4, rng=1)
    c = render_mitsuba(scene, res=8, spp=4, rng=2)
    assert a.shape == (8, 8, 3) and a.dtype == np.float64
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_fingerprint_changes_with_the_scene():
    scene = load_scene("cornell")
    a = scene_fingerprint(scene, res=16, spp=4)
    assert a == scene_fingerprint(load_scene("cornell"), res=16, spp=4)
    brighter = dataclasses.replace(scene, prim_emission=scene.prim_emission * 2,
                                   light_radiance=scene.light_radiance * 2)
    assert scene_fingerprint(brighter, res=16, spp=4) != a
    assert scene_fingerprint(scene, res=16, spp=4, max_depth=2) != a


def _lit_centroid(image):
    """(row, column) centroid of the light reflected by the sphere (background subtracted)."""
    w = np.clip(image.mean(axis=2) - 0.0101, 0.0, None)
    rows, cols = np.indices(w.shape)
    return np.array([(w * rows).sum(), (w * cols).sum()]) / w.sum()


def test_sparse_environment_lights_the_same_side_in_both_engines():
    # the orientation of the map (+y up, u = 0 at +x, row 0 at the top) rendered by both
    # engines: a white sphere under mcvar's sparse lights, its lit side's centroid
    import importlib.util
    from pathlib import Path

    from mcvar.envmap import EnvironmentMap
    from mcvar.integrators import render

    spec = importlib.util.spec_from_file_location(
        "mitsuba_references", Path(__file__).resolve().parents[1] / "benchmarks" / "mitsuba_references.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    # one light, up, to the +x side and towards the camera: its lit side is unambiguous
    one = sparse_lights(directions=[(0.7, 0.4, -0.6)], height=64, width=128)
    scene = dataclasses.replace(bench.build_scene("sphere-sparse-env"), environment=one)
    ours = render(scene, res=32, spp=64, rng=1).image
    theirs = render_mitsuba(scene, res=32, spp=64, rng=2)
    c_ours, c_theirs = _lit_centroid(ours), _lit_centroid(theirs)
    assert np.linalg.norm(c_ours - c_theirs) < 0.5, (c_ours, c_theirs)
    # the test's power: the map turned by 90 degrees about +y moves the lit side by pixels
    # (and +x is image left: the lit side is on the left half)
    assert c_theirs[1] < 15.5, c_theirs
    img = np.asarray(scene.environment.image)
    turned = dataclasses.replace(scene, environment=EnvironmentMap(np.roll(img, img.shape[1] // 4, axis=1)))
    c_turned = _lit_centroid(render(turned, res=32, spp=64, rng=1).image)
    assert np.linalg.norm(c_turned - c_theirs) > 2.0, (c_turned, c_theirs)
