"""Tests of mcvar.discrepancy: brute-force oracles and closed forms first, then rates.

Independent implementations live here (brute-force star discrepancy, the
Warnock / Hickernell / Zhou formulas written out in NumPy) so that the library's
exact algorithm and its scipy calls are each checked against a second one.
"""
import math

import numpy as np
import pytest
from scipy.stats import qmc

from mcvar import discrepancy as D
from mcvar import samplers as S
from mcvar.metrics import loglog_fit

RNG_SEED = 2_718_281_828


# ---------------------------------------------------------------- oracles

def brute_star(p):
    """Sup over the critical grid, counting each box directly: O(n^3)."""
    n = len(p)
    best = 0.0
    for a in np.append(p[:, 0], 1.0):
        for b in np.append(p[:, 1], 1.0):
            closed = np.sum((p[:, 0] <= a) & (p[:, 1] <= b))
            opened = np.sum((p[:, 0] < a) & (p[:, 1] < b))
            best = max(best, closed / n - a * b, a * b - opened / n)
    return best


def warnock(p):
    n, d = p.shape
    pair = np.prod(1 - np.maximum(p[:, None, :], p[None, :, :]), axis=2).sum()
    return 3.0 ** -d - 2.0 ** (1 - d) / n * np.prod(1 - p ** 2, axis=1).sum() + pair / n ** 2


def hickernell_cd(p):
    n, d = p.shape
    z = np.abs(p - 0.5)
    single = np.prod(1 + z / 2 - z ** 2 / 2, axis=1).sum()
    pair = np.prod(1 + z[:, None] / 2 + z[None] / 2 - np.abs(p[:, None] - p[None]) / 2, axis=2).sum()
    return (13 / 12) ** d - 2 / n * single + pair / n ** 2


def hickernell_wd(p):
    n, d = p.shape
    delta = np.abs(p[:, None] - p[None])
    return -(4 / 3) ** d + np.prod(1.5 - delta * (1 - delta), axis=2).sum() / n ** 2


def zhou_md(p):
    n, d = p.shape
    z = np.abs(p - 0.5)
    single = np.prod(5 / 3 - z / 4 - z ** 2 / 4, axis=1).sum()
    delta = np.abs(p[:, None] - p[None])
    pair = np.prod(15 / 8 - z[:, None] / 4 - z[None] / 4 - 3 * delta / 4 + delta ** 2 / 2, axis=2).sum()
    return (19 / 12) ** d - 2 / n * single + pair / n ** 2


# ---------------------------------------------------------------- star

@pytest.mark.parametrize("n", [1, 2, 3, 10, 33, 80])
def test_star_equals_brute_force(n):
    p = np.random.default_rng(RNG_SEED + n).random((n, 2))
    assert D.star(p) == pytest.approx(brute_star(p), abs=1e-14)


def test_star_with_ties_and_edges():
    gen = np.random.default_rng(RNG_SEED)
    p = np.floor(gen.random((40, 2)) * 5) / 5  # many repeated coordinates, zeros
    p[:3] = [[1.0, 1.0], [0.0, 0.0], [1.0, 0.3]]
    assert D.star(p) == pytest.approx(brute_star(p), abs=1e-14)


def test_star_known_values():
    # one point (x, y): the sup is max(1 - xy, x, y) (closed box at the point; open boxes
    # [0,x) x [0,1) and [0,1) x [0,y) are empty)
    for x, y in [(0.5, 0.5), (0.2, 0.9), (0.0, 0.0)]:
        assert D.star([[x, y]]) == pytest.approx(max(1 - x * y, x, y), abs=1e-15)
    # the 2 x 2 grid of cell centres: box [0, 1/4] x [0, 1] closed holds 2/4 of the points
    # at area 1/4 ... the brute force and the exact rate 1/k agree
    assert D.star(S.grid(4)) == pytest.approx(brute_star(S.grid(4)), abs=1e-15)


def test_star_large_n_block_boundaries():
    # n > _BLOCK exercises the carried cumulative counts across blocks
    p = S.random(1100, rng=RNG_SEED)
    sub = p[:120]
    assert D.star(sub) == pytest.approx(brute_star(sub), abs=1e-14)
    full = D.star(p)
    loc = D.local(p, "anchored", resolution=64)
    assert loc.value <= full + 1e-12 and full <= loc.upper


# ---------------------------------------------------------------- L2 family

@pytest.mark.parametrize("d", [1, 2, 3])
def test_l2_family_equals_closed_forms_and_scipy(d):
    p = np.random.default_rng(RNG_SEED + d).random((60, d))
    cases = [(D.l2_star, warnock, "L2-star"), (D.centered, hickernell_cd, "CD"),
             (D.wrap_around, hickernell_wd, "WD"), (D.mixture, zhou_md, "MD")]
    for fn, formula, method in cases:
        sq = fn(p, squared=True)
        assert sq == pytest.approx(formula(p), abs=1e-10)
        assert fn(p) == pytest.approx(math.sqrt(sq), abs=1e-12)
        scipy_value = qmc.discrepancy(p, method=method)
        expected = scipy_value ** 2 if method == "L2-star" else scipy_value  # scipy: L2-star root
        assert sq == pytest.approx(expected, abs=1e-10)


def test_l2_known_values_and_invariances():
    # single point at the origin, d = 2: T^2 = 1/9 - 1/2 + 1 (Warnock's formula)
    assert D.l2_star([[0.0, 0.0]], squared=True) == pytest.approx(1 / 9 - 1 / 2 + 1, abs=1e-15)
    p = S.random(64, rng=RNG_SEED)
    # WD is invariant under toroidal shifts, CD under reflections x -> 1 - x
    assert D.wrap_around(S.cranley_patterson(p, RNG_SEED)) == pytest.approx(D.wrap_around(p), abs=1e-12)
    assert D.centered(1 - p) == pytest.approx(D.centered(p), abs=1e-12)


def test_random_l2_star_expectation_is_exact():
    """E[T^2] = (2^-d - 3^-d) / n for n iid uniform points: the n^-1/2 rate of random sampling.

    Mean of R replicates within 5 standard errors of the exact value, at each n.
    """
    gen = np.random.default_rng(RNG_SEED)
    R = 200
    for n in (16, 256):
        vals = np.array([D.l2_star(S.random(n, rng=g), squared=True) for g in gen.spawn(R)])
        exact = (1 / 4 - 1 / 9) / n
        assert abs(vals.mean() - exact) < 5 * vals.std(ddof=1) / math.sqrt(R)


# ---------------------------------------------------------------- rates

NS = 2 ** np.arange(6, 13)  # 64 ... 4096


def test_star_rate_hammersley_sobol_close_to_one_over_n():
    """Nets have D* = O(log n / n): on [64, 4096] the local log-log slope -1 + 1/ln n lies in
    [-1 + 1/ln 4096, -1 + 1/ln 64] = [-0.88, -0.76] for C log n / n (and is -1 for C / n), so
    the fitted slope must lie in [-1, -0.76] up to 5 standard errors of the fit. Random points
    (slope -1/2) fail this by far."""
    gen = np.random.default_rng(RNG_SEED)
    hamm = np.array([D.star(S.hammersley(int(n))) for n in NS])
    R = 3
    sob = np.array([[D.star(S.sobol(int(n), rng=g)) for g in gen.spawn(R)] for n in NS])
    for fit in (loglog_fit(NS, hamm),
                loglog_fit(NS, sob.mean(1), sigma_log=sob.std(1, ddof=1) / math.sqrt(R) / sob.mean(1))):
        assert -1 - 5 * fit.slope_stderr <= fit.slope <= -1 + 1 / math.log(64) + 5 * fit.slope_stderr


def test_star_rate_random_one_over_sqrt_n():
    """sqrt(n) D* has a limit law for iid points, so E D* ~ c n^-1/2: fitted slope of the mean
    of R replicates (weighted by their standard errors) within 5 standard errors of -1/2."""
    gen = np.random.default_rng(RNG_SEED + 1)
    ns = 2 ** np.arange(6, 11)
    R = 24
    vals = np.array([[D.star(S.random(int(n), rng=g)) for g in gen.spawn(R)] for n in ns])
    mean = vals.mean(1)
    fit = loglog_fit(ns, mean, sigma_log=vals.std(1, ddof=1) / math.sqrt(R) / mean)
    assert abs(fit.slope + 0.5) < 5 * fit.slope_stderr


# ---------------------------------------------------------------- nets

def test_is_net():
    assert D.is_net(S.hammersley(1), 0)
    assert D.is_net(S.sobol(1024, rng=RNG_SEED), 10)
    assert not D.is_net(S.random(256, rng=RNG_SEED), 8)
    g = S.grid(16)  # 4 x 4 grid: strips 1 x 1/16 hold 0 or 4 points: not a (0,4,2)-net ...
    assert not D.is_net(g, 4)
    assert D.is_net(g, 4, t=2)  # ... but every elementary interval of area 1/4 holds 4: a (2,4,2)-net
    # Hammersley in base 3, (i / 9, Phi_3(i)): a (0, 2, 2)-net in base 3
    assert D.is_net(np.column_stack([np.arange(9) / 9, S.radical_inverse(np.arange(9), 3)]), 2, base=3)


def test_is_net_bad_input():
    with pytest.raises(ValueError, match=r"points must hold base\*\*m = 16 points"):
        D.is_net(S.sobol(8, rng=1), 4)
    with pytest.raises(ValueError, match=r"points must lie in \[0, 1\)\^2"):
        D.is_net([[1.0, 0.0]], 0)
    with pytest.raises(ValueError, match="m must be >= 0"):
        D.is_net([[0.0, 0.0]], -1)
    with pytest.raises(ValueError, match="t must be <= m"):
        D.is_net([[0.0, 0.0]], 0, t=1)
    with pytest.raises(ValueError, match="base must be >= 2"):
        D.is_net([[0.0, 0.0]], 0, base=1)


# ---------------------------------------------------------------- local

def brute_boxes(p, r):
    n, best = len(p), 0.0
    e = np.arange(r + 1) / r
    for x0 in e:
        for x1 in e[e > x0]:
            for y0 in e:
                for y1 in e[e > y0]:
                    inside = np.sum((p[:, 0] >= x0) & (p[:, 0] < x1) & (p[:, 1] >= y0) & (p[:, 1] < y1))
                    best = max(best, abs((x1 - x0) * (y1 - y0) - inside / n))
    return best


def test_local_boxes_equals_brute_force_and_bounds():
    p = S.random(25, rng=RNG_SEED)
    boxes = D.local(p, "boxes", resolution=6)
    assert boxes.value == pytest.approx(brute_boxes(p, 6), abs=1e-14)
    x0, y0, x1, y1 = boxes.region
    inside = np.sum((p[:, 0] >= x0) & (p[:, 0] < x1) & (p[:, 1] >= y0) & (p[:, 1] < y1))
    assert abs((x1 - x0) * (y1 - y0) - inside / 25) == pytest.approx(boxes.value, abs=1e-14)
    anchored = D.local(p, "anchored", resolution=6)
    assert anchored.value <= boxes.value  # anchored grid boxes are grid boxes
    assert anchored.value <= D.star(p) <= anchored.upper
    assert boxes.upper == pytest.approx(boxes.value + 4 / 6)


def test_local_disks_sup_over_radii_is_exact():
    p = S.random(40, rng=RNG_SEED)
    res = D.local(p, "disks", resolution=4)
    cx, cy, rad = res.region
    assert rad <= min(cx, cy, 1 - cx, 1 - cy) + 1e-15
    # brute force: every centre, radii on a fine grid below the cap (a lower bound) and at the
    # points' distances (closed and open disks), which must reproduce the value
    best = 0.0
    centres = (np.stack(np.meshgrid(np.arange(4), np.arange(4)), -1).reshape(-1, 2) + 0.5) / 4
    for c in centres:
        cap = min(c.min(), 1 - c.max())
        dist = np.hypot(*(p - c).T)
        for r in np.append(np.linspace(0, cap, 200), dist[dist <= cap]):
            area = math.pi * r * r
            best = max(best, abs(area - np.sum(dist <= r) / 40), abs(area - np.sum(dist < r) / 40))
    assert res.value == pytest.approx(best, abs=1e-12)


def test_local_bad_input():
    with pytest.raises(ValueError, match="family must be one of"):
        D.local([[0.5, 0.5]], "triangles")
    with pytest.raises(ValueError, match="resolution must be >= 1"):
        D.local([[0.5, 0.5]], resolution=0)
    with pytest.raises(ValueError, match=r"points must have shape \(n, 2\)"):
        D.local([[0.5, 0.5, 0.5]])


# ---------------------------------------------------------------- spectra

def test_power_spectrum_grid_spikes_exact():
    k = 8
    ps = D.power_spectrum(S.grid(k * k), k_max=20)
    kx, ky = np.meshgrid(ps.frequencies, ps.frequencies, indexing="ij")
    spike = (kx % k == 0) & (ky % k == 0)
    # sum_j exp(-2 pi i f . x_j) over a k x k lattice is n at multiples of k (times a phase), else 0
    np.testing.assert_allclose(ps.power[spike], k * k, rtol=1e-12)
    np.testing.assert_allclose(ps.power[~spike], 0.0, atol=1e-9)
    # anisotropy per annulus: s spikes of height n among m frequencies give var/mean^2 = m/s - 1
    ring = np.rint(np.hypot(kx, ky)).astype(int)
    expected = [np.sum(ring == f) / np.sum(spike & (ring == f)) - 1 if np.any(spike & (ring == f)) else 0.0
                for f in range(1, 21)]
    np.testing.assert_allclose(ps.radial_anisotropy, expected, rtol=1e-9, atol=1e-9)
    assert ps.anisotropy > 5


def test_power_spectrum_random_flat_blue_noise_dark_centre():
    """Random points: E P(k) = 1 for k != 0; P(k) ~ Exp(1) approximately, with P(-k) = P(k),
    so a mean over m frequencies has standard error about sqrt(2 / m). Blue noise must lie
    below random by more than 5 such errors (measured ratio about 0.1)."""
    n = 1024
    cutoff = 0.5 * math.sqrt(n)
    rand = D.power_spectrum(S.random(n, rng=RNG_SEED))
    blue = D.power_spectrum(S.blue_noise(n, rng=RNG_SEED))
    kx, ky = np.meshgrid(rand.frequencies, rand.frequencies, indexing="ij")
    m = np.sum((np.hypot(kx, ky) > 0) & (np.hypot(kx, ky) < cutoff))
    se = math.sqrt(2 / m)
    low_rand, low_blue = rand.low_frequency_power(cutoff), blue.low_frequency_power(cutoff)
    assert abs(low_rand - 1) < 5 * se
    assert low_blue < low_rand - 5 * se
    assert rand.power[rand.power.shape[0] // 2, rand.power.shape[1] // 2] == pytest.approx(n)
    # isotropy: var/mean^2 per annulus is 1 for exponential ordinates; Exp's kurtosis 9 gives
    # var(CV^2) ~ 8 / (m_f / 2) per annulus; averaged over the annuli, 5 standard errors
    ring = np.rint(np.hypot(kx, ky)).astype(int)
    m_f = np.array([np.sum(ring == f) for f in range(1, len(rand.radial_frequency) + 1)])
    se_aniso = math.sqrt(np.sum(16 / m_f)) / len(m_f)
    for ps in (rand, blue):
        assert abs(ps.anisotropy - 1) < 5 * se_aniso
    assert D.power_spectrum(S.hammersley(n)).anisotropy > 1 + 5 * se_aniso


def test_power_spectrum_bad_input():
    with pytest.raises(ValueError, match="cutoff must be > 1"):
        D.power_spectrum([[0.5, 0.5]]).low_frequency_power(1.0)
    with pytest.raises(ValueError, match="k_max must be >= 1"):
        D.power_spectrum([[0.5, 0.5]], k_max=0)


# ---------------------------------------------------------------- bad input

@pytest.mark.parametrize("fn", list(D.DISCREPANCIES.values()))
def test_discrepancy_bad_input(fn):
    with pytest.raises(ValueError, match="points must be finite"):
        fn([[0.5, np.nan]])
    with pytest.raises(ValueError, match=r"points must lie in \[0, 1\]"):
        fn([[0.5, 1.2]])
    with pytest.raises(ValueError, match="points must have 2 dimensions"):
        fn([0.5, 0.5])
    with pytest.raises(ValueError, match="at least one point"):
        fn(np.empty((0, 2)))
    if fn is not D.star:
        with pytest.raises(TypeError, match="squared must be a bool"):
            fn([[0.5, 0.5]], squared="yes")
