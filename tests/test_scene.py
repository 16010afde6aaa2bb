"""Scenes: the Cornell box exactly as the shared specification, the camera
formula of CORNELL.md, the analytic test scenes, and bad input."""
import json
import math
from pathlib import Path

import numpy as np
import pytest

from mcvar.scene import (
    CORNELL_ALBEDO,
    CORNELL_CAMERA,
    CORNELL_LIGHT_RADIANCE,
    CORNELL_QUADS,
    SCENES,
    Camera,
    load_scene,
)

SPEC = Path(__file__).resolve().parents[2] / "shared" / "scenes" / "cornell.json"


@pytest.fixture(scope="module")
def spec():
    if not SPEC.exists():
        pytest.skip(f"{SPEC} not present (the package's constants are the copy)")
    return json.loads(SPEC.read_text())


def test_cornell_constants_equal_the_shared_json(spec):
    assert [q["name"] for q in spec["quads"]] == [name for name, _, _ in CORNELL_QUADS]
    for q, (name, material, verts) in zip(spec["quads"], CORNELL_QUADS):
        assert q["material"] == material, name
        np.testing.assert_array_equal(np.array(q["vertices"]), np.array(verts), err_msg=name)
        assert q["triangles"] == [[0, 1, 2], [0, 2, 3]], name
    assert {k: tuple(v) for k, v in spec["albedo_rgb"].items()} == dict(CORNELL_ALBEDO)
    assert tuple(spec["emitter"]["radiance_rgb"]) == CORNELL_LIGHT_RADIANCE
    assert spec["emitter"]["one_sided"] is True
    cam = spec["camera"]
    assert tuple(cam["origin"]) == CORNELL_CAMERA[0]
    assert tuple(cam["target"]) == CORNELL_CAMERA[1]
    assert tuple(cam["up"]) == CORNELL_CAMERA[2]
    assert CORNELL_CAMERA[3] == pytest.approx(cam["fov_deg"], rel=1e-14)


def test_cornell_scene_arrays_follow_the_triangulation(spec):
    scene = load_scene("cornell")
    assert scene.n_triangles == 32 and scene.n_spheres == 0 and scene.n_lights == 1
    expected = []
    for q in spec["quads"]:
        v = np.array(q["vertices"])
        expected += [v[[0, 1, 2]], v[[0, 2, 3]]]
    np.testing.assert_array_equal(scene.triangles, np.array(expected))
    albedo = {k: np.array(v) for k, v in spec["albedo_rgb"].items()}
    for t, q in enumerate(np.repeat([q["material"] for q in spec["quads"]], 2)):
        mat = scene.materials[scene.prim_material[t]]
        np.testing.assert_array_equal(mat.albedo, albedo[q])
    # the emitting triangles are exactly the light quad's, one-sided, radiance (17, 12, 4)
    light_rows = np.flatnonzero(np.any(scene.prim_emission > 0, axis=1))
    assert light_rows.tolist() == [30, 31]
    np.testing.assert_array_equal(scene.prim_emission[light_rows], [CORNELL_LIGHT_RADIANCE] * 2)
    assert not scene.prim_two_sided_emission.any()
    np.testing.assert_array_equal(scene.prim_light[light_rows], [0, 0])


def test_cornell_light_is_the_light_quad_as_a_parallelogram(spec):
    scene = load_scene("cornell")
    v = np.array(spec["quads"][-1]["vertices"])
    o, e1, e2 = scene.light_origin[0], scene.light_edge1[0], scene.light_edge2[0]
    np.testing.assert_array_equal(o, v[0])
    np.testing.assert_array_equal(o + e1, v[1])
    np.testing.assert_array_equal(o + e1 + e2, v[2])     # a parallelogram, exactly
    np.testing.assert_array_equal(o + e2, v[3])
    assert scene.light_area[0] == 130.0 * 105.0
    np.testing.assert_array_equal(scene.light_normal[0], spec["emitter"]["normal"])


def _spec_direction(res, j, i, u, v):
    """CORNELL.md's primary-ray formula, written out independently."""
    w, h = res
    x, y = (j + u) / w, (i + v) / h
    t = math.tan(math.radians(2.0 * math.degrees(math.atan(12.5 / 35.0))) / 2.0)
    d = np.array([0.0, 0.0, 1.0]) + (2 * x - 1) * t * np.array([-1.0, 0, 0]) + (1 - 2 * y) * t * np.array([0, 1.0, 0])
    return d / np.linalg.norm(d)


def test_camera_matches_the_specified_formula():
    cam = load_scene("cornell").camera
    rng = np.random.default_rng(20241101)
    res = (16, 16)
    pix = rng.integers(0, 256, 50)
    uv = rng.random((50, 2))
    uv[0] = (0.0, 0.0)
    uv[1] = (1.0, 1.0)
    got = cam.ray_directions(res, pix, uv)
    want = np.array([_spec_direction(res, p % 16, p // 16, a, b) for p, (a, b) in zip(pix, uv)])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-14)


def test_camera_orientation_red_wall_left_row0_top():
    cam = load_scene("cornell").camera
    d = cam.ray_directions((4, 4), np.array([0, 15]), np.array([[0.5, 0.5], [0.5, 0.5]]))
    assert d[0, 0] > 0 and d[0, 1] > 0     # top-left pixel looks to +x (red wall) and up
    assert d[1, 0] < 0 and d[1, 1] < 0     # bottom-right: -x (green wall) and down
    # the corner ray of the image makes half the field of view with the axis
    c = cam.ray_directions((1, 1), np.array([0]), np.array([[0.0, 0.5]]))[0]
    assert math.degrees(math.acos(c[2])) == pytest.approx(cam.fov_deg / 2, rel=1e-12)


def test_non_square_images_keep_square_pixels():
    cam = load_scene("cornell").camera
    d = cam.ray_directions((8, 4), np.array([0, 31]), np.array([[0.0, 0.0], [1.0, 1.0]]))
    slope_x = -d[:, 0] / d[:, 2]
    slope_y = d[:, 1] / d[:, 2]
    np.testing.assert_allclose(np.abs(slope_x) / np.abs(slope_y), 2.0, rtol=1e-12)


def test_scenes_are_fresh_read_only_data():
    a, b = load_scene("cornell"), load_scene("cornell")
    assert a.triangles is not b.triangles
    with pytest.raises(ValueError):
        a.triangles[0, 0, 0] = 1.0
    with pytest.raises(AttributeError):
        a.name = "other"


@pytest.mark.parametrize("name", sorted(SCENES))
def test_every_scene_loads(name):
    if name == "quad-environment":
        pytest.importorskip("mcvar.envmap")
    scene = load_scene(name)
    assert scene.name == name
    assert scene.prim_material.shape == (scene.n_triangles + scene.n_spheres,)


def test_cornell_spheres_has_a_mirror_and_a_glass_sphere():
    from mcvar.bsdf import Glass, Mirror

    scene = load_scene("cornell-spheres")
    assert scene.n_spheres == 2 and scene.n_triangles == 12
    kinds = {type(scene.materials[m]) for m in scene.prim_material[scene.n_triangles:]}
    assert kinds == {Mirror, Glass}
    # both spheres rest on the floor, inside the room
    np.testing.assert_array_equal(scene.sphere_centers[:, 1] - scene.sphere_radii, 0.0)


def test_furnace_rejects_albedo_one():
    with pytest.raises(ValueError, match="albedo must be < 1"):
        load_scene("furnace", albedo=1.0)


def test_unknown_scene_lists_the_names():
    with pytest.raises(ValueError, match="unknown scene 'box'.*cornell.*cornell-spheres.*checkerboard"):
        load_scene("box")
    with pytest.raises(TypeError, match="name must be a string"):
        load_scene(3)


def test_camera_rejects_bad_values():
    with pytest.raises(ValueError, match="fov_deg must lie in"):
        Camera((0, 0, 0), (0, 0, 1), (0, 1, 0), 180.0)
    with pytest.raises(ValueError, match="look_at must differ"):
        Camera((0, 0, 0), (0, 0, 0), (0, 1, 0), 40.0)
    with pytest.raises(ValueError, match="up must not be parallel"):
        Camera((0, 0, 0), (0, 1, 0), (0, 1, 0), 40.0)


def test_scene_rejects_inconsistent_tables():
    import dataclasses

    scene = load_scene("cornell")
    with pytest.raises(ValueError, match="prim_emission must be non-negative"):
        dataclasses.replace(scene, prim_emission=-np.ones((32, 3)))
    with pytest.raises(ValueError, match="prim_material must have one row per primitive"):
        dataclasses.replace(scene, prim_material=np.zeros(3, dtype=int))
    with pytest.raises(ValueError, match="prim_material must index into materials"):
        dataclasses.replace(scene, prim_material=np.full(32, 9))


# ---------------------------------------------------------------------------
# The pinhole as a sensor (issue 11): project, We, pdf_We, sample_Wi

@pytest.mark.parametrize("res", [(16, 16), (12, 7)])
def test_project_returns_the_pixel_sample_of_a_camera_ray(res):
    cam = load_scene("cornell").camera
    rng = np.random.default_rng(11)
    w, h = res
    pix = rng.integers(0, w * h, 2000)
    uv = rng.random((2000, 2))
    d = cam.ray_directions(res, pix, uv)
    points = cam.position + d * rng.uniform(1.0, 2000.0, (2000, 1))
    xy, visible = cam.project(points, res)
    assert visible.all()
    np.testing.assert_allclose(xy, np.stack([pix % w + uv[:, 0], pix // w + uv[:, 1]], -1), rtol=0, atol=1e-9)
    np.testing.assert_array_equal(cam.pixel_index(xy, res), pix)


def test_project_rejects_points_behind_or_outside_the_frame():
    cam = load_scene("cornell").camera
    forward, right, up = cam.basis()
    t = math.tan(math.radians(cam.fov_deg) / 2)
    pts = cam.position + np.array([forward * 10, -forward * 10, forward + 1.01 * t * right,
                                   forward - 0.99 * t * up, forward + 1.01 * t * up])
    _, visible = cam.project(pts, (8, 8))
    assert visible.tolist() == [True, False, False, True, False]
    with pytest.raises(ValueError, match="points"):
        cam.project(np.zeros((3, 2)), (8, 8))
    with pytest.raises(ValueError, match="res"):
        cam.We(np.tile(forward, (2, 1)), (0, 8))


@pytest.mark.parametrize("res", [(16, 16), (10, 6)])
def test_we_and_pdf_we_integrate_to_one_over_the_sphere(res):
    """int We cos d omega = 1 and int pdf_dir d omega = 1, by uniform sphere
    sampling (5 standard errors); the film fraction of the sphere is small, so
    many samples, still < 0.1 s."""
    from mcvar.warps import square_to_uniform_sphere

    cam = Camera((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 1.0, 0.0), 70.0)
    rng = np.random.default_rng(5)
    d = square_to_uniform_sphere(rng.random((400_000, 2)))
    forward = cam.basis()[0]
    cos = d @ forward
    for g in (cam.We(d, res) * cos * 4 * np.pi, cam.pdf_We(d, res)[1] * 4 * np.pi):
        se = g.std(ddof=1) / math.sqrt(g.size)
        assert abs(g.mean() - 1.0) < 5 * se, (g.mean(), se)
    pos, pdf_dir = cam.pdf_We(d[:5], res)
    np.testing.assert_array_equal(pos, 1.0)
    # pbrt's relation between the two: We cos = pdf_dir inside the frame
    inside = cam.We(d, res) > 0
    np.testing.assert_allclose(cam.We(d, res)[inside] * cos[inside], cam.pdf_We(d, res)[1][inside], rtol=1e-12)


def test_light_tracing_an_emitting_plane_gives_its_radiance_per_pixel():
    """Particle tracing by hand with sample_Wi: points uniform on an emitting
    Lambertian quad that fills the view, each splatting Le A cos We / pdf at
    its projected pixel; with N = W H spp particles, image = sum / spp must be
    Le in every pixel (5 SE per pixel, Sidak over the pixels)."""
    from scipy.stats import norm

    cam = Camera((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 1.0, 0.0), 60.0)
    res, spp, le = (6, 4), 4000, 2.5
    w, h = res
    n = w * h * spp
    rng = np.random.default_rng(3)
    half = 3.0                                                       # plane z = 2, [-3, 3]^2
    p = np.column_stack([rng.uniform(-half, half, n), rng.uniform(-half, half, n), np.full(n, 2.0)])
    area = (2 * half) ** 2
    wi, dist, we, pdf, xy, visible = cam.sample_Wi(p, res)
    cos_e = np.abs(wi[:, 2])                                       # plane normal -z faces the camera
    with np.errstate(divide="ignore", invalid="ignore"):
        contrib = np.where(visible, le * area * cos_e * we / pdf, 0.0)
    pix = cam.pixel_index(xy, res)
    img = np.bincount(pix[visible], contrib[visible], minlength=w * h) / spp
    sq = np.bincount(pix[visible], contrib[visible] ** 2, minlength=w * h)
    # per pixel: img = (1/spp) sum_all X_k, X_k = contrib * [in pixel]; var of the sum from E[X^2]
    se = np.sqrt(np.maximum(sq / n - (img * spp / n) ** 2, 0) * n) / spp
    z = norm.isf(0.5 * (1 - (1 - 2 * norm.sf(5)) ** (1 / (w * h))))
    assert np.all(np.abs(img - le) < z * se), (img, se)


def test_cornell_point_has_the_area_lights_power_at_its_centre():
    area, point = load_scene("cornell"), load_scene("cornell-point")
    assert point.n_lights == 0 and point.n_point_lights == 1
    assert not np.any(point.prim_emission)
    assert point.n_triangles == area.n_triangles - 2                 # the light quad is gone
    phi_area = np.pi * area.light_radiance[0] * area.light_area[0]   # one-sided Lambertian
    np.testing.assert_allclose(4 * np.pi * point.point_light_intensity[0], phi_area, rtol=1e-12)
    centre = area.light_origin[0] + 0.5 * (area.light_edge1[0] + area.light_edge2[0])
    np.testing.assert_allclose(point.point_light_position[0], [centre[0], 547.8, centre[2]], rtol=1e-12)


def test_scene_rejects_bad_point_lights():
    base = load_scene("furnace")
    kw = {k: getattr(base, k) for k in base.__dataclass_fields__}
    with pytest.raises(ValueError, match="point_light_position and point_light_intensity"):
        type(base)(**{**kw, "point_light_position": np.zeros((2, 3)), "point_light_intensity": np.ones((1, 3))})
    with pytest.raises(ValueError, match="non-negative"):
        type(base)(**{**kw, "point_light_position": np.zeros((1, 3)), "point_light_intensity": -np.ones((1, 3))})
