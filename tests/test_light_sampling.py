"""Solid-angle sampling of the quad light in next-event estimation
(``light_sampling='solid_angle'``, Urena et al. 2013): the structure-of-arrays
sampler against its pdf (chi-square), NEE's pdf equal to the pdf the MIS
weight of a BSDF-sampled hit of the same light point uses, the image
unbiased against area sampling, and bad input."""
import numpy as np
import pytest

from mcvar import warps
from mcvar.integrators import Emitters, render
from mcvar.scene import load_scene
from mcvar.testing import chi2_test

SEED = 1412


@pytest.fixture(scope="module")
def cornell():
    return load_scene("cornell")


def _points_in_box(n, rng):
    """Shading points inside the Cornell box, below the light."""
    return np.column_stack([rng.uniform(10, 540, n), rng.uniform(1, 540, n), rng.uniform(10, 550, n)])


@pytest.mark.parametrize("ref", [(250.0, 400.0, 300.0), (50.0, 1.0, 500.0), (100.0, 548.0, 100.0)])
def test_soa_sampler_chi2_against_its_pdf(cornell, ref):
    """NEE's sampler as a map onto the light's own (s, t) square, against its
    density there: ``pdf_w cos(theta_l) / r^2 * area`` (the support is the
    whole square; three shading points, Sidak-corrected)."""
    em = Emitters(cornell, "solid_angle")
    o, e1, e2 = cornell.light_origin[0], cornell.light_edge1[0], cornell.light_edge2[0]
    n_l = cornell.light_normal[0]
    area = float(cornell.light_area[0])
    ref = np.asarray(ref)

    def sample(u):
        p = np.broadcast_to(ref[:, None], (3, len(u)))
        w, dist, _, _, _ = em.sample_li(np.ascontiguousarray(p), np.ascontiguousarray(u.T), None)
        x = ref + (w * dist).T
        return warps.uniform_parallelogram_to_square(x, o, e1, e2)

    def pdf(st):
        x = warps.square_to_uniform_parallelogram(st, o, e1, e2)
        d = x - ref
        r2 = np.einsum("ij,ij->i", d, d)
        cos_l = np.abs(d @ n_l) / np.sqrt(r2)
        p = np.ascontiguousarray(np.broadcast_to(ref[:, None], (3, len(st))))
        return em._rect_pdf(0, p) * cos_l / r2 * area

    res = chi2_test(sample, pdf, "square", n=200_000, rng=SEED, bins=(30, 30), test_count=3)
    assert res.passed, res


@pytest.mark.parametrize("mode", ["area", "solid_angle"])
def test_nee_pdf_is_the_pdf_of_hitting_the_same_light_point(cornell, mode):
    """The density NEE hands to the MIS weight equals the density the
    BSDF-sampled hit of the same light point is weighted with
    (``Emitters.pdf_li``): the check that catches an area pdf in a solid-angle
    MIS weight (issue 10's planted bug), for both sampling modes."""
    rng = np.random.default_rng(SEED)
    em = Emitters(cornell, mode)
    p = _points_in_box(5000, rng)
    u = rng.random((2, 5000))
    w, dist, le, pdf, _ = em.sample_li(np.ascontiguousarray(p.T), u, None)
    x = p + (w * dist).T
    on = warps.square_to_uniform_parallelogram_pdf(x, cornell.light_origin[0], cornell.light_edge1[0],
                                                   cornell.light_edge2[0]) > 0
    assert on.all() and (pdf > 0).all()
    light_prim = int(np.flatnonzero(cornell.prim_light >= 0)[0])
    hit = em.pdf_li(np.full(5000, light_prim), p, x)
    np.testing.assert_allclose(pdf, hit, rtol=1e-9)
    if mode == "solid_angle":        # and it is 1 / S, S the light's solid angle
        s = 1.0 / warps.square_to_spherical_rectangle_pdf(x[:3], p[:3], cornell.light_origin[0],
                                                          cornell.light_edge1[0], cornell.light_edge2[0])
        np.testing.assert_allclose(pdf[:3], 1.0 / s, rtol=1e-9)


def test_solid_angle_nee_is_unbiased_against_area_nee(cornell):
    """``path`` with solid-angle NEE against area NEE: per channel, the image
    mean and the mean of the top rows (ceiling and light, where the two
    densities differ most) within 5 standard errors (random sampler: the
    per-pixel variances give the standard errors; 2 seeds each)."""
    res, spp = 16, 64
    a = [render(cornell, spp=spp, res=res, rng=SEED + k, light_sampling="solid_angle") for k in range(2)]
    b = [render(cornell, spp=spp, res=res, rng=SEED + 10 + k) for k in range(2)]
    for rows in (slice(0, res), slice(0, 4)):
        for c in range(3):
            def stat(rs):
                m = np.mean([r.image[rows, :, c].mean() for r in rs])
                k = rs[0].image[rows, :, c].size
                v = np.sum([(r.variance[rows, :, c] / r.spp).sum() for r in rs]) / (k * len(rs)) ** 2
                return m, v
            (ma, va), (mb, vb) = stat(a), stat(b)
            assert abs(ma - mb) < 5 * np.sqrt(va + vb), (rows, c, ma, mb)


def test_bad_light_sampling(cornell):
    with pytest.raises(ValueError, match="light_sampling"):
        render(cornell, spp=1, res=4, light_sampling="cosine")
    with pytest.raises(ValueError, match="rectangle"):
        warps._rectangle_soa_frame([1.0, 0.0, 0.0], [1.0, 1.0, 0.0])


def test_light_sample_without_radiance_is_the_same_sample(cornell):
    """``sample_li(..., radiance=False)`` (the Lambertian kernel's NEE, which takes
    ``Le`` from its own table) returns the same directions, distances, densities
    and light indices exactly, and no radiance; points on the ceiling (behind the
    light's plane) included, where ``le`` would be masked."""
    em = Emitters(cornell)
    rng = np.random.default_rng(SEED + 7)
    m = 4000
    p = np.stack([rng.uniform(1, 550, m), rng.uniform(1, 548, m), rng.uniform(1, 558, m)]).astype(np.float32)
    p[1, : m // 4] = cornell.triangles[:, :, 1].max()           # the ceiling: behind the light
    u = rng.random((2, m), dtype=np.float32)
    a, b = em.sample_li(p, u, None), em.sample_li(p, u, None, radiance=False)
    assert not np.all(a[3] > 0) and np.any(a[3] > 0)
    for i in (0, 1, 3, 4):
        assert np.array_equal(a[i], b[i])
    assert b[2] is None and a[2].shape == (3, m)
