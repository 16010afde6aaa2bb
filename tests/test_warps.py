"""Tests of mcvar.warps: exact facts first, then statistics, extremes, bad input.

Statistical tests use mcvar.testing (chi-square of each sampler against its
pdf) at family-wise significance 1e-3, Sidak-corrected over every chi-square
test in this file; quadrature tests use the cubature's own error estimate.
"""
import numpy as np
import pytest
from scipy import stats

from mcvar import warps as w
from mcvar.testing import (check_extremes, check_inverse, check_pdf_normalized, chi2_test,
                           sidak_significance)

TWO_PI = 2.0 * np.pi
SEED = 20_241_122_031
N_CHI2 = 200_000
SPH_C = np.array([0.0, 3.0, 0.0])            # sin theta_max = 1/3
SPH_OFF = np.array([1.0, 2.0, -1.5])
SPH_IN = np.array([0.4, -0.3, 0.2])

# (id, sampler, pdf, inverse, domain, chi2 bounds, periodic u1)
ALPHA, AX, AY, K, CMAX = 0.3, 0.15, 0.6, 20.0, 0.8
WARPS = [
    ("disk", w.square_to_uniform_disk_concentric, w.square_to_uniform_disk_concentric_pdf,
     w.uniform_disk_concentric_to_square, "disk", None, False),
    ("uniform_hemisphere", w.square_to_uniform_hemisphere, w.square_to_uniform_hemisphere_pdf,
     w.uniform_hemisphere_to_square, "hemisphere", None, True),
    ("cosine_hemisphere", w.square_to_cosine_hemisphere, w.square_to_cosine_hemisphere_pdf,
     w.cosine_hemisphere_to_square, "hemisphere", None, False),
    ("uniform_sphere", w.square_to_uniform_sphere, w.square_to_uniform_sphere_pdf,
     w.uniform_sphere_to_square, "sphere", None, True),
    ("uniform_sphere_flip", w.square_to_uniform_sphere_flip, w.square_to_uniform_sphere_flip_pdf,
     w.uniform_sphere_flip_to_square, "sphere", None, True),
    ("cone", lambda u: w.square_to_uniform_cone(u, CMAX),
     lambda v: w.square_to_uniform_cone_pdf(v, CMAX),
     lambda v: w.uniform_cone_to_square(v, CMAX), "sphere", ((CMAX, 1.0), (0.0, TWO_PI)), True),
    # a sphere seen from outside (on the +y axis: cone bounds), off-axis, and from inside
    ("sphere_cone", lambda u: w.square_to_sphere_from_point(u, np.zeros((len(u), 3)), SPH_C, 1.0)[0],
     lambda v: w.square_to_sphere_from_point_pdf(v, np.zeros((len(v), 3)), SPH_C, 1.0),
     lambda v: w.sphere_from_point_to_square(v, np.zeros((len(v), 3)), SPH_C, 1.0), "sphere",
     ((np.sqrt(8.0 / 9.0), 1.0), (0.0, TWO_PI)), True),
    ("sphere_cone_offaxis", lambda u: w.square_to_sphere_from_point(u, np.zeros((len(u), 3)), SPH_OFF, 0.8)[0],
     lambda v: w.square_to_sphere_from_point_pdf(v, np.zeros((len(v), 3)), SPH_OFF, 0.8),
     lambda v: w.sphere_from_point_to_square(v, np.zeros((len(v), 3)), SPH_OFF, 0.8), "sphere", None, True),
    ("sphere_inside", lambda u: w.square_to_sphere_from_point(u, np.full((len(u), 3), 0.1), SPH_IN, 1.0)[0],
     lambda v: w.square_to_sphere_from_point_pdf(v, np.full((len(v), 3), 0.1), SPH_IN, 1.0),
     lambda v: w.sphere_from_point_to_square(v, np.full((len(v), 3), 0.1), SPH_IN, 1.0), "sphere", None, True),
    ("phong", lambda u: w.square_to_phong_lobe(u, K), lambda v: w.square_to_phong_lobe_pdf(v, K),
     lambda v: w.phong_lobe_to_square(v, K), "hemisphere", None, True),
    ("beckmann", lambda u: w.square_to_beckmann(u, ALPHA), lambda v: w.square_to_beckmann_pdf(v, ALPHA),
     lambda v: w.beckmann_to_square(v, ALPHA), "hemisphere", None, True),
    ("ggx", lambda u: w.square_to_ggx(u, ALPHA), lambda v: w.square_to_ggx_pdf(v, ALPHA),
     lambda v: w.ggx_to_square(v, ALPHA), "hemisphere", None, True),
    ("ggx_aniso", lambda u: w.square_to_ggx(u, AX, AY), lambda v: w.square_to_ggx_pdf(v, AX, AY),
     lambda v: w.ggx_to_square(v, AX, AY), "hemisphere", None, True),
    ("triangle", w.square_to_uniform_triangle, w.square_to_uniform_triangle_pdf,
     w.uniform_triangle_to_square, "square", None, False),
]
WO_LIST = [np.array([0.0, 1.0, 0.0]), np.array([0.6, 0.5, -0.3]) / np.linalg.norm([0.6, 0.5, -0.3]),
           np.array([0.8, 0.0, 0.6])]  # unit vectors: warps refuse other lengths
VNDF = [(f"ggx_visible_{i}", (lambda u, wo=wo: w.square_to_ggx_visible(u, wo, AX, AY)),
         (lambda h, wo=wo: w.square_to_ggx_visible_pdf(h, wo, AX, AY)), "hemisphere")
        for i, wo in enumerate(WO_LIST)]
N_TESTS = len(WARPS) + len(VNDF) + 1  # + the flip-vs-sphere homogeneity test
SIG = sidak_significance(1e-3, N_TESTS)
# one independent stream per chi-square test (Sidak assumes independent tests)
STREAMS = dict(zip([c[0] for c in WARPS] + [c[0] for c in VNDF],
                   np.random.SeedSequence(SEED).spawn(len(WARPS) + len(VNDF))))


def _random_u(n, seed=SEED):
    return np.random.default_rng(seed).random((n, 2))


# ---------------------------------------------------------------- exact facts

def test_concentric_disk_known_points():
    u = np.array([[0.5, 0.5], [1.0, 0.5], [0.5, 1.0], [0.0, 0.5], [0.5, 0.0], [1.0, 1.0]])
    p = w.square_to_uniform_disk_concentric(u)
    s = np.sqrt(0.5)
    expect = np.array([[0, 0], [1, 0], [0, 1], [-1, 0], [0, -1], [s, s]])
    np.testing.assert_allclose(p, expect, atol=1e-15)


def test_closed_form_pdfs():
    v = w.square_to_uniform_sphere(_random_u(1000))
    y = v[:, 1]
    np.testing.assert_allclose(w.square_to_cosine_hemisphere_pdf(v), np.where(y >= 0, y / np.pi, 0), rtol=1e-15)
    np.testing.assert_array_equal(w.square_to_uniform_hemisphere_pdf(v), np.where(y >= 0, 1 / TWO_PI, 0))
    np.testing.assert_array_equal(w.square_to_uniform_sphere_pdf(v), np.full(1000, 1 / (4 * np.pi)))
    np.testing.assert_allclose(w.square_to_uniform_sphere_flip_pdf(v), 1 / (4 * np.pi), rtol=1e-15)
    # Phong with k = 0 is the uniform hemisphere; the cone of cos 0 is the hemisphere, of -1 the sphere
    np.testing.assert_allclose(w.square_to_phong_lobe_pdf(v, 0.0), w.square_to_uniform_hemisphere_pdf(v))
    np.testing.assert_allclose(w.square_to_uniform_cone_pdf(v, 0.0), w.square_to_uniform_hemisphere_pdf(v))
    np.testing.assert_allclose(w.square_to_uniform_cone_pdf(v, -1.0), w.square_to_uniform_sphere_pdf(v))


def test_ggx_alpha_one_is_the_cosine_lobe():
    # D = 1 / (pi (x^2 + y^2 + z^2)^2) = 1 / pi for alpha = 1, so D cos = cos / pi;
    # the sampler reduces to Malley's sin(theta) = sqrt(u0).
    u = _random_u(1000)
    h = w.square_to_ggx(u, 1.0)
    np.testing.assert_allclose(w.square_to_ggx_pdf(h, 1.0), h[:, 1] / np.pi, rtol=1e-13)
    np.testing.assert_allclose(np.sqrt(1 - h[:, 1] ** 2), np.sqrt(u[:, 0]), atol=1e-12)


def _spherical(v):
    theta = np.arccos(np.clip(v[:, 1], -1, 1))
    phi = np.arctan2(v[:, 2], v[:, 0])
    return theta, phi


def test_microfacet_pdfs_match_the_papers_tan_forms():
    # Independent implementations in (theta, phi): Walter et al. 2007 eq. (25)
    # (Beckmann) and Heitz 2014 eq. (85) (anisotropic GGX), times cos(theta).
    v = w.square_to_cosine_hemisphere(_random_u(2000))[:1999]
    th, ph = _spherical(v)
    t2, c = np.tan(th) ** 2, np.cos(th)
    beck = np.exp(-t2 / ALPHA ** 2) / (np.pi * ALPHA ** 2 * c ** 4) * c
    np.testing.assert_allclose(w.square_to_beckmann_pdf(v, ALPHA), beck, rtol=1e-10, atol=1e-300)  # denormals
    ggx = 1 / (np.pi * AX * AY * c ** 4 * (1 + t2 * (np.cos(ph) ** 2 / AX ** 2
                                                     + np.sin(ph) ** 2 / AY ** 2)) ** 2) * c
    np.testing.assert_allclose(w.square_to_ggx_pdf(v, AX, AY), ggx, rtol=1e-10)


def test_visible_normals_at_normal_incidence_are_d_cos():
    # wo = n: G1 = 1, cos(theta_o) = 1, so D_wo(h) = D(h) (h . n) (Heitz & d'Eon 2014, eq. 1).
    h = w.square_to_ggx(_random_u(1000), AX, AY)
    np.testing.assert_allclose(w.square_to_ggx_visible_pdf(h, [0, 1, 0], AX, AY),
                               w.square_to_ggx_pdf(h, AX, AY), rtol=1e-13)


def test_visible_normals_face_the_viewer():
    for wo in WO_LIST:
        h = w.square_to_ggx_visible(_random_u(5000), wo, AX, AY)
        assert np.all(h[:, 1] >= 0.0)
        assert np.all(h @ (wo / np.linalg.norm(wo)) >= -1e-12)


def test_sample_pdf_positive_in_the_interior_and_unit_directions():
    u = _random_u(20_000)
    for name, sample, pdf, _, domain, _, _ in WARPS:
        x = sample(u)
        assert np.all(pdf(x) > 0.0), name
        if domain in ("hemisphere", "sphere"):
            np.testing.assert_allclose(np.linalg.norm(x, axis=1), 1.0, atol=1e-14, err_msg=name)


def test_vectorised_equals_elementwise():
    u = _random_u(16)
    for name, sample, pdf, inverse, *_ in WARPS:
        batch = sample(u)
        single = np.concatenate([sample(u[i:i + 1]) for i in range(len(u))])
        np.testing.assert_array_equal(batch, single, err_msg=name)
        np.testing.assert_array_equal(pdf(batch), np.concatenate([pdf(batch[i:i + 1]) for i in range(16)]))


def test_empty_input_gives_empty_output():
    u = np.zeros((0, 2))
    assert w.square_to_cosine_hemisphere(u).shape == (0, 3)
    assert w.square_to_uniform_disk_concentric(u).shape == (0, 2)
    assert w.square_to_ggx_visible(u, [0, 1, 0], 0.3).shape == (0, 3)
    assert w.square_to_cosine_hemisphere_pdf(np.zeros((0, 3))).shape == (0,)


# ------------------------------------------------------------- statistics

@pytest.mark.parametrize("name,sample,pdf,inverse,domain,bounds,periodic", WARPS, ids=[c[0] for c in WARPS])
def test_chi2_sampler_matches_pdf(name, sample, pdf, inverse, domain, bounds, periodic):
    bins = (16, 16) if name == "triangle" else None  # fewer cells cut by the hypotenuse
    r = chi2_test(sample, pdf, domain, n=N_CHI2, rng=STREAMS[name], bounds=bounds, bins=bins,
                  significance=SIG)
    assert r.passed, r.message
    assert r.observed.sum() + r.outside_bounds == N_CHI2


@pytest.mark.parametrize("name,sample,pdf,domain", VNDF, ids=[c[0] for c in VNDF])
def test_chi2_visible_normals(name, sample, pdf, domain):
    r = chi2_test(sample, pdf, domain, n=N_CHI2, rng=STREAMS[name], significance=SIG)
    assert r.passed, r.message


@pytest.mark.parametrize("name,sample,pdf,inverse,domain,bounds,periodic", WARPS, ids=[c[0] for c in WARPS])
def test_pdf_integrates_to_one(name, sample, pdf, inverse, domain, bounds, periodic):
    if name == "triangle":
        # integrate over the triangle itself (its hypotenuse is no cell edge of
        # the square): the Duffy map (x, y) -> (x (1 - y), x y) has Jacobian x.
        def pdf_on_square(p, pdf=pdf):
            return pdf(np.stack([p[:, 0] * (1 - p[:, 1]), p[:, 0] * p[:, 1]], axis=-1)) * p[:, 0]
        pdf = pdf_on_square
    if name == "sphere_cone_offaxis":
        # the cone's rim cuts the (cos theta, phi) cells: integrate in the frame
        # about the centre's direction, where the rim is the cell edge cos = cos_max
        from mcvar.geometry import Frame
        fr, cmax = Frame(SPH_OFF / np.linalg.norm(SPH_OFF)), np.sqrt(1.0 - 0.64 / SPH_OFF.dot(SPH_OFF))

        def pdf_in_cone_frame(v, pdf=pdf):
            return pdf(fr.to_world(np.asarray(v, float)))
        pdf, bounds = pdf_in_cone_frame, ((cmax, 1.0), (0.0, TWO_PI))
    r = check_pdf_normalized(pdf, domain, bounds=bounds, atol=1e-6)
    assert r.passed, r.message


@pytest.mark.parametrize("i", range(len(WO_LIST)))
def test_visible_normal_pdf_integrates_to_one(i):
    r = check_pdf_normalized(VNDF[i][2], "hemisphere", atol=1e-5)
    assert r.passed, r.message


def test_flip_sphere_is_the_uniform_sphere():
    # Two-sample chi-square homogeneity test (contingency table of both
    # histograms) on independent streams: the lecture's coin-flip sampler and
    # the direct one draw the same distribution.
    ss = np.random.SeedSequence(SEED).spawn(2)
    a = w.square_to_uniform_sphere_flip(np.random.default_rng(ss[0]).random((100_000, 2)))
    b = w.square_to_uniform_sphere(np.random.default_rng(ss[1]).random((100_000, 2)))

    def hist(v):
        phi = np.mod(np.arctan2(v[:, 2], v[:, 0]), TWO_PI)
        return np.histogram2d(v[:, 1], phi, bins=(16, 32), range=((-1, 1), (0, TWO_PI)))[0].ravel()
    res = stats.chi2_contingency(np.stack([hist(a), hist(b)]))
    assert res.pvalue > SIG
    # and both halves are hit equally often (Binomial(n, 1/2) within 5 sigma)
    assert abs((a[:, 1] < 0).sum() - 50_000) <= 5 * np.sqrt(100_000 * 0.25)


def test_area_to_solid_angle_matches_the_rectangle_solid_angle():
    # A 1 x 0.5 rectangle light centred at height d above the shading point,
    # facing down: its solid angle is 4 arcsin(ab / sqrt((a^2 + 4d^2)(b^2 + 4d^2)))
    # (the rectangular-pyramid formula). E[1 / p_omega] over uniform area samples equals it.
    a, b, d = 1.0, 0.5, 0.8
    origin = np.array([-a / 2, d, -b / 2])
    e1, e2 = np.array([a, 0, 0]), np.array([0, 0, b])
    n = 200_000
    pts = w.square_to_uniform_parallelogram(_random_u(n), origin, e1, e2)
    pa = w.square_to_uniform_parallelogram_pdf(pts, origin, e1, e2)
    np.testing.assert_allclose(pa, 1 / (a * b))
    p_omega = w.area_to_solid_angle_pdf(pa, np.zeros(3), pts, np.array([0, -1.0, 0]))
    x = 1.0 / p_omega
    exact = 4 * np.arcsin(a * b / np.sqrt((a * a + 4 * d * d) * (b * b + 4 * d * d)))
    assert abs(x.mean() - exact) <= 5 * x.std(ddof=1) / np.sqrt(n)


def test_area_to_solid_angle_exact_values_and_edge_on():
    ref = np.zeros((3, 3))
    light = np.array([[0, 2.0, 0], [0, 2.0, 0], [3.0, 0, 0]])
    normals = np.array([[0, -1.0, 0], [0, -1, 1.0] / np.sqrt(2), [0, 1.0, 0]])
    got = w.area_to_solid_angle_pdf(np.array([0.5, 0.5, 0.5]), ref, light, normals)
    np.testing.assert_allclose(got, [0.5 * 4, 0.5 * 4 * np.sqrt(2), 0.0])
    assert w.area_to_solid_angle_pdf(1.0, [0, 0, 0], [0, 0, 0], [0, 1, 0]) == 0.0


def test_world_triangle_pdf_support_and_inverse():
    v0, v1, v2 = np.array([0.0, 1, 0]), np.array([2.0, 1, 0]), np.array([0.0, 1, 3])
    u = _random_u(1000)
    p = w.square_to_world_triangle(u, v0, v1, v2)
    np.testing.assert_allclose(w.square_to_world_triangle_pdf(p, v0, v1, v2), 1 / 3.0)
    np.testing.assert_allclose(w.world_triangle_to_square(p, v0, v1, v2), u, atol=1e-12)
    off = p + np.array([0, 1e-3, 0])  # off the plane
    assert np.all(w.square_to_world_triangle_pdf(off, v0, v1, v2) == 0.0)
    outside = np.array([[2.0, 1, 3]])
    assert w.square_to_world_triangle_pdf(outside, v0, v1, v2)[0] == 0.0
    # parallelogram inverse and outside points
    q = w.square_to_uniform_parallelogram(u, v0, v1 - v0, v2 - v0)
    np.testing.assert_allclose(w.uniform_parallelogram_to_square(q, v0, v1 - v0, v2 - v0), u, atol=1e-12)
    assert w.square_to_uniform_parallelogram_pdf(outside + [1, 0, 0], v0, v1 - v0, v2 - v0)[0] == 0.0


def test_pdfs_vanish_outside_support():
    below = np.array([[0.0, -1.0, 0.0], [0.6, -0.8, 0.0]])
    for f in (w.square_to_uniform_hemisphere_pdf, w.square_to_cosine_hemisphere_pdf,
              lambda v: w.square_to_phong_lobe_pdf(v, 5.0), lambda v: w.square_to_beckmann_pdf(v, 0.2),
              lambda v: w.square_to_ggx_pdf(v, 0.2), lambda v: w.square_to_uniform_cone_pdf(v, 0.5)):
        np.testing.assert_array_equal(f(below), 0.0)
    assert w.square_to_uniform_disk_concentric_pdf([[0.8, 0.8]])[0] == 0.0
    assert w.square_to_uniform_triangle_pdf([[0.6, 0.6], [-0.1, 0.5]]).tolist() == [0.0, 0.0]
    # back-facing microfacet normals are invisible
    assert w.square_to_ggx_visible_pdf([[0.0, 0.6, -0.8]], [0.0, 0.6, 0.8], 0.2)[0] == 0.0


# ------------------------------------------------------------- inverses

@pytest.mark.parametrize("name,sample,pdf,inverse,domain,bounds,periodic", WARPS, ids=[c[0] for c in WARPS])
def test_inverse_round_trip(name, sample, pdf, inverse, domain, bounds, periodic):
    r = check_inverse(sample, inverse, n=20_000, rng=SEED, atol=1e-9, periodic=(False, periodic))
    assert r.passed, r.message


# ------------------------------------------------------------- extremes

@pytest.mark.parametrize("name,sample,pdf,inverse,domain,bounds,periodic", WARPS, ids=[c[0] for c in WARPS])
def test_boundary_of_the_square(name, sample, pdf, inverse, domain, bounds, periodic):
    r = check_extremes(sample, pdf, domain)
    assert r.passed, r.message
    corners = np.array([[0.0, 0.0], [1.0, 1.0], [0.0, 1.0], [1.0, 0.0]])
    back = inverse(sample(corners))
    assert np.all((back >= 0) & (back <= 1))


@pytest.mark.parametrize("i", range(len(WO_LIST)))
def test_boundary_visible_normals(i):
    r = check_extremes(VNDF[i][1], VNDF[i][2], "hemisphere")
    assert r.passed, r.message


def test_horizon_directions_have_finite_pdfs():
    horizon = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [-0.6, 0.0, 0.8]])
    for f in (w.square_to_cosine_hemisphere_pdf, lambda v: w.square_to_beckmann_pdf(v, 1e-3),
              lambda v: w.square_to_ggx_pdf(v, 1e-3), lambda v: w.square_to_phong_lobe_pdf(v, 1e6)):
        p = f(horizon)
        assert np.all(np.isfinite(p)) and np.all(p == 0.0)
    np.testing.assert_array_equal(w.square_to_uniform_hemisphere_pdf(horizon), 1 / TWO_PI)
    # grazing wo: G1 / cos stays finite (2 / (alpha sin theta_o) in the limit)
    h = w.square_to_ggx_visible(_random_u(1000), [1.0, 0.0, 0.0], 0.3)
    p = w.square_to_ggx_visible_pdf(h, [1.0, 0.0, 0.0], 0.3)
    assert np.all(np.isfinite(h)) and np.all(np.isfinite(p)) and np.all(p >= 0)


@pytest.mark.parametrize("alpha", [1e-4, 1e-8, w.ALPHA_MIN])
def test_roughness_to_zero_concentrates_at_the_normal(alpha):
    u = np.concatenate([_random_u(1000), [[0, 0], [1, 1], [1, 0], [0.5, 0.5]]])
    for s, p in ((w.square_to_beckmann, w.square_to_beckmann_pdf), (w.square_to_ggx, w.square_to_ggx_pdf)):
        h = s(u, alpha)
        pdf = p(h, alpha)
        assert np.all(np.isfinite(h)) and np.all(np.isfinite(pdf))
        # all but the u0 = 1 (horizon) samples lie within ~alpha * few of the normal
        inner = u[:, 0] < 1.0 - 1e-6
        assert np.all(np.hypot(h[inner, 0], h[inner, 2]) <= 1e3 * alpha)
        assert np.all(pdf[inner] > 0)
    hv = w.square_to_ggx_visible(u, [0.6, 0.8, 0.0], alpha)
    assert np.all(np.isfinite(hv)) and np.all(np.isfinite(w.square_to_ggx_visible_pdf(hv, [0.6, 0.8, 0], alpha)))


@pytest.mark.parametrize("k", [1e3, 1e8, 1e300])
def test_huge_phong_exponent(k):
    u = np.concatenate([_random_u(1000), [[0, 0], [1, 1], [1e-300, 0.5]]])
    v = w.square_to_phong_lobe(u, k)
    p = w.square_to_phong_lobe_pdf(v, k)
    assert np.all(np.isfinite(v)) and np.all(np.isfinite(p))
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-15)
    # sin(theta) = sqrt(1 - u0^(2/(k+1))) keeps full precision (not 0 from 1 - cos^2)
    s_expected = np.sqrt(-np.expm1(2 * np.log(u[:1000, 0]) / (k + 1)))
    np.testing.assert_allclose(np.hypot(v[:1000, 0], v[:1000, 2]), s_expected, rtol=1e-12)


def test_tiny_cone():
    c = np.cos(1e-5)
    v = w.square_to_uniform_cone(np.array([[0, 0], [1, 1], [1, 0.3]]), c)
    p = w.square_to_uniform_cone_pdf(v, c)
    assert np.all(np.isfinite(p)) and np.all(p > 0)


# ------------------------------------------------------------- bad input

@pytest.mark.parametrize("u,match", [
    (np.zeros((4, 3)), r"u must have shape \(n, 2\)"),
    (np.zeros(4), "u must have 2 dimensions"),
    (np.array([[0.5, np.nan]]), "u must be finite"),
    (np.array([[0.5, 1.0 + 1e-12]]), r"u must lie in \[0, 1\]"),
    (np.array([[-0.1, 0.5]]), r"u must lie in \[0, 1\]"),
])
def test_bad_u(u, match):
    for f in (w.square_to_cosine_hemisphere, w.square_to_uniform_sphere,
              lambda x: w.square_to_ggx(x, 0.2), w.square_to_uniform_triangle):
        with pytest.raises(ValueError, match=match):
            f(u)


def test_bad_parameters():
    u = _random_u(4)
    with pytest.raises(ValueError, match="alpha must be finite and > 0"):
        w.square_to_beckmann(u, 0.0)
    with pytest.raises(ValueError, match="alpha_y must be finite and > 0"):
        w.square_to_ggx(u, 0.2, -1.0)
    with pytest.raises(ValueError, match="alpha_x must be >= 1e-100"):
        w.square_to_ggx_pdf(np.array([[0, 1.0, 0]]), 1e-200)
    with pytest.raises(TypeError, match="alpha must be a real number"):
        w.square_to_beckmann(u, "rough")
    with pytest.raises(ValueError, match=r"cos_theta_max must lie in \[-1, 1\)"):
        w.square_to_uniform_cone(u, 1.0)
    with pytest.raises(ValueError, match=r"cos_theta_max must lie in \[-1, 1\)"):
        w.square_to_uniform_cone_pdf(np.array([[0, 1.0, 0]]), np.nan)
    with pytest.raises(ValueError, match="exponent must be finite and >= 0"):
        w.square_to_phong_lobe(u, -1.0)
    with pytest.raises(ValueError, match="exponent must be finite and >= 0"):
        w.square_to_phong_lobe(u, np.inf)
    with pytest.raises(ValueError, match="wo must lie in the upper hemisphere"):
        w.square_to_ggx_visible(u, [0, -0.6, 0.8], 0.2)
    with pytest.raises(ValueError, match=r"wo must have shape \(3,\) or \(4, 3\)"):
        w.square_to_ggx_visible(u, np.ones((3, 3)), 0.2)
    with pytest.raises(ValueError, match="v must be finite"):
        w.square_to_cosine_hemisphere_pdf([[np.nan, 1.0, 0.0]])
    with pytest.raises(ValueError, match=r"v must have shape \(\.\.\., 3\)"):
        w.square_to_uniform_sphere_pdf(np.ones((2, 2)))
    with pytest.raises(ValueError, match="triangle v0, v1, v2 must be non-degenerate"):
        w.square_to_world_triangle(u, [0, 0, 0], [1, 0, 0], [2, 0, 0])
    with pytest.raises(ValueError, match=r"origin must have shape \(3,\) or \(4, 3\)"):
        w.square_to_uniform_parallelogram(u, np.zeros((2, 3)), [1, 0, 0], [0, 0, 1])
    with pytest.raises(ValueError, match="pdf_area must be non-negative"):
        w.area_to_solid_angle_pdf(-1.0, [0, 0, 0], [0, 1, 0], [0, -1, 0])
    with pytest.raises(ValueError, match="light_normals must be non-zero"):
        w.area_to_solid_angle_pdf(1.0, [0, 0, 0], [0, 1, 0], [0, 0, 0])
    with pytest.raises(ValueError, match="must broadcast together"):
        w.area_to_solid_angle_pdf(np.ones(3), np.zeros((2, 3)), [0, 1, 0], [0, -1, 0])


def test_sphere_from_point_bad_input_and_known_values():
    u = np.full((2, 2), 0.5)
    ref = np.zeros((2, 3))
    with pytest.raises(ValueError, match="radius"):
        w.square_to_sphere_from_point(u, ref, SPH_C, 0.0)
    with pytest.raises(ValueError, match="ref"):
        w.square_to_sphere_from_point(u, np.full((2, 3), np.nan), SPH_C, 1.0)
    with pytest.raises(ValueError, match="one row per sample"):
        w.square_to_sphere_from_point(u, np.zeros((3, 3)), SPH_C, 1.0)
    # u0 = 0: the direction to the centre, at distance d - r; pdf 1 / (2 pi (1 - cos theta_max))
    v, t = w.square_to_sphere_from_point(np.array([[0.0, 0.3]]), np.zeros((1, 3)), SPH_C, 1.0)
    np.testing.assert_allclose(v, [[0.0, 1.0, 0.0]], atol=1e-15)
    np.testing.assert_allclose(t, [2.0], rtol=1e-15)
    cmax = np.sqrt(8.0 / 9.0)
    np.testing.assert_allclose(w.square_to_sphere_from_point_pdf(v, np.zeros((1, 3)), SPH_C, 1.0),
                               [1.0 / (2 * np.pi * (1 - cmax))], rtol=1e-12)
    # u0 = 1: the rim, tangent: the point lies on the sphere at the cone's edge
    v, t = w.square_to_sphere_from_point(np.array([[1.0, 0.7]]), np.zeros((1, 3)), SPH_C, 1.0)
    np.testing.assert_allclose(v[0, 1], cmax, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(v * t[:, None] - SPH_C, axis=1), [1.0], rtol=1e-12)
    # a far, tiny sphere: 1 - cos theta_max without cancellation (r/d = 1e-9)
    p = w.square_to_sphere_from_point_pdf(np.array([[0.0, 1.0, 0.0]]), np.zeros((1, 3)), [0.0, 1.0, 0.0], 1e-9)
    np.testing.assert_allclose(p, [1.0 / (np.pi * 1e-18)], rtol=1e-9)
    # outside the cone: exactly 0
    assert w.square_to_sphere_from_point_pdf(np.array([[1.0, 0.0, 0.0]]), np.zeros((1, 3)), SPH_C, 1.0)[0] == 0.0
