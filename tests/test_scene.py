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
