"""Tests of mcvar.samplers: contracts first, exact facts, then statistics.

Statistical checks use large literal seeds and tolerances derived from the
null distribution (chi-square quantiles at alpha = 1e-3 with a Sidak
correction over the samplers tested, or 5 standard errors).
"""
import math
import warnings

import numpy as np
import pytest
from scipy import special, stats
from scipy.stats import qmc

from mcvar import samplers as S
from mcvar.discrepancy import is_net

NAMES = list(S.SAMPLERS)
RANDOMIZED = ["random", "jittered", "n_rooks", "multi_jittered", "sobol", "blue_noise"]
ALPHA = 1e-3


def _call(name, n, rng, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # sobol's non-power-of-2 warning
        return S.get_sampler(name)(n, rng=rng, **kw)


# ---------------------------------------------------------------- contracts

def test_registry_names_are_the_contract():
    # the built-in nine first, in this order; a sampler added later follows them
    assert NAMES[:9] == ["random", "grid", "jittered", "n_rooks", "multi_jittered",
                         "hammersley", "halton", "sobol", "blue_noise"]
    for name, record in S.SAMPLERS.items():
        assert isinstance(record, S.Sampler) and record.name == name
        assert S.get_sampler(name) is record.function and S.sampler_record(name) is record


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("n", [1, 16, 64, 256])
def test_shape_dtype_range_determinism(name, n):
    a = _call(name, n, 982_451_653)
    b = _call(name, n, np.random.default_rng(982_451_653))
    assert a.shape == (n, 2) and a.dtype == np.float64
    assert np.all(a >= 0.0) and np.all(a < 1.0)
    np.testing.assert_array_equal(a, b)
    if name in RANDOMIZED and n > 1:
        assert not np.array_equal(a, _call(name, n, 982_451_654))


@pytest.mark.parametrize("name,n", [("random", 10), ("n_rooks", 10), ("hammersley", 10),
                                    ("halton", 10), ("sobol", 8), ("grid", 27), ("jittered", 27)])
def test_dim_option(name, n):
    p = _call(name, n, 7_919, dim=3)
    assert p.shape == (n, 3) and np.all((p >= 0) & (p < 1))


def test_generator_state_advances():
    gen = np.random.default_rng(104_729)
    assert not np.array_equal(S.jittered(16, rng=gen), S.jittered(16, rng=gen))


# ---------------------------------------------------------------- exact facts

def test_radical_inverse_slide_example():
    # lecture slide "Hammersley Sampling": 13 = 1101_2 -> 0.1011_2 = 11/16 = 0.6875 (slide: 0.6975)
    assert S.radical_inverse(13, 2) == 11 / 16
    # 5 = 12_3 -> 0.21_3 = 2/3 + 1/9
    assert S.radical_inverse(5, 3) == pytest.approx(7 / 9, abs=1e-15)
    np.testing.assert_array_equal(S.radical_inverse(np.arange(8)), [0, .5, .25, .75, .125, .625, .375, .875])
    assert S.radical_inverse(0, 7) == 0.0


def test_hammersley_exact_values():
    n = 16
    p = S.hammersley(n)
    np.testing.assert_array_equal(p[:, 0], np.arange(n) / n)
    assert p[13, 1] == 0.6875
    # Phi_2 is a bijection of {0..15} onto {k/16}: n-rooks on the 16 x 16 grid
    assert sorted((p[:, 1] * n).astype(int)) == list(range(n))


def test_halton_equals_scipy_unscrambled():
    # scipy.stats.qmc.Halton is an independent implementation of the same sequence
    mine = S.halton(500, dim=4)
    theirs = qmc.Halton(4, scramble=False).random(500)
    np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-15)


def test_grid_is_cell_centres():
    p = S.grid(9)
    np.testing.assert_array_equal(np.unique(p[:, 0]), [1 / 6, 0.5, 5 / 6])
    assert len({tuple(r) for r in p}) == 9


@pytest.mark.parametrize("n", [1, 4, 64, 1024])
def test_jittered_one_point_per_stratum(n):
    k = math.isqrt(n)
    p = S.jittered(n, rng=15_485_863)
    cells = np.floor(p * k).astype(int)
    counts = np.bincount(cells[:, 0] * k + cells[:, 1], minlength=n)
    assert np.all(counts == 1)


def _rooks(p):
    n = p.shape[0]
    return all(sorted(np.floor(p[:, j] * n).astype(int)) == list(range(n)) for j in range(p.shape[1]))


@pytest.mark.parametrize("n", [1, 7, 12, 64, 1000])
def test_n_rooks_condition(n):
    assert _rooks(S.n_rooks(n, rng=32_452_843))
    assert _rooks(S.n_rooks(n, rng=32_452_843, dim=4))


@pytest.mark.parametrize("correlated", [True, False])
@pytest.mark.parametrize("n", [1, 12, 37, 64, 1024])
def test_multi_jittered_is_jittered_and_rooks(n, correlated):
    p = S.multi_jittered(n, rng=49_979_687, correlated=correlated)
    assert _rooks(p)
    nx, ny = S._mj_shape(n)
    assert nx * ny == n and ny <= nx
    cells = np.floor(p[:, 0] * nx).astype(int) * ny + np.floor(p[:, 1] * ny).astype(int)
    assert np.all(np.bincount(cells, minlength=n) == 1)


def _replicate_means(f, sampler, n, reps, seed, **kw):
    """Means of ``f`` over ``reps`` independent sets drawn through the public sampler."""
    return np.array([f(sampler(n, rng=g, **kw)).mean() for g in np.random.default_rng(seed).spawn(reps)])


def _f_test_p(var_big, var_small, reps):
    """One-sided p-value of H0: var_big <= var_small (F distribution, reps - 1 dof each)."""
    return stats.f.sf(var_big / var_small, reps - 1, reps - 1)


def test_multi_jittered_variance_claims():
    """The docstring's claims, by one-sided F-tests (Sidak over the three):
    on the smooth exp(xy) the default (uncorrelated) multi-jitter beats
    jittering and the correlated variant loses to it; on a disk's indicator
    the correlated variant beats the uncorrelated one. The old default
    (correlated) fails the first test: its variance was 8x jittered's at
    n = 1024, not lower (issue 15)."""
    reps, n = 300, 1024
    smooth = lambda p: np.exp(p[:, 0] * p[:, 1])  # noqa: E731
    disk = lambda p: ((p[:, 0] - 0.5) ** 2 + (p[:, 1] - 0.5) ** 2 < 0.16).astype(float)  # noqa: E731
    sig = 1.0 - (1.0 - ALPHA) ** (1.0 / 3.0)
    default = _replicate_means(smooth, S.multi_jittered, n, reps, 15_485_863)
    jit = _replicate_means(smooth, S.jittered, n, reps, 15_485_867)
    corr = _replicate_means(smooth, S.multi_jittered, n, reps, 15_485_917, correlated=True)
    exact = special.expi(1.0) - np.euler_gamma  # int_0^1 (e^x - 1) / x dx
    for est in (default, jit, corr):  # unbiased, 5 standard errors
        assert abs(est.mean() - exact) < 5.0 * est.std(ddof=1) / math.sqrt(reps)
    v_def, v_jit, v_corr = default.var(ddof=1), jit.var(ddof=1), corr.var(ddof=1)
    assert _f_test_p(v_jit, v_def, reps) < sig, (v_def, v_jit)
    assert _f_test_p(v_corr, v_jit, reps) < sig, (v_corr, v_jit)
    d_unc = _replicate_means(disk, S.multi_jittered, n, reps, 15_485_927)
    d_corr = _replicate_means(disk, S.multi_jittered, n, reps, 15_485_933, correlated=True)
    assert _f_test_p(d_unc.var(ddof=1), d_corr.var(ddof=1), reps) < sig


def test_correlated_multi_jittered_variance_closed_form():
    """For f = xy the correlated variant's variance is exactly (2 m^4 V1 + VZ) / n^6
    (docstring): a chi-square test of the replicate variance, Sidak over two n."""
    reps = 400
    sig = 1.0 - (1.0 - ALPHA) ** 0.5
    for n, seed in ((256, 32_452_867), (1024, 32_452_909)):
        m = math.isqrt(n)
        v1 = m ** 2 * (m - 1) * (m + 1) ** 2 / 144
        vz = (n - 1) * n * (2 * n - 1) / 36 + 7 * n / 144 + n * (n - 1) / 12
        exact_var = (2 * m ** 4 * v1 + vz) / n ** 6
        est = _replicate_means(lambda p: p[:, 0] * p[:, 1], S.multi_jittered, n, reps, seed, correlated=True)
        assert abs(est.mean() - 0.25) < 5.0 * math.sqrt(exact_var / reps)
        stat = (reps - 1) * est.var(ddof=1) / exact_var
        lo, hi = stats.chi2.ppf([sig / 2, 1 - sig / 2], reps - 1)
        assert lo < stat < hi, (n, est.var(ddof=1), exact_var)


@pytest.mark.parametrize("m", range(0, 11))
def test_hammersley_and_sobol_are_nets(m):
    n = 2 ** m
    assert is_net(S.hammersley(n), m)
    assert is_net(S.hammersley(n, scramble=True, rng=67_867_967), m)
    assert is_net(S.sobol(n, rng=67_867_967), m)
    assert is_net(S.sobol(n, scramble=False), m)


def test_cranley_patterson_and_digital_shift_extremes():
    gen = np.random.default_rng(86_028_121)
    edge = np.array([[0.0, 1.0], [S.ONE_MINUS_EPS, 0.5]])
    for _ in range(50):
        q = S.cranley_patterson(edge, gen)
        assert np.all((q >= 0) & (q < 1))
    # a shift is an isometry of the torus: toroidal differences are kept
    p = S.random(32, rng=gen)
    q = S.cranley_patterson(p, gen)
    np.testing.assert_allclose(np.mod(q - q[0], 1.0), np.mod(p - p[0], 1.0), atol=1e-12)
    # digital shift keeps the net and the range, even at 1 - eps
    d = S.digital_shift(np.vstack([S.sobol(64, scramble=False)]), gen)
    assert is_net(d, 6) and np.all(d < 1.0)
    assert np.all(S.digital_shift(edge[:, ::-1][:1] * 0 + S.ONE_MINUS_EPS, gen) < 1.0)


def test_blue_noise_poisson_disk_radius():
    # dart throwing keeps pairs >= r apart (toroidal distance); r starts at 0.7 r_max and can
    # only shrink by 3 % steps when throwing stalls. Uniform random points have a minimum
    # distance of order 1/n, far below 0.6 r_max ~ 0.64/sqrt(n): the check separates them.
    from scipy.spatial import cKDTree
    for n in (64, 1024):
        p = S.blue_noise(n, rng=122_949_829)
        dist, _ = cKDTree(p, boxsize=1.0).query(p, k=2)
        r_max = math.sqrt(2 / (math.sqrt(3) * n))
        assert dist[:, 1].min() >= 0.6 * r_max
        q = S.random(n, rng=122_949_829)
        assert cKDTree(q, boxsize=1.0).query(q, k=2)[0][:, 1].min() < 0.6 * r_max


def _achieved_radius(p):
    from scipy.spatial import cKDTree
    dist, _ = cKDTree(p, boxsize=1.0).query(p, k=2)
    return dist[:, 1].min() / math.sqrt(2 / (math.sqrt(3) * len(p)))


def test_blue_noise_achieves_what_its_docstring_says():
    """The docstring's table: 0.65 and 0.7 are met (n >= 256); 0.85 is not, it ends
    in the measured band 0.64-0.76, below what 0.7 gives (issue 15: the old docstring
    said 'slightly below')."""
    for n in (256, 1024):
        for rho in (0.65, 0.7):
            assert _achieved_radius(S.blue_noise(n, rng=1009, radius=rho)) >= rho * (1 - 1e-12)
        high = _achieved_radius(S.blue_noise(n, rng=1009, radius=0.85))
        assert 0.64 <= high <= 0.76
        assert high < 0.85 * 0.97  # it did shrink: the request is not reached


# ---------------------------------------------------------------- statistics

@pytest.mark.parametrize("name", NAMES)
def test_pixel_samples_each_point_uniform(name):
    """Every randomized point is U[0,1)^2: chi-square of point 0 of 4096 pixels on a 4 x 4 grid."""
    spp = 16
    p = S.pixel_samples(name, 4096, spp, dim=4, rng=179_424_673)
    alpha = 1 - (1 - ALPHA) ** (1 / (2 * len(NAMES)))  # Sidak over samplers and pairs
    for pair in (p[:, 0, 0:2], p[:, 3, 2:4]):
        cells = np.floor(pair * 4).astype(int)
        counts = np.bincount(cells[:, 0] * 4 + cells[:, 1], minlength=16)
        assert stats.chisquare(counts).pvalue > alpha


def test_scrambled_halton_uniform():
    gen = np.random.default_rng(373_587_883)
    first = np.array([S.halton(8, rng=g, scramble=True)[5] for g in gen.spawn(1000)])
    cells = np.floor(first * 4).astype(int)
    counts = np.bincount(cells[:, 0] * 4 + cells[:, 1], minlength=16)
    assert stats.chisquare(counts).pvalue > ALPHA


# ---------------------------------------------------------------- pixel_samples

@pytest.mark.parametrize("name", NAMES)
def test_pixel_samples_contract(name):
    a = S.pixel_samples(name, 50, 16, dim=5, rng=2_038_074_743)
    b = S.pixel_samples(name, 50, 16, dim=5, rng=np.random.default_rng(2_038_074_743))
    assert a.shape == (50, 16, 5) and a.dtype == np.float64
    assert np.all((a >= 0) & (a < 1))
    np.testing.assert_array_equal(a, b)
    # pixels hold different sets
    flat = a.reshape(50, -1)
    assert len({row.tobytes() for row in flat}) == 50


@pytest.mark.parametrize("name", ["jittered", "grid"])
def test_pixel_samples_stratified_per_pixel(name):
    p = S.pixel_samples(name, 300, 64, dim=4, rng=1_000_000_007)
    for pair in (p[..., 0:2], p[..., 2:4]):
        cells = np.floor(pair * 8).astype(int)
        ids = np.sort(cells[..., 0] * 8 + cells[..., 1], axis=1)
        assert np.all(ids == np.arange(64))


@pytest.mark.parametrize("name", ["n_rooks", "multi_jittered"])
def test_pixel_samples_rooks_per_pixel(name):
    p = S.pixel_samples(name, 300, 48, dim=3, rng=1_000_000_009)
    strata = np.sort(np.floor(p * 48).astype(int), axis=1)
    assert np.all(strata == np.arange(48)[None, :, None])


@pytest.mark.parametrize("name", ["sobol", "hammersley"])
def test_pixel_samples_nets_per_pixel(name):
    p = S.pixel_samples(name, 40, 64, dim=4, rng=2_147_483_647)
    assert all(is_net(p[i, :, 2 * k:2 * k + 2], 6) for i in range(40) for k in range(2))


def test_pixel_samples_pairs_are_decorrelated():
    """Padded pairs: within a pixel, dim 0 and dim 2 are in independent random order.

    Under independence Spearman's rho over spp points has mean 0 and variance exactly
    1/(spp - 1); rho^2 has mean 1/(spp - 1) and, with rho ~ N(0, 1/(spp - 1)), variance
    about 2/(spp - 1)^2. The mean over P pixels is tested within 5 standard errors.
    """
    spp, P = 16, 3000
    p = S.pixel_samples("sobol", P, spp, dim=4, rng=4_294_967_291)
    r0 = np.argsort(np.argsort(p[:, :, 0], axis=1), axis=1)
    r2 = np.argsort(np.argsort(p[:, :, 2], axis=1), axis=1)
    rho = 1 - 6 * np.sum((r0 - r2) ** 2, axis=1) / (spp * (spp ** 2 - 1))
    se = math.sqrt(2) / (spp - 1) / math.sqrt(P)
    assert abs(np.mean(rho ** 2) - 1 / (spp - 1)) < 5 * se
    assert abs(np.mean(rho)) < 5 / math.sqrt((spp - 1) * P)


def test_pixel_samples_odd_dim_and_one_pixel():
    p = S.pixel_samples("halton", 1, 1, dim=3, rng=5)
    assert p.shape == (1, 1, 3)


# ---------------------------------------------------------------- bad input

@pytest.mark.parametrize("name", NAMES)
def test_bad_n(name):
    fn = S.get_sampler(name)
    with pytest.raises(ValueError, match="n must be >= 0"):
        fn(-4)
    with pytest.raises(TypeError, match="n must be an integer"):
        fn(4.5)
    with pytest.raises(TypeError, match="n must be an integer"):
        fn("16")


@pytest.mark.parametrize("name", NAMES)
def test_n_zero_gives_an_empty_float64_set(name):
    """As scipy.stats.qmc (``Sobol(2).random(0).shape == (0, 2)``) and docs/conventions.md."""
    fn = S.get_sampler(name)
    p = fn(0, rng=3)
    assert p.shape == (0, 2) and p.dtype == np.float64
    if name not in ("multi_jittered", "blue_noise"):
        assert fn(0, rng=3, dim=3).shape == (0, 3)
    assert p.shape == qmc.Sobol(2, rng=0).random(0).shape


@pytest.mark.parametrize("name", NAMES)
def test_sizes_that_cannot_fit_are_refused_before_allocating(name):
    """2^40 points would need tens of TiB: a ValueError saying how much and what to do."""
    fn = S.get_sampler(name)
    with pytest.raises(ValueError, match=rf"{name}: n=1099511627776 points .* need about [0-9.]+ TiB"
                       r".*MAX_BYTES = 4 GiB.*smaller n \(at most [0-9]+ fits\)"):
        fn(2 ** 40, rng=1)


def test_memory_limit_is_overridable_and_exact(monkeypatch):
    words = S.SAMPLERS["random"].words_per_coord
    fits = 1000
    monkeypatch.setattr(S, "MAX_BYTES", 8 * words * 2 * fits)
    assert S.random(fits, rng=1).shape == (fits, 2)  # exactly at the limit: allowed
    with pytest.raises(ValueError, match=r"at most 1000 fits"):
        S.random(fits + 1, rng=1)
    with pytest.raises(ValueError, match=r"pixel_samples: spp=16 points .* for 1000 pixels"):
        S.pixel_samples("random", 1000, 16, rng=1)


@pytest.mark.parametrize("name", [n for n, r in S.SAMPLERS.items() if r.square])
def test_not_a_perfect_square(name):
    with pytest.raises(ValueError, match="n must be a perfect square.*got n=15"):
        S.get_sampler(name)(15)
    with pytest.raises(ValueError, match="perfect 3-th power"):
        S.get_sampler(name)(9, dim=3)
    with pytest.raises(ValueError, match="spp must be a perfect square"):
        S.pixel_samples(name, 4, 15)


def test_other_bad_input():
    with pytest.raises(ValueError, match="sampler name must be one of .*'sobol'.*got 'sobbol'"):
        S.get_sampler("sobbol")
    with pytest.raises(ValueError, match="name must be one of"):
        S.pixel_samples("nope", 4, 16)
    with pytest.raises(ValueError, match="n_pixels must be >= 1"):
        S.pixel_samples("random", 0, 16)
    with pytest.raises(ValueError, match="dim must be >= 1"):
        S.random(4, dim=0)
    with pytest.raises(ValueError, match="radius must be <= 0.85"):
        S.blue_noise(16, radius=0.9)
    with pytest.raises(ValueError, match="radius must be finite and > 0"):
        S.blue_noise(16, radius=float("nan"))
    with pytest.raises(TypeError, match="correlated must be a bool"):
        S.multi_jittered(16, correlated="yes")
    with pytest.raises(ValueError, match="points must be finite"):
        S.cranley_patterson([[0.5, np.nan]], 1)
    with pytest.raises(ValueError, match=r"points must lie in \[0, 1\]"):
        S.cranley_patterson([[0.5, 1.5]], 1)
    with pytest.raises(ValueError, match="points must have 2 dimensions"):
        S.cranley_patterson([0.5, 0.5], 1)
    with pytest.raises(ValueError, match=r"points must lie in \[0, 1\)"):
        S.digital_shift([[1.0, 0.5]], 1)
    with pytest.raises(ValueError, match="index must be >= 0"):
        S.radical_inverse([-1], 2)
    with pytest.raises(TypeError, match="index must hold integers"):
        S.radical_inverse([0.5], 2)
    with pytest.raises(ValueError, match="base must be >= 2"):
        S.radical_inverse([3], 1)
    with pytest.raises(TypeError, match="rng must be"):
        S.random(4, rng="seed")


def test_sobol_warns_for_non_power_of_two_at_caller():
    with pytest.warns(UserWarning, match="not a power of 2") as record:
        S.sobol(100, rng=1)
    assert record[0].filename == __file__


def test_scrambled_sobol_randomises_every_binary_digit():
    # With scipy's default 30 bits, scrambled points lie on a 2^-30 grid and the
    # mean of u is 1/2 - 2^-31: a bias no replicate error bar can detect.
    # Exact fact: scrambled points are not on that grid; unscrambled ones are.
    pts = S.sobol(256, rng=20261122)
    assert np.mean(np.ldexp(pts, 30) % 1.0 != 0.0) > 0.99
    raw = S.sobol(256, rng=20261122, scramble=False)
    assert np.all(np.ldexp(raw, 30) % 1.0 == 0.0)


def test_deterministic_names_exactly_the_samplers_that_ignore_rng():
    for name in NAMES:
        a, b = S.SAMPLERS[name](64, rng=1), S.SAMPLERS[name](64, rng=2)
        assert np.array_equal(a, b) == (name in S.DETERMINISTIC), name


@pytest.mark.parametrize("name, dim", [("sobol", 2), ("sobol", 5), ("sobol", 6), ("halton", 3), ("random", 4)])
def test_pixel_sample_columns_are_pixel_samples_transposed(name, dim):
    """The wavefront's column layout holds exactly pixel_samples' values for the same rng."""
    from mcvar.samplers import pixel_sample_columns
    a = S.pixel_samples(name, 37, 16, dim=dim, rng=7).reshape(-1, dim).T
    b = pixel_sample_columns(name, 37, 16, dim=dim, rng=7)
    assert b.shape == (dim, 37 * 16) and b.flags.c_contiguous
    np.testing.assert_array_equal(a, b)


# ---------------------------------------------------------------- the Sampler record

def test_records_say_what_the_old_tables_said():
    """The fields replace _WORDS_PER_COORD, EXPECTED_STAR_SLOPES, _IID_SAMPLERS and the
    ("grid", "jittered") literals: check them against the samplers' own behaviour."""
    for name, rec in S.SAMPLERS.items():
        # square: exactly the samplers that refuse a non-square count
        refuses = False
        try:
            rec(15, rng=1)
        except ValueError:
            refuses = True
        assert refuses == rec.square, name
        # deterministic: exactly those giving the same points for two seeds
        a, b = rec(64, rng=1), rec(64, rng=2)
        assert np.array_equal(a, b) == rec.deterministic, name
    assert [n for n, r in S.SAMPLERS.items() if r.iid] == ["random"]
    assert S.DETERMINISTIC == {n for n, r in S.SAMPLERS.items() if r.deterministic}


def test_unknown_sampler_is_a_value_error_everywhere():
    from mcvar.estimators import estimate_mean
    from mcvar.sampler_report import discrepancy_sweep

    for call in (lambda: S.pixel_samples("halton2", 4, 16),
                 lambda: S.pixel_sample_columns("halton2", 4, 16),
                 lambda: S.sampler_record("halton2"),
                 lambda: discrepancy_sweep([16], names=["halton2"]),
                 lambda: estimate_mean(lambda u: u[:, 0], n=16, sampler="halton2", rng=1)):
        with pytest.raises(ValueError, match="halton2"):
            call()


def test_a_record_checks_its_fields():
    with pytest.raises(ValueError, match="name"):
        S.Sampler("not a name", S.random, -0.5)
    with pytest.raises(TypeError, match="function"):
        S.Sampler("toy", 3, -0.5)
    with pytest.raises(ValueError, match="star_slope"):
        S.Sampler("toy", S.random, 0.5)
    with pytest.raises(ValueError, match="words_per_coord"):
        S.Sampler("toy", S.random, -0.5, words_per_coord=0)
    with pytest.raises(ValueError, match="already registered"):
        S.register_sampler(S.Sampler("sobol", S.sobol, -1.0))
    with pytest.raises(TypeError, match="Sampler"):
        S.register_sampler(S.sobol)


def test_default_pixel_sets_are_shifted_copies_of_one_base_set():
    """A record without pixel_sets gets one base set and a Cranley-Patterson shift per
    pixel: every pixel's set is the base set moved on the torus (exact identity)."""
    base = S.hammersley(16)
    sets = S.shifted_pixel_sets(lambda n, rng=None: S.hammersley(n), 5, 16, np.random.default_rng(4))
    shift = np.mod(sets[:, :1, :] - base[None, :1, :], 1.0)
    assert np.allclose(np.mod(base[None] + shift, 1.0), sets, atol=1e-12)
    assert len({tuple(s) for s in shift[:, 0, :]}) == 5   # a different shift per pixel
    with pytest.raises(ValueError, match=r"shape \(16, 2\)"):
        S.shifted_pixel_sets(lambda n, rng=None: np.zeros((n, 3)), 2, 16, np.random.default_rng(1))


@pytest.mark.parametrize("n_pixels, spp, dim", [(5, 16, 2), (7, 8, 5), (3, 1, 20), (64, 4, 7)])
def test_sobol_pixel_samples_by_rows_equal_the_pairs(n_pixels, spp, dim):
    """pixel_samples('sobol') is written from pixel_sample_columns' rows; the same
    values, bit for bit, as the generic pair-by-pair construction (XOR shift per
    pixel, padding shuffle per pair) from the same rng, odd dims included."""
    from mcvar.samplers import _pixel_samples_by_pairs

    fast = S.pixel_samples("sobol", n_pixels, spp, dim=dim, rng=11)
    slow = _pixel_samples_by_pairs("sobol", n_pixels, spp, dim, 11)
    assert fast.shape == slow.shape == (n_pixels, spp, dim)
    np.testing.assert_array_equal(fast, slow)
    assert fast.flags.c_contiguous
