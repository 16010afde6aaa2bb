"""Point lights, light tracing and bidirectional path tracing (issue 11).

Tolerances come from standard errors (5 sigma, Sidak-corrected over the
pixels or blocks compared); renders are small (<= 32 x 32) to keep CI fast.
"""
import math

import numpy as np
import pytest
from scipy.stats import norm

from mcvar.bsdf import Lambertian
from mcvar.integrators import render
from mcvar.scene import Camera, Scene, load_scene


def _sidak_z(k, sigma=5.0):
    """Two-sided z threshold for k comparisons at the family level of 'sigma' sigma."""
    return float(norm.isf(0.5 * (1.0 - (1.0 - 2.0 * norm.sf(sigma)) ** (1.0 / k))))


def _point_over_quad(height=0.5, intensity=(3.0, 2.0, 1.0), rho=0.5):
    quad = np.array([(-1.0, 0.0, -1.0), (-1.0, 0.0, 1.0), (1.0, 0.0, 1.0), (1.0, 0.0, -1.0)])
    tris = np.array([quad[[0, 1, 2]], quad[[0, 2, 3]]])
    return Scene(
        name="point-over-quad", triangles=tris, sphere_centers=np.zeros((0, 3)), sphere_radii=np.zeros(0),
        prim_material=[0, 0], prim_emission=np.zeros((2, 3)), prim_two_sided_emission=[False, False],
        prim_light=[-1, -1], prim_group=[0, 0], materials=(Lambertian(rho),), material_names=("diffuse",),
        light_origin=np.zeros((0, 3)), light_edge1=np.zeros((0, 3)), light_edge2=np.zeros((0, 3)),
        light_radiance=np.zeros((0, 3)),
        camera=Camera((0.0, 1.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 60.0),
        point_light_position=[(0.0, height, 0.0)], point_light_intensity=[intensity], ray_epsilon=1e-5)


def _point_over_quad_reference(scene, res, sub=24):
    """Pixel means of rho / pi * I h / r^3 by a sub x sub midpoint grid per pixel."""
    w, h = res
    g = (np.arange(sub) + 0.5) / sub
    uv = np.stack(np.meshgrid(g, g, indexing="xy"), -1).reshape(-1, 2)
    pix = np.repeat(np.arange(w * h), sub * sub)
    d = scene.camera.ray_directions(res, pix, np.tile(uv, (w * h, 1)))
    o = scene.camera.position
    x = o + d * (-o[1] / d[:, 1])[:, None]                      # hit on y = 0
    v = scene.point_light_position[0] - x
    r = np.linalg.norm(v, axis=1)
    e = (v[:, 1] / r ** 3)[:, None] * scene.point_light_intensity[0]
    radiance = scene.materials[0].albedo / np.pi * e
    return radiance.reshape(h, w, sub * sub, 3).mean(axis=2)


@pytest.mark.parametrize("integrator", ["path", "direct"])
def test_next_event_estimation_sees_a_point_light(integrator):
    """A Lambertian quad under a point light: pixel = mean of rho/pi I cos / r^2
    over its footprint (quadrature), within 5 SE (Sidak over pixels and channels)."""
    scene = _point_over_quad()
    res = (6, 6)
    r = render(scene, integrator=integrator, spp=64, res=res, rng=2, max_depth=2 if integrator == "path" else None)
    want = _point_over_quad_reference(scene, res)
    se = r.standard_error
    z = _sidak_z(want.size)
    assert np.all(np.abs(r.image - want) <= z * se + 1e-4 * want), np.max(np.abs(r.image - want) / se)


def test_path_bsdf_renders_a_point_light_black_and_path_does_not():
    scene = load_scene("cornell-point")
    lit = render(scene, integrator="path", spp=4, res=8, rng=1, max_depth=3)
    dark = render(scene, integrator="path_bsdf", spp=4, res=8, rng=1, max_depth=3)
    assert np.all(dark.image == 0.0)
    assert np.all(lit.image.mean(axis=(0, 1)) > 0.0)
    assert np.mean(lit.image.sum(axis=2) > 0) > 0.5          # most pixels see the lit room
