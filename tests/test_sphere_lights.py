"""Sphere lights (issue 21) in every method: NEE samples them by the cone they
subtend, BSDF hits are MIS-weighted with the same ``pdf_li``, light subpaths
and photons start on them uniformly by area.

A closed Lambertian cube lit by one sphere light: photons carry the sphere's
power ``pi (4 pi r^2) L`` exactly at their first hit; ``path`` with NEE and
MIS agrees with ``path_bsdf`` (no NEE), ``light``, ``bdpt`` and ``sppm`` on
the image mean and on every 4 x 4 block (z-scores from the per-pixel
standard errors, Sidak-corrected over the blocks, 5 sigma for the mean), and
``photon`` on the image mean.
"""
import numpy as np
import pytest
from scipy.stats import norm

from mcvar.bsdf import Lambertian
from mcvar.integrators import Emitters, render
from mcvar.integrators.photon import trace_photons
from mcvar.scene import Camera, Scene
from mcvar.testing import sidak_significance

from cube_quads import unit_cube_quads  # tests/cube_quads.py

SEED = 21_4242
RES = 16
BLOCK = 4
CENTER, RADIUS, LE = (0.5, 0.7, 0.55), 0.12, 4.0


def sphere_lit_cube(rho=0.5, light=True):
    """Closed unit cube (inward normals, Lambertian ``rho``) with an emitting
    sphere in it: a sampled light (``sphere_light``) or, with ``light=False``,
    emission that only BSDF sampling finds."""
    quads = unit_cube_quads()
    tris = np.array([t for q in quads for t in ([q[0], q[1], q[2]], [q[0], q[2], q[3]])])
    n = tris.shape[0] + 1
    emission = np.zeros((n, 3))
    emission[-1] = LE
    prim_light = np.full(n, -1)
    if light:
        prim_light[-1] = 0
    return Scene(name="sphere-lit-cube", triangles=tris, sphere_centers=[CENTER], sphere_radii=[RADIUS],
                 prim_material=np.zeros(n, int), prim_emission=emission,
                 prim_two_sided_emission=np.zeros(n, bool), prim_light=prim_light, prim_group=np.zeros(n, int),
                 materials=(Lambertian(rho),), material_names=("white",), light_origin=np.zeros((0, 3)),
                 light_edge1=np.zeros((0, 3)), light_edge2=np.zeros((0, 3)), light_radiance=np.zeros((0, 3)),
                 sphere_light=[0] if light else None,
                 camera=Camera((0.5, 0.5, 0.05), (0.5, 0.5, 1.0), (0.0, 1.0, 0.0), 70.0), ray_epsilon=1e-6)


def test_scene_validates_sphere_lights():
    scene = sphere_lit_cube()
    assert scene.n_sphere_lights == 1 and Emitters(scene).n_emitters == 1
    import dataclasses
    with pytest.raises(ValueError, match="sphere_light"):
        dataclasses.replace(scene, sphere_light=[1])                       # no such sphere
    with pytest.raises(ValueError, match="prim_light"):
        dataclasses.replace(scene, sphere_light=None)                      # prim_light says light 0: no such light
    with pytest.raises(ValueError, match="sphere_light"):
        dataclasses.replace(scene, sphere_light=[0.5])
    assert sphere_lit_cube(light=False).n_sphere_lights == 0


def test_photons_start_on_the_sphere_with_its_power():
    scene = sphere_lit_cube()
    phi = np.pi * 4 * np.pi * RADIUS ** 2 * LE
    batches = list(trace_photons(scene, 1 << 14, rng=SEED, batch=1 << 10))
    direct = np.array([b.power[b.depth == 1].sum(axis=0) for b in batches]).sum(axis=0)
    np.testing.assert_allclose(direct, phi, rtol=1e-9)


@pytest.fixture(scope="module")
def renders():
    scene = sphere_lit_cube()
    plan = {"path": 256, "path_bsdf": 512, "light": 256, "bdpt": 64, "sppm": 64, "photon": 64}
    seeds = np.random.SeedSequence(SEED).spawn(len(plan))
    out = {}
    for (m, spp), s in zip(plan.items(), seeds):
        # splatting methods estimate their variance from independent batches: 32 of them
        r = render(scene, integrator=m, spp=spp, res=RES, rng=s, batch_spp=spp // 32)
        out[m] = (np.asarray(r.image).mean(axis=2), np.asarray(r.standard_error).mean(axis=2))
    return out


def _blocks(a, sq=False):
    h = a.shape[0] // BLOCK
    b = (a ** 2 if sq else a).reshape(h, BLOCK, h, BLOCK).sum(axis=(1, 3))
    return np.sqrt(b) / BLOCK ** 2 if sq else b / BLOCK ** 2


@pytest.mark.parametrize("method", ["path_bsdf", "light", "bdpt", "sppm", "photon"])
def test_methods_agree_with_path_on_a_sphere_light(renders, method):
    """The channel mean's standard error is bounded by the mean of the channels'
    (Cauchy-Schwarz), which is used: conservative. ``photon`` (a fixed
    radius) blurs the light's neighbourhood (a block at z = -10, measured):
    its image mean is tested, its blocks are not; SPPM's shrinking radius
    passes the block test."""
    (a, sa), (b, sb) = renders["path"], renders[method]
    n = a.size
    z_mean = (a.mean() - b.mean()) / np.sqrt((sa ** 2).sum() / n ** 2 + (sb ** 2).sum() / n ** 2)
    assert abs(z_mean) < 5.0, z_mean
    if method == "photon":
        return
    z = (_blocks(a) - _blocks(b)) / np.hypot(_blocks(sa, True), _blocks(sb, True))
    limit = norm.isf(0.5 * sidak_significance(1e-3, z.size))
    assert np.abs(z).max() < limit, (z, limit)


def test_a_scene_file_keeps_the_sphere_a_sampled_light(tmp_path):
    """Written to Mitsuba XML and read back, an outward-emitting sphere is a
    sphere light again (Mitsuba samples its sphere emitters too), and the
    image is the builder's (float32 geometry of the file aside: same seed)."""
    from mcvar.scene import load_scene, save_scene

    scene = sphere_lit_cube()
    back = load_scene(save_scene(scene, tmp_path / "cube.xml", res=8, spp=2))
    assert back.n_sphere_lights == 1 and back.prim_light[back.n_triangles] == 0
    a = render(scene, integrator="path", spp=64, res=8, rng=SEED)
    b = render(back, integrator="path", spp=64, res=8, rng=SEED)
    np.testing.assert_allclose(b.image, a.image, rtol=1e-5, atol=1e-7)     # float32 vertices in the file


def test_the_sphere_lit_cube_renders_as_in_mitsuba():
    """An independent renderer: Mitsuba 3 (``scalar_rgb`` path tracer, which
    samples sphere emitters its own way) against mcvar's ``path`` (cone NEE
    and MIS), R independent renders each; per 4 x 4 block of the grey image,
    Welch's t on the replicate block means, Sidak-corrected over the blocks
    (t quantile at R - 1 degrees of freedom: conservative)."""
    pytest.importorskip("mitsuba")
    from scipy.stats import t as student

    from mcvar.interop.mitsuba import render_mitsuba

    scene = sphere_lit_cube()
    reps, spp = 16, 256
    seeds = np.random.SeedSequence(SEED + 7).spawn(2 * reps)
    ours = np.array([render(scene, integrator="path", spp=spp, res=RES, rng=s).image for s in seeds[:reps]])
    theirs = np.array([render_mitsuba(scene, res=RES, spp=spp, rng=s) for s in seeds[reps:]])
    h = RES // BLOCK

    def blocks(x):
        return x.mean(axis=3).reshape(reps, h, BLOCK, h, BLOCK).mean(axis=(2, 4))
    a, b = blocks(ours), blocks(theirs)
    se = np.sqrt(a.var(axis=0, ddof=1) / reps + b.var(axis=0, ddof=1) / reps)
    tval = np.abs(a.mean(axis=0) - b.mean(axis=0)) / se
    crit = student.isf(0.5 * sidak_significance(1e-3, tval.size), reps - 1)
    assert tval.max() < crit, (tval.max(), crit)
    # and the image means, 5 sigma
    ma, mb = ours.mean(axis=(1, 2, 3)), theirs.mean(axis=(1, 2, 3))
    assert abs(ma.mean() - mb.mean()) < 5 * np.sqrt(ma.var(ddof=1) / reps + mb.var(ddof=1) / reps)
