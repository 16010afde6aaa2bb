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


# -- glass_splits: both lobes of glass on camera paths -------------------------

def _glass_pixels(scene, res):
    tracer = Tracer(scene)
    d = scene.camera.ray_directions_soa((res, res), np.arange(res * res), np.full((res * res, 2), 0.5))
    o = np.broadcast_to(scene.camera.position[:, None], d.shape)
    _, prim = tracer.closest_soa(np.ascontiguousarray(o), np.ascontiguousarray(d))
    glass = [i for i, m in enumerate(scene.materials) if type(m) is Glass]
    mat = np.where(prim >= 0, np.asarray(scene.prim_material)[np.maximum(prim, 0)], -1)
    return np.isin(mat, glass).reshape(res, res)


@pytest.mark.parametrize("splits,max_depth", [(1, 3), (3, 3), (1, None), (3, None)])
def test_glass_splits_keep_the_image(splits, max_depth):
    # splitting replaces the Fresnel choice by both lobes with weights F and 1 - F: the same
    # expectation. Per channel over the image and over the pixels that see the glass sphere,
    # within 5 combined standard errors (Sidak over 4 x 3 x 2 tests); at max_depth 3 (the
    # light seen in and through the sphere, E S L and E S S L, without the heavy tails of
    # the caustics seen through it) the glass pixels' variance falls several times: the
    # variance of the choice is what splitting removes
    from mcvar.integrators import render

    scene = load_scene("cornell-spheres")
    res = 16
    kw = dict(spp=512, res=res, sampler="random", caustics="light", max_depth=max_depth)
    a = render(scene, rng=41, glass_splits=0, **kw)
    b = render(scene, rng=42, glass_splits=splits, **kw)
    keep = _glass_pixels(scene, res)
    assert keep.sum() >= 6
    z = norm.isf(0.5 * sidak_significance(2 * norm.sf(5.0), 24))
    for sel in (np.ones_like(keep), keep):
        k = sel.sum()
        ma, mb = a.image[sel].mean(axis=0), b.image[sel].mean(axis=0)
        sa = np.sqrt(a.variance[sel].sum(axis=0) / a.spp) / k
        sb = np.sqrt(b.variance[sel].sum(axis=0) / b.spp) / k
        assert np.all(np.abs(ma - mb) < z * np.hypot(sa, sb)), (k, ma, mb, sa, sb)
    if max_depth is not None:
        assert b.variance[keep].sum() < 0.25 * a.variance[keep].sum()


def test_glass_splits_change_nothing_without_glass():
    # the Cornell box and the mirror-only room: the same paths, the same image
    from mcvar.integrators import render

    kw = dict(spp=16, res=16, sampler="sobol", rng=3, kernel="general")
    for scene in (load_scene("cornell"), Scene(name="mirror-room", description="a mirror sphere",
                                               **_cornell_common(blocks=False, extra_spheres=(
                                                   ((278.0, 100.0, 279.0), 100.0, "mirror", Mirror()),)))):
        a, b = render(scene, glass_splits=0, **kw), render(scene, glass_splits=2, **kw)
        np.testing.assert_array_equal(a.image, b.image)
        assert a.rays == b.rays


def test_glass_splits_are_checked():
    from mcvar.integrators.settings import PathSettings

    assert PathSettings(glass_splits=0).glass_splits == 0
    for bad in (-1, 1.5, True, "1"):
        with pytest.raises((ValueError, TypeError), match="glass_splits"):
            PathSettings(glass_splits=bad)


def test_a_split_path_is_the_weighted_sum_of_its_two_choices():
    # An identity, path by path: with a constant Fresnel term (F = 0.3) and a fixed depth (no
    # roulette, whose survival depends on the throughput), a camera path split at its first
    # vertex, when that vertex is glass, carries F x (the path that reflected there) + (1 - F)
    # x (the path that refracted), each traced unsplit with vertex 1's lobe forced (its
    # BSDF column 0 set to 0 or to 1 - 1e-9) and every other number the same; a path whose
    # first vertex is not glass is traced exactly as without splitting.
    from mcvar.integrators import stream_dim, trace_camera_paths
    from mcvar.integrators.stream import BSDF, CAMERA_DIMS

    kw = _cornell_common(blocks=False, extra_spheres=(((278.0, 150.0, 250.0), 150.0, "glass",
                                                       Glass(1.5, fresnel=0.3)),))
    scene = Scene(name="glass-03", description="a glass sphere of constant F = 0.3", **kw)
    res, n, depth = (8, 8), 4000, 6
    rng = np.random.default_rng(2_718_281)
    pixel = rng.integers(0, res[0] * res[1], n)
    u = rng.random((n, stream_dim(depth)))
    tracer = Tracer(scene, dtype="float64")
    col = CAMERA_DIMS + BSDF                              # vertex 1's lobe choice

    def trace(v, splits):
        return trace_camera_paths(scene, res, pixel, v, rng=0, tracer=tracer, max_depth=depth,
                                  glass_splits=splits, kernel="general")[0]

    split = trace(u, 1)
    plain = trace(u, 0)
    u_r, u_t = u.copy(), u.copy()
    u_r[:, col], u_t[:, col] = 0.0, 1.0 - 1e-9
    forced = 0.3 * trace(u_r, 0) + 0.7 * trace(u_t, 0)
    d = scene.camera.ray_directions_soa(res, pixel, u[:, :CAMERA_DIMS])
    o = np.broadcast_to(scene.camera.position[:, None], d.shape)
    _, prim = tracer.closest_soa(np.ascontiguousarray(o), np.ascontiguousarray(d))
    glass = prim == scene.n_triangles
    assert 0.1 < glass.mean() < 0.9 and np.any(forced[glass] > 0)
    np.testing.assert_allclose(split[glass], forced[glass], rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(split[~glass], plain[~glass])


def test_joins_at_lambertian_vertices_written_out_equal_the_bsdf_evaluation():
    # the caustic stage's written-out f at Lambertian vertices against the light tracer's
    # generic evaluation (frames flipped towards wo, Lambertian.eval), on random normals and
    # directions on both sides; None as soon as a material is not Lambertian
    from mcvar.integrators.caustics import _lambertian_f
    from mcvar.integrators.light import _bsdf_eval, _flips

    scene = load_scene("cornell-spheres")
    rng = np.random.default_rng(31_415)
    n = 5000

    def unit(v):
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    ng, wo, wi = (unit(rng.normal(size=(n, 3))) for _ in range(3))
    lamb = [i for i, m in enumerate(scene.materials) if type(m).__name__ == "Lambertian"]
    table = np.array([m.albedo / np.pi if i in lamb else np.full(3, np.nan) for i, m in enumerate(scene.materials)])
    mat = rng.choice(lamb, n)
    got = _lambertian_f(table, mat, ng, wo, np.einsum("ij,ij->i", ng, wi))
    want, _, _ = _bsdf_eval(scene, _flips(scene), mat, ng, wo, wi, need_pdf=False)
    assert np.any(got > 0) and np.any(got == 0)
    np.testing.assert_array_equal(got, want)
    other = next(i for i in range(len(scene.materials)) if i not in lamb)
    assert _lambertian_f(table, np.append(mat, other), np.vstack([ng, ng[:1]]), np.vstack([wo, wo[:1]]),
                         np.zeros(n + 1)) is None
