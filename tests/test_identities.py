"""Identities between functions that compute one quantity (issues 24 and 26).

Deterministic checks, exact or to rounding: the importance the camera hands
to a light-path connection is the camera's ``We`` of the same ray; the pdf
every light sampler returns is that light's ``pdf_*`` of the same point or
direction; ``pdf_le`` of what ``sample_le`` produced is the pdf it
reported; the camera's direction density is the Jacobian of its ray map. A
bug planted in either side of one of these breaks an equality, where a
statistical comparison would need many standard errors to see it (issue 24:
``sample_Wi`` with ``cos^3`` instead of ``cos^4`` passed every image test).
"""
import dataclasses

import numpy as np
import pytest

from mcvar.bsdf import Lambertian
from mcvar.envmap import constant, sky_with_sun
from mcvar.integrators import Emitters, LightOrigins, pdf_le, sample_le
from mcvar.scene import Camera, Scene, load_scene

SEED = 26_2026
RES = (16, 12)          # not square: the vertical film extent is H / W of the horizontal one


def _quad(o, e1, e2):
    o, e1, e2 = (np.asarray(v, float) for v in (o, e1, e2))
    return [np.array([o, o + e1, o + e1 + e2]), np.array([o, o + e1 + e2, o + e2])]


def mixed_emitters_scene(environment=None):
    """Every kind of emitter at once: two parallelogram lights (one tilted), an
    emitting sphere that NEE does not sample, a two-sided emitting triangle
    pair, a point light and (optionally) an environment map, over a floor."""
    lights = [((-0.5, 1.0, -0.5), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (4.0, 3.0, 2.0)),   # faces down
              ((1.5, 0.2, -0.5), (0.0, 0.0, 1.0), (0.3, 0.8, 0.0), (1.0, 2.0, 5.0))]    # tilted, faces -x
    tris = _quad((-2.0, 0.0, -2.0), (0.0, 0.0, 4.0), (4.0, 0.0, 0.0))                    # floor, normal +y
    prim_light, emission, two = [-1, -1], [(0, 0, 0)] * 2, [False, False]
    for k, (o, e1, e2, le) in enumerate(lights):
        tris += _quad(o, e1, e2)
        prim_light += [k, k]
        emission += [le, le]
        two += [False, False]
    tris += _quad((-1.5, 0.3, 1.0), (0.4, 0.0, 0.0), (0.0, 0.4, 0.0))                   # two-sided panel
    prim_light += [-1, -1]
    emission += [(0.5, 0.5, 0.5)] * 2
    two += [True, True]
    n = len(tris) + 1
    return Scene(
        name="mixed-emitters", triangles=np.array(tris), sphere_centers=[(-0.8, 0.4, -0.8)],
        sphere_radii=[0.15], prim_material=[0] * n, prim_emission=emission + [(2.0, 1.0, 1.0)],
        prim_two_sided_emission=two + [False], prim_light=prim_light + [-1], prim_group=[0] * n,
        materials=(Lambertian(0.5),), material_names=("diffuse",),
        light_origin=[lt[0] for lt in lights], light_edge1=[lt[1] for lt in lights],
        light_edge2=[lt[2] for lt in lights], light_radiance=[lt[3] for lt in lights],
        camera=Camera((0.0, 1.5, -3.0), (0.0, 0.2, 0.0), (0.0, 1.0, 0.0), 50.0),
        point_light_position=[(0.3, 1.4, 0.6)], point_light_intensity=[(2.0, 2.0, 1.0)],
        environment=environment, ray_epsilon=1e-5)


def _points(rng, n):
    """Shading points above the floor, around the lights."""
    return np.column_stack([rng.uniform(-1.8, 1.4, n), rng.uniform(0.01, 0.9, n), rng.uniform(-1.8, 1.8, n)])


# ---------------------------------------------------------------------------
# The pinhole

@pytest.mark.parametrize("name", ["cornell", "cornell-point", "quad-environment"])
def test_sample_wi_importance_is_we_of_the_same_ray(name):
    """``Camera.sample_Wi``'s importance equals ``Camera.We`` of the ray from
    the pinhole to the point, its pixel is ``project``'s, and its pdf is the
    position delta converted to solid angle, ``r^2 / cos theta_camera``
    (issue 24's planted ``cos^3`` fails the first equality by cos theta)."""
    scene = load_scene(name)
    cam = scene.camera
    rng = np.random.default_rng(SEED)
    lo, hi = scene.triangles.reshape(-1, 3).min(axis=0), scene.triangles.reshape(-1, 3).max(axis=0)
    pts = lo + (hi - lo) * rng.random((4000, 3))
    wi, dist, we, pdf, xy, visible = cam.sample_Wi(pts, RES)
    assert 0.2 < visible.mean() < 1.0                   # points inside and outside the frame
    np.testing.assert_allclose(we, cam.We(-wi, RES), rtol=1e-12, atol=0.0)
    np.testing.assert_array_equal(we > 0, visible)
    np.testing.assert_allclose(dist, np.linalg.norm(pts - cam.position, axis=1), rtol=1e-12)
    np.testing.assert_allclose(cam.position - pts, wi * dist[:, None], rtol=1e-9, atol=1e-9)
    proj_xy, proj_vis = cam.project(pts, RES)
    np.testing.assert_array_equal(proj_vis, visible)
    np.testing.assert_allclose(xy[visible], proj_xy[visible], rtol=1e-12, atol=1e-9)
    cos_cam = -wi @ cam.basis()[0]
    np.testing.assert_allclose(pdf[visible], (dist ** 2 / cos_cam)[visible], rtol=1e-12)


def test_we_times_cos_is_the_direction_density_of_camera_rays():
    """``We cos theta = pdf_We``: both are the film's uniform density, one per
    unit projected solid angle and one per unit solid angle (0 outside the frame)."""
    cam = load_scene("cornell").camera
    rng = np.random.default_rng(SEED)
    d = rng.normal(size=(5000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[:2500] = 0.3 * d[:2500] + cam.basis()[0]                  # half of them near the view axis
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    cos = d @ cam.basis()[0]
    pos, pdf_dir = cam.pdf_We(d, RES)
    we = cam.We(d, RES)
    assert 0.2 < (we > 0).mean() < 0.8
    np.testing.assert_array_equal(pos, 1.0)
    np.testing.assert_allclose(we * np.where(we > 0, cos, 0.0), pdf_dir, rtol=1e-12, atol=0.0)


def test_pdf_we_is_the_jacobian_density_of_the_ray_map():
    """A pixel uniform among ``W H`` and an offset uniform in it: the
    direction density is ``1 / (W H |dd/du x dd/dv|)`` (the solid angle one
    unit square of offsets maps to), by central differences of
    ``ray_directions``, to the differences' truncation error."""
    cam = load_scene("cornell").camera
    rng = np.random.default_rng(SEED)
    w, h = RES
    n = 2000
    pixel = rng.integers(0, w * h, n)
    uv = 0.05 + 0.9 * rng.random((n, 2))
    eps = 1e-5
    du = (cam.ray_directions(RES, pixel, uv + [eps, 0]) - cam.ray_directions(RES, pixel, uv - [eps, 0])) / (2 * eps)
    dv = (cam.ray_directions(RES, pixel, uv + [0, eps]) - cam.ray_directions(RES, pixel, uv - [0, eps])) / (2 * eps)
    want = 1.0 / (w * h * np.linalg.norm(np.cross(du, dv), axis=1))
    _, got = cam.pdf_We(cam.ray_directions(RES, pixel, uv), RES)
    np.testing.assert_allclose(got, want, rtol=1e-6)


# ---------------------------------------------------------------------------
# Next-event estimation: sample_li against pdf_li / environment_pdf

@pytest.mark.parametrize("mode", ["area", "solid_angle"])
def test_sample_li_pdf_is_the_pdf_of_the_same_light_point(mode):
    """Every emitter kind NEE samples, one scene: a parallelogram light's pdf
    is ``pdf_li`` of the point it drew (seen from the same shading point), the
    environment's ``environment_pdf`` of the direction, a point light's its
    selection probability with ``le = I / r^2`` and the direction pointing at it."""
    scene = mixed_emitters_scene(sky_with_sun())
    em = Emitters(scene, mode)
    assert em.n_emitters == 4
    rng = np.random.default_rng(SEED)
    n = 8000
    p = _points(rng, n)
    w, dist, le, pdf, light = em.sample_li(np.ascontiguousarray(p.T), rng.random((2, n)), rng.random(n))
    w, le = w.T, le.T
    assert set(np.unique(light)) == {-2, -1, 0, 1}
    for k in (0, 1):
        sel = np.flatnonzero((light == k) & (pdf > 0))
        assert sel.size > 500
        prim = np.full(sel.size, int(np.flatnonzero(scene.prim_light == k)[0]))
        x = p[sel] + w[sel] * dist[sel, None]
        np.testing.assert_allclose(pdf[sel], em.pdf_li(prim, p[sel], x), rtol=1e-9)
        np.testing.assert_allclose(le[sel], np.broadcast_to(scene.light_radiance[k], (sel.size, 3)))
    env = np.flatnonzero(light == -1)
    np.testing.assert_allclose(pdf[env], em.environment_pdf(w[env]), rtol=1e-12)
    np.testing.assert_allclose(le[env], scene.environment.radiance(w[env]), rtol=1e-12)
    pt = np.flatnonzero(light == -2)
    np.testing.assert_allclose(pdf[pt], em.select_pdf, rtol=0)
    np.testing.assert_allclose(p[pt] + w[pt] * dist[pt, None], np.broadcast_to(scene.point_light_position[0],
                                                                                (pt.size, 3)), atol=1e-12)
    r2 = ((scene.point_light_position[0] - p[pt]) ** 2).sum(axis=1)
    np.testing.assert_allclose(le[pt], scene.point_light_intensity[0] / r2[:, None], rtol=1e-12)


# ---------------------------------------------------------------------------
# Light subpaths and photons: sample_le against pdf_le and LightOrigins

def _scenes_for_sample_le():
    return [load_scene("cornell"), load_scene("cornell-point"), load_scene("furnace"),
            mixed_emitters_scene(), mixed_emitters_scene(sky_with_sun()), load_scene("quad-environment")]


@pytest.mark.parametrize("scene", _scenes_for_sample_le(), ids=lambda s: f"{s.name}-env{s.environment is not None}")
def test_pdf_le_of_sample_le_is_the_pdf_it_returned(scene):
    """``pdf_le(light, point, direction)`` of every origin ``sample_le`` drew
    equals the ``(pdf_pos, pdf_dir)`` it reported, for every emitter kind
    (triangles one- and two-sided, spheres, point lights, the environment's
    disk), and ``LightOrigins``' per-origin densities agree with both."""
    rng = np.random.default_rng(SEED)
    n = 6000
    p, w, nrm, le, pdf_pos, pdf_dir, light = sample_le(scene, rng.random((n, 2)), rng.random((n, 2)))
    assert np.all(pdf_pos > 0) and np.all(pdf_dir > 0) and np.all(le >= 0)
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, rtol=1e-12)
    got_pos, got_dir = pdf_le(scene, light, p, w)
    np.testing.assert_allclose(got_pos, pdf_pos, rtol=1e-12)
    np.testing.assert_allclose(got_dir, pdf_dir, rtol=1e-9)
    origins = LightOrigins(scene)
    area = light >= 0
    np.testing.assert_allclose(origins.pdf_pos(light[area]), pdf_pos[area], rtol=1e-12)
    np.testing.assert_allclose(origins.pdf_dir(light[area], p[area], w[area]), pdf_dir[area], rtol=1e-9)
    np.testing.assert_allclose(origins.emission(light[area], p[area], w[area]), le[area], rtol=1e-12)


@pytest.mark.parametrize("scene", [mixed_emitters_scene(), mixed_emitters_scene(constant(0.7)),
                                   load_scene("quad-environment")], ids=lambda s: s.name)
def test_one_origin_estimates_the_total_power_exactly(scene):
    """``le cos / (pdf_pos pdf_dir)`` is the total emitted power divided by the
    chosen emitter's share of it, so its mean over origins is the power; for
    Lambertian emitters, point lights and a constant environment every single
    sample equals ``Phi_k / p_k`` (pbrt-v4 12.5). Checked per emitter kind:
    the sample's value times its choice probability is that emitter's power."""
    rng = np.random.default_rng(SEED)
    n = 4000
    p, w, nrm, le, pdf_pos, pdf_dir, light = sample_le(scene, rng.random((n, 2)), rng.random((n, 2)))
    origins = LightOrigins(scene)
    cos = np.abs(np.einsum("ij,ij->i", nrm, w))
    cos = np.where(np.linalg.norm(nrm, axis=1) > 0, cos, 1.0)
    est = le * (cos / (pdf_pos * pdf_dir))[:, None]
    total = origins.power_rgb.sum(axis=0)
    # the estimate is unbiased for the total: the mean over all origins
    k = origins.index(light)
    np.testing.assert_allclose(est * origins.pmf[k][:, None], origins.power_rgb[k] * (origins.pmf[k] > 0)[:, None],
                               rtol=1e-9)
    assert np.all(total > 0)


def test_environment_origins_lie_on_the_disk_that_covers_the_scene():
    """An environment origin is a point of the disk of radius r (the scene's
    bounding sphere) perpendicular to its direction, r beyond the centre, and
    its ray runs along -w: every such ray passes within r of the centre, so
    it covers every primitive. ``pdf_le`` gives 0 for a point off that disk."""
    scene = mixed_emitters_scene(sky_with_sun())
    origins = LightOrigins(scene)
    corners = scene.triangles.reshape(-1, 3)
    assert np.all(np.linalg.norm(corners - origins.center, axis=1) <= origins.radius * (1 + 1e-12))
    rng = np.random.default_rng(SEED)
    n = 20000
    p, w, nrm, le, pdf_pos, pdf_dir, light = sample_le(scene, rng.random((n, 2)), rng.random((n, 2)))
    env = light == -1 - scene.n_point_lights
    assert 0.05 < env.mean() < 0.95
    towards = -w[env]
    off = p[env] - origins.center - origins.radius * towards
    np.testing.assert_allclose(np.einsum("ij,ij->i", off, towards), 0.0, atol=1e-12 * origins.radius)
    assert np.all(np.linalg.norm(off, axis=1) <= origins.radius * (1 + 1e-12))
    # uniform on the disk: the mean squared distance from its centre is r^2 / 2 (5 SE)
    r2 = np.einsum("ij,ij->i", off, off) / origins.radius ** 2
    assert abs(r2.mean() - 0.5) < 5 * r2.std() / np.sqrt(r2.size)
    np.testing.assert_allclose(pdf_pos[env], origins.pmf[origins.env_index] / (np.pi * origins.radius ** 2),
                               rtol=1e-12)
    moved = p[env] + 0.1 * origins.radius * towards
    got_pos, _ = pdf_le(scene, light[env], moved, w[env])
    np.testing.assert_array_equal(got_pos, 0.0)


# ---------------------------------------------------------------------------
# Sphere lights (issue 21): the cone sampler against pdf_li

def _sphere_light_scene(center=(0.0, 3.0, 0.0), radius=0.5, radiance=2.0, quad=True):
    """A facing plate (y = 0, normal +y), one sphere light above it, and a
    parallelogram light beside it when ``quad`` (two emitter kinds, one scene)."""
    tris = _quad((-2, 0, -2), (0, 0, 4), (4, 0, 0))          # normal cross(e1, e2) = +y
    n_tri = len(tris)
    lo, le1, le2 = np.array([3.0, 2.0, -0.5]), np.array([1.0, 0, 0]), np.array([0, 0, 1.0])
    if quad:
        tris += _quad(lo, le1, le2)                              # normal -y: faces the plate
    n_tri = len(tris)
    emission = np.zeros((n_tri + 1, 3))
    emission[n_tri] = radiance
    prim_light = np.full(n_tri + 1, -1)
    if quad:
        emission[2:4] = 1.0
        prim_light[2:4] = 0
    prim_light[n_tri] = 1 if quad else 0
    return Scene(name="sphere-light", triangles=np.array(tris), sphere_centers=[center], sphere_radii=[radius],
                 prim_material=[0] * (n_tri + 1), prim_emission=emission,
                 prim_two_sided_emission=np.zeros(n_tri + 1, bool), prim_light=prim_light,
                 prim_group=[0] * (n_tri + 1), materials=(Lambertian(0.5),), material_names=("white",),
                 light_origin=lo[None] if quad else np.zeros((0, 3)),
                 light_edge1=le1[None] if quad else np.zeros((0, 3)),
                 light_edge2=le2[None] if quad else np.zeros((0, 3)),
                 light_radiance=np.ones((1, 3)) if quad else np.zeros((0, 3)), sphere_light=[0],
                 camera=Camera((0, 5, -8), (0, 0, 0), (0, 1, 0), 40.0))


def test_sample_li_of_a_sphere_light_is_pdf_li_of_the_point_it_drew():
    """A sphere light's NEE pdf is ``pdf_li`` of the sphere point it drew, seen
    from the same shading point (outside, near the rim, and from inside); the
    point lies on the sphere and ``le`` is its radiance (0 from inside)."""
    scene = _sphere_light_scene()
    em = Emitters(scene)
    assert em.n_emitters == 2 and not em.single_quad
    rng = np.random.default_rng(SEED + 1)
    n = 6000
    c, r = scene.sphere_centers[0], scene.sphere_radii[0]
    p = _points(rng, n)
    p[: n // 10] = c + rng.uniform(-0.2, 0.2, (n // 10, 3))                 # inside the sphere
    p[n // 10: n // 5] = c + np.array([0.0, -(r + 1e-2), 0.0])          # just outside: a wide cone
    p[n // 5: n // 5 + 50] = c + np.array([0.0, -r * (1 + 1e-7), 0.0])  # on the sphere (a path's vertex on it)
    w, dist, le, pdf, light = em.sample_li(np.ascontiguousarray(p.T), rng.random((2, n)), rng.random(n))
    w, le = w.T, le.T
    on = np.flatnonzero(light[n // 5: n // 5 + 50] == -3) + n // 5
    assert on.size and np.all(pdf[on] == 0) and np.all(le[on] == 0)     # a convex light cannot light itself
    sel = np.flatnonzero((light == -3) & (pdf > 0))
    assert sel.size > n // 3
    x = p[sel] + w[sel] * dist[sel, None]
    np.testing.assert_allclose(np.linalg.norm(x - c, axis=1), r, rtol=1e-9)
    prim = np.full(sel.size, scene.n_triangles)
    np.testing.assert_allclose(pdf[sel], em.pdf_li(prim, p[sel], x), rtol=1e-9)
    assert np.all(pdf[sel] > 0)
    inside = np.linalg.norm(p[sel] - c, axis=1) < r
    assert inside.sum() > 100
    np.testing.assert_array_equal(le[sel][inside], 0.0)
    np.testing.assert_allclose(le[sel][~inside], 2.0)
    # from outside, the density is the inverse of the subtended solid angle (times the choice)
    d2 = ((p[sel][~inside] - c) ** 2).sum(axis=1)
    omc = 1.0 - np.sqrt(1.0 - r * r / d2)
    np.testing.assert_allclose(pdf[sel][~inside], 0.5 / (2 * np.pi * omc), rtol=1e-6)
    q = np.flatnonzero(light == 0)
    assert q.size > 500


def test_sphere_light_irradiance_on_a_facing_plane_is_l_pi_r2_over_d2():
    """Analytic: a sphere of radiance L seen from distance d (to its centre)
    gives a facing plane's point on the axis the irradiance ``L pi (r/d)^2``
    (the cone's projected solid angle ``pi sin^2 theta_max``). NEE's estimator
    ``le cos / pdf`` must hit it within 5 standard errors."""
    scene = _sphere_light_scene(center=(0.0, 2.0, 0.0), radius=0.6, radiance=3.0, quad=False)
    em = Emitters(scene)
    rng = np.random.default_rng(SEED + 2)
    n = 200_000
    p = np.zeros((3, n))
    w, dist, le, pdf, light = em.sample_li(p, rng.random((2, n)), None)
    est = le[0] * np.maximum(w[1], 0.0) / pdf
    exact = 3.0 * np.pi * (0.6 / 2.0) ** 2
    se = est.std(ddof=1) / np.sqrt(n)
    assert abs(est.mean() - exact) < 5 * se + 1e-12, (est.mean(), exact, se)
    # the cone sampler's estimate is nearly exact (cos varies little over the cap): a sharp check
    assert se < 2e-3 * exact
