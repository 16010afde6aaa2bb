"""Caustics by light tracing (:mod:`mcvar.integrators.caustics`): the aimed
light-subpath origins deliver the light's power to the specular objects as
the light's own cosine density does, and the partition between path tracing
and the light tracer (every path whose first camera vertex is non-specular
and whose last vertex before the light is specular goes to the light tracer)
renders the image path tracing renders."""
import numpy as np
import pytest
from scipy.stats import norm

from mcvar.bsdf import Glass, Mirror
from mcvar.integrators.caustics import AimedOrigins
from mcvar.integrators.emitters import LightOrigins
from mcvar.integrators.state import light_caustics_apply
from mcvar.scene import Scene, _cornell_common, load_scene
from mcvar.testing import sidak_significance
from mcvar.tracer import Tracer


def _stacked_spheres() -> Scene:
    # a glass sphere hung above a mirror sphere under the light: seen from the
    # light their cones overlap, so the density must sum both cones
    spheres = (((278.0, 320.0, 279.0), 60.0, "glass", Glass(1.5)),
               ((278.0, 100.0, 279.0), 100.0, "mirror", Mirror()))
    return Scene(name="stacked-spheres", description="glass sphere above a mirror sphere",
                 **_cornell_common(blocks=False, extra_spheres=spheres))


def _mirror_wall() -> Scene:
    # the green wall a mirror: a specular triangle the cones do not cover
    # (the cosine density's share a = 1/2 covers it)
    kw = _cornell_common(blocks=False, extra_spheres=(((180.0, 100.0, 170.0), 100.0, "glass", Glass(1.5)),))
    kw["materials"] = tuple(Mirror() if n == "green" else m for n, m in zip(kw["material_names"], kw["materials"]))
    return Scene(name="mirror-wall", description="glass sphere, a mirror wall", **kw)


SCENES = {"cornell-spheres": lambda: load_scene("cornell-spheres"), "stacked-spheres": _stacked_spheres,
          "mirror-wall": _mirror_wall}


def _first_hit_power(scene, p, w, beta, normal):
    """Per specular primitive: ``beta`` (channel 0) where the subpath's first hit is it, (P, n)."""
    tracer = Tracer(scene, dtype="float64")
    o = p + normal * scene.ray_epsilon
    _, prim = tracer.closest_soa(np.ascontiguousarray(o.T), np.ascontiguousarray(w.T))
    delta = np.array([bool(getattr(m, "is_delta", False)) for m in scene.materials])
    mat = np.asarray(scene.prim_material)
    spec = np.flatnonzero(delta[mat])
    hit = np.where(prim >= 0, prim, -1)
    return spec, np.stack([np.where(hit == s, beta[:, 0], 0.0) for s in spec])


@pytest.mark.parametrize("name", list(SCENES))
def test_aimed_origins_deliver_the_power_the_cosine_density_delivers(name):
    # E[beta 1(first hit = s)] is the light's power arriving directly at the
    # specular primitive s, whatever the direction density: the aimed origins
    # against LightOrigins' cosine density, per primitive within 5 combined
    # standard errors (Sidak over the primitives and scenes)
    scene = SCENES[name]()
    assert light_caustics_apply(scene)
    n = 400_000
    rng = np.random.default_rng(8_675_309)
    aimed = AimedOrigins(scene)
    p, w, beta = aimed.sample(rng.random((n, 5)))
    spec, xa = _first_hit_power(scene, p, w, beta, aimed.normal)
    s = LightOrigins(scene).sample(rng.random((n, 2)), rng.random((n, 2)))
    beta_c = s["le"] * (s["cos"] / (s["pdf_pos"] * s["pdf_dir"]))[:, None]
    spec_c, xc = _first_hit_power(scene, s["p"], s["w"], beta_c, aimed.normal)
    assert np.array_equal(spec, spec_c)
    ma, mc = xa.mean(axis=1), xc.mean(axis=1)
    se = np.hypot(xa.std(axis=1, ddof=1), xc.std(axis=1, ddof=1)) / np.sqrt(n)
    z = norm.isf(0.5 * sidak_significance(2 * norm.sf(5.0), 3 * 8))
    assert np.all(mc > 0) and np.all(np.abs(ma - mc) < z * se), (spec, ma, mc, se)
    if aimed.cosine == 0.0:
        # every subpath aimed: nearly all of them reach a specular sphere first (the cosine density: ~8%)
        assert (xa > 0).any(axis=0).mean() > 0.95
        assert (xa.std(axis=1) < 0.5 * xc.std(axis=1)).all()


def test_aimed_origins_mix_in_the_cosine_density_only_where_the_cones_do_not_cover():
    assert AimedOrigins(load_scene("cornell-spheres")).cosine == 0.0
    assert AimedOrigins(_stacked_spheres()).cosine == 0.0
    assert AimedOrigins(_mirror_wall()).cosine == 0.5


def test_caustics_by_light_tracing_agree_with_path_tracing_with_a_mirror_wall():
    # the partition where the light tracer's subpaths also start on a
    # specular triangle (the cosine half of the mixture) and come back through
    # the glass: image and caustic region per channel within 5 combined
    # standard errors (Sidak over 3 channels x 2 regions), random sampler
    from mcvar.integrators import render

    scene = _mirror_wall()
    res = 16
    kw = dict(spp=1024, res=res, sampler="random")
    a = render(scene, rng=31, caustics="path", **kw)
    b = render(scene, rng=32, caustics="light", **kw)
    z = norm.isf(0.5 * sidak_significance(2 * norm.sf(5.0), 6))
    for rows, cols in ((slice(None), slice(None)), (slice(10, 16), slice(0, 16))):
        ia, ib = a.image[rows, cols], b.image[rows, cols]
        k = ia.shape[0] * ia.shape[1]
        sa = np.sqrt(a.variance[rows, cols].sum(axis=(0, 1)) / a.spp) / k
        sb = np.sqrt(b.variance[rows, cols].sum(axis=(0, 1)) / b.spp) / k
        ma, mb = ia.mean(axis=(0, 1)), ib.mean(axis=(0, 1))
        assert np.all(np.abs(ma - mb) < z * np.hypot(sa, sb)), (rows, ma, mb, sa, sb)
