"""Tests for mcvar.envmap: the direction <-> pixel mapping at every edge, the
three samplers against their pdfs (exactly, then by chi-square), unbiased
irradiance against an exact pixel sum, the variance the lecture's importance
sampling saves, MIS, the extremes and every error path."""
import math
import tracemalloc
import warnings

import numpy as np
import pytest
from scipy import stats

from mcvar import warps
from mcvar.envmap import (
    METHODS,
    EnvironmentMap,
    constant,
    gradient,
    sky_with_sun,
    sparse_lights,
)
from mcvar.estimators import estimate, power_heuristic
from mcvar.geometry import Frame, spherical_to_direction
from mcvar.images import write_image
from mcvar.testing import chi2_test

SEED = 0x5EED_E7A9
Z = stats.norm.isf(0.5e-6)  # two-sided alpha = 1e-6 per comparison (~4.9 sigma)
IMPORTANCE = ("importance", "importance2d")


def _random_map(rng, h=8, w=16):
    """A map with a fully black row, a black column, and light-tailed values."""
    img = rng.random((h, w, 3)) ** 3
    img[h // 2 - 1] = 0.0
    img[:, 3] = 0.0
    return img


def _pixel_grid(env):
    return np.meshgrid(np.arange(env.height), np.arange(env.width), indexing="ij")


def _cdf_rtol(env):
    """Relative rounding of a probability taken as a CDF step: each CDF entry
    is a float64 sum of at most H W terms below 1 (error <= H W eps), so a
    step P carries a relative error <= 2 H W eps / P (Higham, *Accuracy and
    Stability of Numerical Algorithms*, 2nd ed., 2002, sec. 4.2)."""
    p = env.pixel_probabilities()
    return 2 * p.size * np.finfo(float).eps / p[p > 0].min()


def _tilted():
    n = np.array([0.35, 0.8, -0.45])
    return n / np.linalg.norm(n)


# --------------------------------------------------------------------------
# mapping: exact facts
# --------------------------------------------------------------------------

@pytest.mark.parametrize("shape", [(1, 2), (3, 5), (8, 16), (33, 64)])
def test_pixel_centres_have_no_half_texel_offset(shape):
    env = EnvironmentMap(np.ones(shape + (3,)))
    i, j = _pixel_grid(env)
    centres = env.pixel_to_direction(i, j)
    theta = (i + 0.5) * math.pi / shape[0]
    phi = (j + 0.5) * 2 * math.pi / shape[1]
    np.testing.assert_allclose(centres, spherical_to_direction(theta, phi), atol=1e-15)
    i2, j2 = env.direction_to_pixel(centres)
    np.testing.assert_array_equal(i2, i)
    np.testing.assert_array_equal(j2, j)


def test_pixel_edges_belong_to_the_pixel_after_them():
    # pixel (i, j) covers theta in [i pi/H, (i+1) pi/H), phi in [j 2pi/W, ...)
    h, w = 6, 12
    env = EnvironmentMap(np.ones((h, w, 3)))
    eps = 1e-9
    for i in range(1, h):
        for sign, want in ((-1, i - 1), (1, i)):
            d = spherical_to_direction(i * math.pi / h + sign * eps, 0.3)
            assert env.direction_to_pixel(d)[0] == want
    for j in range(1, w):
        for sign, want in ((-1, j - 1), (1, j)):
            d = spherical_to_direction(1.0, j * 2 * math.pi / w + sign * eps)
            assert env.direction_to_pixel(d)[1] == want


def test_poles_and_seam():
    h, w = 4, 8
    env = EnvironmentMap(np.ones((h, w, 3)))
    i, j = env.direction_to_pixel(np.array([[0, 1, 0], [0, -1, 0], [1, 0, -1e-300], [1, 0, 0]]))
    np.testing.assert_array_equal(i, [0, h - 1, h // 2, h // 2])
    np.testing.assert_array_equal(j[2:], [0, 0])  # phi just below 2 pi rounds to 0: never column W


def test_single_hot_pixel_is_seen_only_inside_its_pixel():
    h, w = 9, 18
    img = np.zeros((h, w, 3))
    img[4, 7] = (3.0, 2.0, 1.0)
    env = EnvironmentMap(img)
    i, j = _pixel_grid(env)
    lit = np.any(env.radiance(env.pixel_to_direction(i, j)) > 0, axis=-1)
    np.testing.assert_array_equal(lit, (i == 4) & (j == 7))
    # bilinear at a pixel centre is the pixel's value (to the rounding of the
    # centre's direction -> (theta, phi) round trip)
    np.testing.assert_allclose(env.radiance(env.pixel_to_direction(i, j), interpolation="bilinear"), img,
                               rtol=0, atol=1e-12 * img.max())


def test_bilinear_wraps_in_phi_and_never_leaks_across_the_poles():
    h, w = 4, 8
    img = np.zeros((h, w, 3))
    img[0] = 1.0       # top row
    img[-1] = 100.0    # bottom row
    img[1:3, 0] = 10.0
    env = EnvironmentMap(img)
    # near the north pole only the top row contributes (no blend with the bottom row)
    ring = np.linspace(0, 2 * math.pi, 50, endpoint=False)
    north = spherical_to_direction(np.full(50, 1e-6), ring)
    np.testing.assert_allclose(env.radiance(north, interpolation="bilinear"), 1.0, rtol=1e-12)
    south = spherical_to_direction(np.full(50, math.pi - 1e-6), ring)
    np.testing.assert_allclose(env.radiance(south, interpolation="bilinear"), 100.0, rtol=1e-12)
    # at phi = 0 (the seam) column 0 and column W-1 blend half and half
    seam = spherical_to_direction(1.5 * math.pi / h, 0.0)  # centre of row 1 in theta
    np.testing.assert_allclose(env.radiance(seam, interpolation="bilinear"), 5.0, rtol=1e-12)


def test_pixel_solid_angles_sum_to_four_pi_and_match_sine_weights():
    for h in (1, 2, 7, 64):
        env = constant(1.0, height=h, width=3)
        assert math.isclose(env.pixel_solid_angle.sum() * env.width, 4 * math.pi, rel_tol=1e-14)
        # 'Creating A PDF': sin(theta_centre) is exactly proportional to the solid angle
        ratio = env.pixel_solid_angle / np.sin((np.arange(h) + 0.5) * math.pi / h)
        np.testing.assert_allclose(ratio, ratio[0], rtol=1e-13)


# --------------------------------------------------------------------------
# sampling: exact facts
# --------------------------------------------------------------------------

@pytest.mark.parametrize("method", IMPORTANCE)
def test_pdf_integrates_to_one_exactly(method):
    env = EnvironmentMap(_random_map(np.random.default_rng(SEED)))
    i, j = _pixel_grid(env)
    pdf = env.pdf(env.pixel_to_direction(i, j), method=method)  # constant over each pixel
    assert math.isclose(np.sum(pdf * env.pixel_solid_angle[:, None]), 1.0, rel_tol=1e-13)
    assert np.all(pdf[env.luminance == 0] == 0) and np.all(pdf[env.luminance > 0] > 0)


@pytest.mark.parametrize("method", METHODS)
def test_pdf_integrates_to_one_by_monte_carlo(method):
    # an independent check: E_uniform[pdf / (1 / 4 pi)] = 1
    env = sparse_lights(height=32, width=64)
    d = warps.square_to_uniform_sphere(np.random.default_rng(SEED).random((400_000, 2)))
    ratio = 4 * math.pi * env.pdf(d, method=method)
    se = ratio.std(ddof=1) / math.sqrt(ratio.size)
    assert abs(ratio.mean() - 1.0) <= Z * se + 1e-12


@pytest.mark.parametrize("method", METHODS)
def test_pdf_of_sample_equals_returned_pdf_even_at_edges(method):
    rng = np.random.default_rng(SEED)
    env = EnvironmentMap(_random_map(rng))
    prob = env.pixel_probabilities().ravel()
    cdf = np.cumsum(prob) / prob.sum()
    edge = np.array([0.0, 1.0, 0.5, 1 - 2 ** -53])
    u = np.concatenate([
        rng.random((20_000, 2)),
        np.stack(np.meshgrid(edge, edge), -1).reshape(-1, 2),          # corners of the square
        np.stack([cdf, rng.random(cdf.size)], -1),                    # exactly on CDF steps
        np.stack([rng.random(cdf.size), np.clip(cdf * 4 % 1, 0, 1)], -1),
    ])
    d, p = env.sample(u, method=method)
    assert d.shape == (u.shape[0], 3) and p.shape == (u.shape[0],)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-15)
    np.testing.assert_array_equal(env.pdf(d, method=method), p)
    assert np.all(p > 0)
    if method != "uniform":
        i, j = env.direction_to_pixel(d)
        assert np.all(env.luminance[i, j] > 0)  # zero rows/columns never sampled


@pytest.mark.parametrize("method", IMPORTANCE)
def test_u_exactly_zero_and_one_pick_first_and_last_nonzero_pixel(method):
    img = np.zeros((5, 6, 3))
    img[1, 2] = 1.0
    img[3, 4] = 2.0
    env = EnvironmentMap(img)
    d, p = env.sample(np.array([[0.0, 0.0], [1.0, 1.0], [0.0, 1.0], [1.0, 0.0]]), method=method)
    i, j = env.direction_to_pixel(d)
    assert set(zip(i.tolist(), j.tolist())) <= {(1, 2), (3, 4)}
    assert (int(i[0]), int(j[0])) == (1, 2) and (int(i[1]), int(j[1])) == (3, 4)
    assert np.all(np.isfinite(p)) and np.all(p > 0)


@pytest.mark.parametrize("method", IMPORTANCE)
@pytest.mark.parametrize("shape,pixel", [((1, 2), (0, 1)), ((6, 10), (0, 3)), ((6, 10), (5, 9)), ((6, 10), (2, 0))])
def test_single_hot_pixel_takes_every_sample(method, shape, pixel):
    img = np.zeros(shape + (3,))
    img[pixel] = 5.0
    env = EnvironmentMap(img)
    u = np.random.default_rng(SEED).random((5000, 2))
    d, p = env.sample(u, method=method)
    i, j = env.direction_to_pixel(d)
    assert np.all(i == pixel[0]) and np.all(j == pixel[1])
    np.testing.assert_allclose(p, 1.0 / env.pixel_solid_angle[pixel[0]], rtol=1e-12)
    # the pixel's directions are uniform in cos(theta) between its edges
    cos_lo, cos_hi = np.cos((pixel[0] + 1) * math.pi / shape[0]), np.cos(pixel[0] * math.pi / shape[0])
    t = (d[:, 1] - cos_lo) / (cos_hi - cos_lo)
    assert stats.kstest(t, "uniform").pvalue > 1e-4


@pytest.mark.parametrize("method", IMPORTANCE)
def test_importance_is_zero_variance_for_the_maps_own_luminance(method):
    # pdf = Y / sum(Y Omega) exactly, so Y / pdf is the same for every sample
    env = sky_with_sun(height=32, width=64)
    d, p = env.sample(np.random.default_rng(SEED).random((10_000, 2)), method=method)
    y = env.radiance(d) @ np.array([0.2126, 0.7152, 0.0722])
    total = np.sum(env.luminance * env.pixel_solid_angle[:, None])
    np.testing.assert_allclose(y / p, total, rtol=_cdf_rtol(env))


def test_one_and_two_dimensional_tables_give_the_same_distribution():
    env = EnvironmentMap(_random_map(np.random.default_rng(SEED), 17, 40))
    d = warps.square_to_uniform_sphere(np.random.default_rng(SEED + 1).random((50_000, 2)))
    np.testing.assert_allclose(env.pdf(d, method="importance2d"), env.pdf(d, method="importance"),
                               rtol=2 * _cdf_rtol(env), atol=0)


def test_empty_input_gives_empty_output():
    env = constant(1.0)
    for method in METHODS:
        d, p = env.sample(np.zeros((0, 2)), method=method)
        assert d.shape == (0, 3) and p.shape == (0,)
        assert env.pdf(np.zeros((0, 3)), method=method).shape == (0,)
    assert env.radiance(np.zeros((0, 3))).shape == (0, 3)


# --------------------------------------------------------------------------
# statistics: samples against pdfs
# --------------------------------------------------------------------------

@pytest.mark.parametrize("method", METHODS)
def test_chi_square_sampler_against_pdf(method):
    # A 3-row map has its row edges at cos(theta) = 1, 1/2, -1/2, -1, which are
    # edges of chi2_test's 16 uniform cos(theta) bins, and its 16 columns are
    # edges of the 32 phi bins: the pdf is constant on every cell, so the
    # expected counts are exact. Row 0 (at the pole) and column 3 are black.
    env = EnvironmentMap(_random_map(np.random.default_rng(SEED), 3, 16))
    result = chi2_test(lambda u: env.sample(u, method=method), lambda d: env.pdf(d, method=method),
                       "sphere", n=200_000, rng=SEED, bins=(16, 32), test_count=len(METHODS))
    assert result.passed, result.message


@pytest.mark.parametrize("method", IMPORTANCE)
def test_chi_square_on_pixel_subcells_of_sparse_lights(method):
    # An exact second test on a map with tiny features: cells are the pixels
    # split 2 x 2 (halves in cos(theta) and phi, equal solid angle), whose
    # expected counts n P_ij / 4 need no quadrature. Cells expecting < 5
    # samples are pooled (Mitsuba's chi2 rule).
    env = sparse_lights(height=64, width=128)
    n = 400_000
    d, _ = env.sample(np.random.default_rng(SEED).random((n, 2)), method=method)
    i, j = env.direction_to_pixel(d)
    c0, c1 = np.cos(i * math.pi / env.height), np.cos((i + 1) * math.pi / env.height)
    sub_t = ((c0 - d[:, 1]) / (c0 - c1) >= 0.5).astype(int)
    phi = np.arctan2(d[:, 2], d[:, 0]) % (2 * math.pi)
    sub_p = (phi * env.width / (2 * math.pi) - j >= 0.5).astype(int)
    cell = ((i * env.width + j) * 2 + sub_t) * 2 + sub_p
    observed = np.bincount(cell, minlength=4 * env.height * env.width).astype(float)
    expected = np.repeat(n * env.pixel_probabilities().ravel() / 4, 4)
    assert observed[expected == 0].sum() == 0
    small = expected < 5
    obs = np.append(observed[~small], observed[small].sum())
    exp = np.append(expected[~small], expected[small].sum())
    keep = exp > 0
    stat = np.sum((obs[keep] - exp[keep]) ** 2 / exp[keep])
    pvalue = stats.chi2.sf(stat, keep.sum() - 1)
    assert pvalue > 1e-3 / 2, (stat, keep.sum() - 1)


def _irradiance_estimates(env, normal, method, n, rng):
    f = lambda d: env.radiance(d) * np.maximum(0.0, d @ normal)[:, None]  # noqa: E731
    return estimate(f, sample=lambda u: env.sample(u, method=method)[0],
                    pdf=lambda d: env.pdf(d, method=method), n=n, rng=rng)


@pytest.mark.parametrize("make", [lambda: sky_with_sun(height=32, width=64),
                                  lambda: sparse_lights(height=64, width=128),
                                  lambda: gradient((1, 2, 3), 0.5, height=5, width=7)],
                         ids=["sky_with_sun", "sparse_lights", "gradient"])
@pytest.mark.parametrize("method", METHODS)
def test_irradiance_is_unbiased(make, method):
    env = make()
    normal = _tilted()
    exact = env.irradiance(normal)
    est = _irradiance_estimates(env, normal, method, 200_000, np.random.default_rng(SEED))
    assert np.all(np.abs(est.mean - exact) <= Z * est.stderr), (est.mean, exact, est.stderr)


def _clipped_cos2(env, normal, k):
    """Per-pixel ``integral of max(0, n . w)^2 dw`` by a k x k midpoint rule
    aligned with each pixel (error O(1/k^2): max(0, x)^2 is C^1)."""
    h, w = env.height, env.width
    th = (np.arange(h * k) + 0.5) * math.pi / (h * k)
    ph = (np.arange(w * k) + 0.5) * 2 * math.pi / (w * k)
    out = np.empty((h, w))
    for r in range(h):  # a band of k sub-rows at a time keeps memory at O(k^2 W)
        t = th[r * k:(r + 1) * k]
        d = spherical_to_direction(*np.meshgrid(t, ph, indexing="ij"))
        c = np.maximum(0.0, d @ normal) ** 2 * np.sin(t)[:, None]
        out[r] = c.reshape(k, w, k).sum(axis=(0, 2)) * (math.pi / (h * k)) * (2 * math.pi / (w * k))
    return out


def _exact_variances(env, normal, channel, k):
    """Per-sample variances of the uniform and importance irradiance
    estimators of the nearest-lookup map, ``integral of f^2 / p dw - E^2``:
    ``f^2 / p`` is ``L_ij^2 cos+^2`` times the constant ``4 pi`` (uniform) or
    ``Omega_i / P_ij`` (importance) inside each pixel."""
    c = _clipped_cos2(env, normal, k)
    lum2 = env.image[..., channel] ** 2
    e = env.irradiance(normal)[channel]
    prob = env.pixel_probabilities()
    lit = prob > 0
    uniform = 4 * math.pi * np.sum(lum2 * c) - e * e
    importance = np.sum((lum2 * c * env.pixel_solid_angle[:, None])[lit] / prob[lit]) - e * e
    return uniform, importance


def _variance_and_se(x):
    """Sample variance and its standard error, ``sqrt((m4 - s^4) / n)`` (the
    sampling distribution of a variance, any finite-kurtosis population)."""
    v = x.var(ddof=1)
    m4 = np.mean((x - x.mean()) ** 4)
    return v, math.sqrt(max(m4 - v * v, 0.0) / x.size)


@pytest.mark.parametrize("name,make,factor", [
    ("sun", lambda: sky_with_sun(height=64, width=128), 4498.0),
    ("sparse", lambda: sparse_lights(height=64, width=128), 378.1),
], ids=["sun", "sparse"])
def test_importance_sampling_beats_uniform_by_the_exact_factor(name, make, factor):
    # The lecture's 'Uniform vs. Importance' slides, measured and derived:
    # per-sample variance of the irradiance estimate (green channel) at a
    # tilted normal. The exact variances come from the pixel sums of f^2 / p
    # (midpoint rule at k = 16 per pixel side, its error bounded by twice the
    # change from k = 8); the measured ones must agree with them within Z
    # standard errors of a sample variance. The factor (uniform / importance)
    # is quoted in docs/envmap.md: ~4500x on the sun map, ~380x on the
    # sparse lights.
    env = make()
    normal = _tilted()
    exact_u, exact_i = _exact_variances(env, normal, 1, 16)
    coarse_u, coarse_i = _exact_variances(env, normal, 1, 8)
    assert math.isclose(exact_u / exact_i, factor, rel_tol=1e-3), exact_u / exact_i
    n = 200_000
    for method, exact, coarse, rng in zip(("uniform", "importance"), (exact_u, exact_i), (coarse_u, coarse_i),
                                          np.random.default_rng(SEED).spawn(2)):
        d, p = env.sample(rng.random((n, 2)), method=method)
        x = env.radiance(d)[:, 1] * np.maximum(0.0, d @ normal) / p
        v, se = _variance_and_se(x)
        assert abs(v - exact) <= Z * se + 2 * abs(exact - coarse), (name, method, v, exact, se)


@pytest.mark.parametrize("make", [lambda: sky_with_sun(height=64, width=128),
                                  lambda: sparse_lights(height=64, width=128)], ids=["sun", "sparse"])
def test_mis_with_cosine_sampling_is_unbiased_and_never_worse_than_the_worse_strategy(make):
    # One sample from each strategy per pair, power heuristic (Veach 1997,
    # eq. 9.13); compare the pair's variance with each strategy's two-sample
    # variance, with the 1e-6 margin of the variance's sampling distribution
    # estimated from the fourth central moment.
    env = make()
    normal = _tilted()
    frame = Frame(normal)
    exact = env.irradiance(normal)[1]
    n = 200_000
    r_env, r_cos = np.random.default_rng(SEED).spawn(2)

    def f(d):
        return env.radiance(d)[:, 1] * np.maximum(0.0, d @ normal)

    def cos_sample(u):
        return frame.to_world(warps.square_to_cosine_hemisphere(u))

    def cos_pdf(d):
        return np.maximum(0.0, d @ normal) / math.pi

    d1, p1 = env.sample(r_env.random((n, 2)), method="importance")
    d2 = cos_sample(r_cos.random((n, 2)))
    p2 = cos_pdf(d2)
    c_env = f(d1) / p1
    c_cos = np.where(p2 > 0, f(d2) / np.where(p2 > 0, p2, 1.0), 0.0)
    mis = (power_heuristic(p1, cos_pdf(d1)) * c_env
           + power_heuristic(p2, env.pdf(d2, method="importance")) * c_cos)
    se = mis.std(ddof=1) / math.sqrt(n)
    assert abs(mis.mean() - exact) <= Z * se

    v_mis, s_mis = _variance_and_se(mis)
    worse = max(_variance_and_se(c_env), _variance_and_se(c_cos))
    assert v_mis - Z * s_mis <= 0.5 * (worse[0] + Z * worse[1])


# --------------------------------------------------------------------------
# extremes
# --------------------------------------------------------------------------

def test_all_black_map_falls_back_to_uniform_with_a_warning():
    env = EnvironmentMap(np.zeros((4, 8, 3)))
    u = np.random.default_rng(SEED).random((1000, 2))
    with pytest.warns(RuntimeWarning, match="zero luminance everywhere"):
        d, p = env.sample(u, method="importance")
    np.testing.assert_allclose(p, 1 / (4 * math.pi))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # warned once per map, not per call
        np.testing.assert_allclose(env.pdf(d, method="importance"), 1 / (4 * math.pi))
    with pytest.warns(RuntimeWarning):
        _, p2 = EnvironmentMap(np.zeros((1, 2, 3))).sample(u, method="importance2d")
    np.testing.assert_allclose(p2, 1 / (4 * math.pi))
    assert np.all(env.radiance(d) == 0)
    np.testing.assert_array_equal(env.pixel_probabilities(), 0.0)


def test_large_map_memory_is_bounded():
    # 4096 x 2048: tables are O(H W); sampling n directions is O(n) (an
    # n x H W temporary would be 10^4 x 8.4M doubles = 670 GB)
    h, w = 2048, 4096
    img = np.zeros((h, w, 3))
    img[h // 3, 100:200] = 7.0
    img[-1, -1] = 1.0  # the very last pixel (south pole row, seam column)
    env = EnvironmentMap(img)
    n = 10_000
    u = np.random.default_rng(SEED).random((n, 2))
    u[:2] = [[0.0, 0.0], [1.0, 1.0]]
    table_bytes = h * w * 8
    for method in IMPORTANCE:
        # building a method's tables keeps two H x W float64 arrays and peaks
        # at four (the documented bound; 1 % for small per-row arrays)
        tracemalloc.start()
        env.sample(u[:1], method=method)
        kept, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        assert kept <= 2.01 * table_bytes and peak <= 4.01 * table_bytes, (kept / table_bytes, peak / table_bytes)
        tracemalloc.start()
        d, p = env.sample(u, method=method)
        q = env.pdf(d, method=method)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert peak < 200 * n * 8, peak  # a couple of hundred doubles per sample
        np.testing.assert_array_equal(p, q)
        i, j = env.direction_to_pixel(d)
        assert np.all(env.luminance[i, j] > 0)
        assert (int(i[1]), int(j[1])) == (h - 1, w - 1)


# --------------------------------------------------------------------------
# exact irradiance reference
# --------------------------------------------------------------------------

def test_irradiance_of_constant_map_is_pi_at_every_normal():
    env = constant((1.0, 2.0, 0.5), height=7, width=10)
    normals = np.random.default_rng(SEED).normal(size=(10, 3))
    normals = np.vstack([normals, [[0, 1, 0], [0, -1, 0], [1, 0, 0], [0, 0, -1]]])
    for n in normals:
        np.testing.assert_allclose(env.irradiance(n), math.pi * np.array([1.0, 2.0, 0.5]), rtol=1e-13)
    # the same through the quadrature's hard cases: normals grazing row edges
    for i in range(1, 7):
        n = spherical_to_direction(0.5 * math.pi - i * math.pi / 7 + 1e-9, 0.7)
        np.testing.assert_allclose(env.irradiance(n), math.pi * np.array([1.0, 2.0, 0.5]), rtol=1e-12)


def test_irradiance_closed_form_for_the_up_normal():
    # n = +y: K_i = dphi (sin^2 theta_{i+1} - sin^2 theta_i) / 2 on the upper half
    env = EnvironmentMap(_random_map(np.random.default_rng(SEED), 8, 12))
    te = np.arange(9) * math.pi / 8
    k = (2 * math.pi / 12) * 0.5 * np.maximum(0.0, np.diff(np.sin(np.minimum(te, math.pi / 2)) ** 2))
    np.testing.assert_allclose(env.irradiance((0, 1, 0)), np.einsum("ijc,i->c", env.image, k), rtol=1e-13)


def test_irradiance_matches_brute_force_quadrature():
    # A midpoint rule on a grid aligned with the pixels converges as h^2;
    # its error is bounded by the change between two grids (Richardson).
    env = EnvironmentMap(_random_map(np.random.default_rng(SEED), 6, 12))
    normal = _tilted()

    def midpoint(k):
        th = (np.arange(6 * k) + 0.5) * math.pi / (6 * k)
        ph = (np.arange(12 * k) + 0.5) * 2 * math.pi / (12 * k)
        d = spherical_to_direction(*np.meshgrid(th, ph, indexing="ij"))
        wgt = np.maximum(0, d @ normal) * np.sin(th)[:, None] * (math.pi / (6 * k)) * (2 * math.pi / (12 * k))
        return np.einsum("ijc,ij->c", env.radiance(d), wgt)

    coarse, fine = midpoint(100), midpoint(200)
    exact = env.irradiance(normal)
    assert np.all(np.abs(exact - fine) <= 2 * np.abs(fine - coarse) + 1e-12)
    np.testing.assert_allclose(env.irradiance(normal, nodes=32), exact, rtol=1e-13)


# --------------------------------------------------------------------------
# built-in maps and files
# --------------------------------------------------------------------------

def test_builtin_maps():
    g = gradient(top=(1.0, 2.0, 3.0), bottom=0.0, height=4, width=2)
    t = 0.5 * (1 + np.cos((np.arange(4) + 0.5) * math.pi / 4))
    np.testing.assert_allclose(g.image[:, 0, :], t[:, None] * [1.0, 2.0, 3.0])
    # sun: antialiased disk, its power ~ L 2 pi (1 - cos r) at any size
    for h in (32, 256):
        base = sky_with_sun(sun_radiance=1e-12, height=h, width=2 * h).power()
        sun = sky_with_sun(height=h, width=2 * h).power() - base
        expect = 2000 * 2 * math.pi * (1 - math.cos(math.radians(2))) * np.array([1, 0.95, 0.85])
        np.testing.assert_allclose(sun, expect, rtol=0.01)
    # lights at the poles: tints white then warm (1, 0.8, 0.55)
    s = sparse_lights(background=0.0, directions=[(0, 1, 0), (0, -1, 0)], height=64, width=128)
    omega = 2 * math.pi * (1 - math.cos(math.radians(3)))
    np.testing.assert_allclose(s.power(), 100 * omega * np.array([2.0, 1.8, 1.55]), rtol=0.01)
    assert s.image[0, 0, 0] > 0 and s.image[-1, 0, 0] > 0 and s.image[32, 0, 0] == 0


def test_from_file_round_trips(tmp_path):
    img = _random_map(np.random.default_rng(SEED), 4, 6)
    for suffix in (".npy", ".exr", ".hdr"):
        env = EnvironmentMap.from_file(write_image(tmp_path / f"m{suffix}", img))
        assert env.image.shape == img.shape
        np.testing.assert_allclose(env.image, img, rtol=2 ** -8, atol=2 ** -8 * img.max())
    (tmp_path / "bad.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4 +X 6\n\x02\x02")
    with pytest.raises(ValueError, match=r"bad\.hdr"):
        EnvironmentMap.from_file(tmp_path / "bad.hdr")


# --------------------------------------------------------------------------
# bad input
# --------------------------------------------------------------------------

def test_bad_images():
    img = np.ones((2, 4, 3))
    for value, message in ((np.nan, "finite"), (np.inf, "finite"), (-1e-3, "non-negative")):
        bad = img.copy()
        bad[1, 2, 0] = value
        with pytest.raises(ValueError, match=rf"{message}.*\(1, 2, 0\)"):
            EnvironmentMap(bad)
    with pytest.raises(ValueError, match=r"at least 1 row and 2 columns"):
        EnvironmentMap(np.ones((3, 1, 3)))
    with pytest.raises(ValueError, match=r"3 dimensions"):
        EnvironmentMap(np.ones((3, 4)))
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3\)"):
        EnvironmentMap(np.ones((3, 4, 4)))


def test_bad_arguments():
    env = constant(1.0)
    with pytest.raises(ValueError, match="method must be one of"):
        env.sample(np.zeros((1, 2)), method="cosine")
    with pytest.raises(ValueError, match="method must be one of"):
        env.pdf(np.ones((1, 3)), method="importance3d")
    with pytest.raises(ValueError, match="interpolation must be one of"):
        env.radiance(np.ones((1, 3)), interpolation="cubic")
    with pytest.raises(ValueError, match=r"u must lie in \[0, 1\]"):
        env.sample(np.array([[0.5, 1.5]]))
    with pytest.raises(ValueError, match="u must have shape"):
        env.sample(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="directions must hold unit vectors"):
        env.radiance(np.zeros((1, 3)))
    with pytest.raises(ValueError, match="directions must hold unit vectors"):
        env.pdf(np.zeros((2, 3)))  # issue 15: named 'v' before
    with pytest.raises(ValueError, match="directions must be finite"):
        env.pdf(np.array([[np.nan, 1.0, 0.0]]))
    with pytest.raises(ValueError, match="pixel indices"):
        env.pixel_to_direction(16, 0)
    with pytest.raises(TypeError, match="integer arrays"):
        env.pixel_to_direction(0.5, 0)
    with pytest.raises(ValueError, match="width must be >= 2"):
        constant(1.0, width=1)
    with pytest.raises(ValueError, match="radiance must be a scalar or an RGB triple"):
        constant((1.0, 2.0))
    with pytest.raises(ValueError, match="sun_radius_deg must be < 90"):
        sky_with_sun(sun_radius_deg=95.0)
    with pytest.raises(ValueError, match="background must be finite and >= 0"):
        sparse_lights(background=-1.0)
    with pytest.raises(TypeError, match="nodes must be an integer"):
        env.irradiance((0, 1, 0), nodes=4.0)
