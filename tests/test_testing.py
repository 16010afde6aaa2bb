"""Tests of mcvar.testing and mcvar.testing.mutants.

Two promises are proved here: every check rejects every mutant it is meant to
catch (with its power measured: the smallest sample count at which all
replicates reject), and correct pairs pass at family-wise significance 1e-3
(Sidak-corrected over the tests of this file).
"""
import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats

from mcvar import warps as w
from mcvar.geometry import Frame
from mcvar.testing import (Chi2Result, bsdf_chi2_test, check_extremes, check_inverse,
                           check_pdf_normalized, check_unbiased, check_weight_consistency, chi2_test,
                           measure_power, sidak_significance)
from mcvar.testing import mutants

SEED = 7_341_905_221
TWO_PI = 2 * np.pi
N_FAMILY = 64  # statistical tests of correct pairs in this file (upper bound)
SIG = sidak_significance(1e-3, N_FAMILY)


# ------------------------------------------------------------ fixtures: BSDFs

class Diffuse:
    """Lambertian reference, f = albedo / pi, cosine-sampled: weight = albedo."""

    is_delta = False

    def __init__(self, albedo=(0.8, 0.5, 0.2)):
        self.albedo = np.asarray(albedo, dtype=float)

    def eval(self, wo, wi):
        up = (wo[:, 1] > 0) & (wi[:, 1] > 0)
        return np.where(up[:, None], self.albedo / np.pi, 0.0)

    def pdf(self, wo, wi):
        return np.where(wo[:, 1] > 0, w.square_to_cosine_hemisphere_pdf(wi), 0.0)

    def sample(self, wo, u):
        wi = w.square_to_cosine_hemisphere(u)
        pdf = self.pdf(wo, wi)
        weight = np.where((pdf > 0)[:, None], self.albedo, 0.0)
        return wi, weight, pdf


class Phong:
    """Lafortune's modified Phong lobe about the mirror direction: some samples
    fall below the horizon and fail (weight 0, eval 0)."""

    is_delta = False

    def __init__(self, k=10.0, rho=0.7):
        self.k, self.rho = k, rho

    def _local(self, wo, wi):
        r = wo * np.array([-1.0, 1.0, -1.0])
        return Frame(r).to_local(wi)

    def eval(self, wo, wi):
        c = np.maximum(self._local(wo, wi)[:, 1], 0.0)
        f = self.rho * (self.k + 2) / TWO_PI * c ** self.k
        return np.where(wi[:, 1] > 0, f, 0.0)

    def pdf(self, wo, wi):
        return np.where(wi[:, 1] > 0, w.square_to_phong_lobe_pdf(self._local(wo, wi), self.k), 0.0)

    def sample(self, wo, u):
        r = wo * np.array([-1.0, 1.0, -1.0])
        loc = w.square_to_phong_lobe(u, self.k)
        wi = Frame(r).to_world(loc)
        pdf = w.square_to_phong_lobe_pdf(loc, self.k)
        ok = wi[:, 1] > 0
        weight = np.where(ok, self.rho * (self.k + 2) / (self.k + 1) * np.abs(wi[:, 1]), 0.0)
        return wi, weight, pdf


class CoatedDiffuse:
    """A mixed model: a mirror coat chosen with probability ``p_spec`` (a delta
    lobe, discrete pdf ``p_spec``) over a diffuse base sampled with the
    remaining probability, so ``pdf = (1 - p_spec) cos / pi`` integrates to
    ``1 - p_spec``. ``p_pdf`` is the coat probability ``pdf()`` assumes (a
    bug when it differs from ``p_spec``)."""

    is_delta, has_delta = False, True

    def __init__(self, p_spec=0.3, albedo=0.6, p_pdf=None):
        self.p_spec, self.albedo = p_spec, albedo
        self.p_pdf = p_spec if p_pdf is None else p_pdf

    def eval(self, wo, wi):
        up = (wo[:, 1] > 0) & (wi[:, 1] > 0)
        return np.where(up[:, None], (1 - self.p_spec) * self.albedo / np.pi, 0.0) * np.ones(3)

    def pdf(self, wo, wi):
        up = (wo[:, 1] > 0) & (wi[:, 1] > 0)
        return np.where(up, (1 - self.p_pdf) * wi[:, 1] / np.pi, 0.0)

    def sample(self, wo, u, *, return_delta=False):
        spec = u[:, 0] < self.p_spec
        ud = np.column_stack([(u[:, 0] - self.p_spec) / (1 - self.p_spec), u[:, 1]]).clip(0, 1)
        wi = np.where(spec[:, None], wo * np.array([-1.0, 1.0, -1.0]), w.square_to_cosine_hemisphere(ud))
        pdf = np.where(spec, self.p_spec, (1 - self.p_spec) * wi[:, 1] / np.pi)
        weight = np.where(spec[:, None], 1.0, self.albedo) * np.ones(3)
        return (wi, weight, pdf, spec) if return_delta else (wi, weight, pdf)


class DiffuseTransmitter:
    """Reflects or transmits (coin flip) into a cosine lobe: a transmissive
    non-delta BSDF, pdf |cos| / (2 pi) over the whole sphere."""

    is_delta, transmissive = False, True

    def eval(self, wo, wi):
        return np.full((len(wo), 3), 0.5 / (2 * np.pi))

    def pdf(self, wo, wi):
        return np.abs(wi[:, 1]) / (2 * np.pi)

    def sample(self, wo, u):
        side = np.where(u[:, 0] < 0.5, 1.0, -1.0) * np.sign(wo[:, 1])
        ud = np.column_stack([np.where(u[:, 0] < 0.5, 2 * u[:, 0], 2 * u[:, 0] - 1), u[:, 1]]).clip(0, 1)
        wi = w.square_to_cosine_hemisphere(ud) * np.stack([np.ones_like(side), side, np.ones_like(side)], -1)
        return wi, np.full((len(wo), 3), 0.5), self.pdf(wo, wi)


class Mirror:
    is_delta = True

    def eval(self, wo, wi):
        return np.zeros((len(wo), 3))

    def pdf(self, wo, wi):
        return np.zeros(len(wo))

    def sample(self, wo, u):
        wi = wo * np.array([-1.0, 1.0, -1.0])
        return wi, np.ones((len(wo), 3)), np.full(len(wo), np.inf)


WO = np.array([0.3, 0.8, -0.2]) / np.linalg.norm([0.3, 0.8, -0.2])


# ------------------------------------------------------------ Sidak

def test_sidak_significance():
    assert sidak_significance(0.05, 1) == pytest.approx(0.05, rel=1e-14)
    a = sidak_significance(1e-3, 20)
    assert (1 - a) ** 20 == pytest.approx(1 - 1e-3, rel=1e-14)
    with pytest.raises(ValueError, match="significance must lie in"):
        sidak_significance(1.0, 2)
    with pytest.raises(ValueError, match="test_count must be >= 1"):
        sidak_significance(0.01, 0)


# ------------------------------------------------------------ chi2_test

def test_chi2_rejects_cosine_sampler_with_uniform_pdf():
    r = chi2_test(w.square_to_cosine_hemisphere, w.square_to_uniform_hemisphere_pdf, "hemisphere",
                  n=20_000, rng=SEED)
    assert not r.passed and r.pvalue < 1e-10 and np.isfinite(r.statistic)
    assert "rejected" in r.message


def test_chi2_rejects_pdf_off_by_two():
    r = chi2_test(w.square_to_cosine_hemisphere, lambda v: 2 * w.square_to_cosine_hemisphere_pdf(v),
                  "hemisphere", n=1000, rng=SEED)
    assert not r.passed and r.pvalue == 0.0
    assert "integrates to 2" in r.message


def _z_up(v):
    """A +z-normal library's view of mcvar directions (the swap docs/testing.md gives)."""
    return np.asarray(v)[:, [0, 2, 1]]


def test_third_party_style_pdfs_are_broadcast_and_axes_adapted():
    """Issue 15: a pdf returning one constant (Mitsuba 3's uniform sphere returns a
    size-1 array) is broadcast, in every check that calls a pdf; a +z-normal cosine
    warp adapted by the documented one-line swap passes, and a mismatched pair fails."""
    const = lambda v: np.array([1.0 / (4.0 * np.pi)])  # noqa: E731
    r = chi2_test(w.square_to_uniform_sphere, const, "sphere", n=20_000, rng=SEED, test_count=N_FAMILY)
    assert r.passed, r.message
    assert check_pdf_normalized(lambda v: 1.0 / (4.0 * np.pi), "sphere").passed
    assert check_extremes(w.square_to_uniform_sphere, const, "sphere").passed
    wrong = chi2_test(w.square_to_uniform_sphere, lambda v: np.array([1.0 / (2.0 * np.pi)]), "sphere",
                      n=2_000, rng=SEED)
    assert not wrong.passed and "integrates to 2" in wrong.message

    def lib_sample(u):  # a +z-normal cosine warp (normal = third coordinate)
        return _z_up(w.square_to_cosine_hemisphere(u))

    def lib_pdf(v):
        return np.where(v[:, 2] >= 0.0, v[:, 2] / np.pi, 0.0)

    ok = chi2_test(lambda u: _z_up(lib_sample(u)), lambda v: lib_pdf(_z_up(v)), "hemisphere",
                   n=20_000, rng=SEED, test_count=N_FAMILY)
    assert ok.passed, ok.message
    unadapted = chi2_test(lib_sample, lib_pdf, "hemisphere", n=2_000, rng=SEED)
    assert not unadapted.passed
    with pytest.raises(ValueError, match=r"pdf\(x\) must return shape \(m,\).*got shape \(2,\)"):
        chi2_test(w.square_to_uniform_sphere, lambda v: np.ones(2), "sphere", n=100, rng=SEED)


def test_chi2_result_fields():
    r = chi2_test(w.square_to_uniform_sphere, w.square_to_uniform_sphere_pdf, "sphere",
                  n=50_000, rng=SEED, bins=(10, 20), significance=SIG)
    assert isinstance(r, Chi2Result) and r.passed
    assert r.observed.shape == r.expected.shape == (10, 20)
    assert r.observed.sum() == 50_000
    assert r.expected.sum() == pytest.approx(50_000, rel=1e-12)
    np.testing.assert_allclose(r.edges[0], np.linspace(-1, 1, 11))
    np.testing.assert_allclose(r.edges[1], np.linspace(0, TWO_PI, 21))
    assert r.coordinates == ("cos_theta", "phi") and r.dof == 199
    assert r.pdf_integral == pytest.approx(1.0, abs=1e-12)
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.pvalue = 1.0


def test_chi2_pvalues_are_uniform_for_a_correct_pair():
    # Calibration: under H0 the p-value is U(0, 1) (the dof and pooling are
    # right); Kolmogorov-Smirnov over 40 independent runs.
    streams = np.random.SeedSequence(SEED).spawn(40)
    p = [chi2_test(w.square_to_cosine_hemisphere, w.square_to_cosine_hemisphere_pdf, "hemisphere",
                   n=5000, rng=s).pvalue for s in streams]
    assert stats.kstest(p, "uniform").pvalue > SIG


def test_chi2_batches_equal_one_pass():
    a = chi2_test(w.square_to_cosine_hemisphere, w.square_to_cosine_hemisphere_pdf, "hemisphere",
                  n=30_000, rng=SEED)
    b = chi2_test(w.square_to_cosine_hemisphere, w.square_to_cosine_hemisphere_pdf, "hemisphere",
                  n=30_000, rng=SEED, batch_size=7_000)
    np.testing.assert_array_equal(a.observed, b.observed)
    assert a.statistic == b.statistic


def test_chi2_bounds_and_rest_cell():
    # The phong lobe binned only near the pole: samples outside bounds form one cell.
    k = 50.0
    bounds = ((0.9, 1.0), (0.0, TWO_PI))
    r = chi2_test(lambda u: w.square_to_phong_lobe(u, k), lambda v: w.square_to_phong_lobe_pdf(v, k),
                  "hemisphere", n=100_000, rng=SEED, bounds=bounds, significance=SIG)
    assert r.passed, r.message
    # P(cos < 0.9) = 0.9^(k + 1)
    assert abs(r.outside_bounds - 1e5 * 0.9 ** 51) <= 5 * np.sqrt(1e5 * 0.9 ** 51)
    with pytest.raises(ValueError, match=r"bounds\[0\] must satisfy"):
        chi2_test(w.square_to_uniform_hemisphere, w.square_to_uniform_hemisphere_pdf, "hemisphere",
                  n=100, bounds=((-0.5, 1.0), (0.0, TWO_PI)))


def test_chi2_sanity_checks():
    def below(u):
        v = w.square_to_uniform_hemisphere(u)
        v[:10, 1] *= -1
        return v
    r = chi2_test(below, w.square_to_uniform_hemisphere_pdf, "hemisphere", n=1000, rng=SEED)
    assert not r.passed and "outside the hemisphere domain" in r.message

    def nan_sampler(u):
        v = w.square_to_uniform_hemisphere(u)
        v[0] = np.nan
        return v
    r = chi2_test(nan_sampler, w.square_to_uniform_hemisphere_pdf, "hemisphere", n=1000, rng=SEED)
    assert not r.passed and "NaN or Inf" in r.message
    r = chi2_test(w.square_to_uniform_hemisphere, lambda v: w.square_to_uniform_hemisphere_pdf(v) - 0.2,
                  "hemisphere", n=1000, rng=SEED)
    assert not r.passed and "negative" in r.message
    r = chi2_test(w.square_to_uniform_hemisphere, lambda v: np.full(len(v), np.nan), "hemisphere",
                  n=1000, rng=SEED)
    assert not r.passed and "NaN or Inf at" in r.message
    # normalised pdf, but zero where samples land: the uniform hemisphere against a cone
    r = chi2_test(w.square_to_uniform_hemisphere, lambda v: w.square_to_uniform_cone_pdf(v, 0.5),
                  "hemisphere", n=1000, rng=SEED)
    assert not r.passed and "pdf integrates to 0" in r.message


def test_chi2_bad_arguments():
    s, p = w.square_to_uniform_hemisphere, w.square_to_uniform_hemisphere_pdf
    with pytest.raises(ValueError, match="domain must be one of"):
        chi2_test(s, p, "cube", n=100)
    with pytest.raises(ValueError, match="n must be >= 1"):
        chi2_test(s, p, "hemisphere", n=0)
    with pytest.raises(TypeError, match="sample must be callable"):
        chi2_test(None, p, "hemisphere", n=100)
    with pytest.raises(ValueError, match="bins must be a pair"):
        chi2_test(s, p, "hemisphere", n=100, bins=(3,))
    with pytest.raises(ValueError, match=r"sample\(u\) must return shape \(100, 2\)"):
        chi2_test(s, p, "disk", n=100)
    with pytest.raises(ValueError, match=r"pdf\(x\) must return shape"):
        chi2_test(s, lambda v: p(v)[:, None], "hemisphere", n=100)
    with pytest.raises(ValueError, match="too small"):
        chi2_test(s, p, "hemisphere", n=10, bins=(8, 8))
    with pytest.raises(ValueError, match="significance must be finite and > 0"):
        chi2_test(s, p, "hemisphere", n=100, significance=-1)


# ------------------------------------------------------------ samplers that fail

# The tilted cosine lobe of mcvar.testing.mutants: samples below the geometric
# horizon fail; P(valid) = (1 + cos 45 deg) / 2 (Malley's method, see mutants).
LOBE = mutants.get("pdf_ignores_failures")
P_VALID = (1 + np.cos(np.pi / 4)) / 2


def test_chi2_sampler_with_failures_passes():
    r = chi2_test(LOBE.correct_sample, LOBE.correct_pdf, "hemisphere", n=100_000, rng=SEED,
                  significance=SIG)
    assert r.passed, r.message
    assert r.pdf_integral == pytest.approx(P_VALID, abs=1e-6)
    # failures are Binomial(n, 1 - P_VALID): within 5 standard deviations
    assert abs(r.failed - 1e5 * (1 - P_VALID)) <= 5 * np.sqrt(1e5 * P_VALID * (1 - P_VALID))
    assert r.observed.sum() == 100_000 - r.failed and r.valid_pvalue > r.significance
    # the binomial test and the statistic share the Sidak-corrected significance
    assert r.significance == pytest.approx(sidak_significance(SIG, 2), rel=1e-12)
    assert "failed" in r.message
    # (points, valid) with every sample valid behaves like the plain sampler
    plain = chi2_test(w.square_to_cosine_hemisphere, w.square_to_cosine_hemisphere_pdf, "hemisphere",
                      n=20_000, rng=SEED)
    masked = chi2_test(lambda u: (w.square_to_cosine_hemisphere(u), np.ones(len(u), bool)),
                       w.square_to_cosine_hemisphere_pdf, "hemisphere", n=20_000, rng=SEED,
                       significance=SIG)
    np.testing.assert_array_equal(plain.observed, masked.observed)
    assert masked.passed and masked.failed == 0 and masked.valid_pvalue == 1.0


def test_chi2_pvalues_are_uniform_with_failures():
    # the failure cell and the dof are right: p-values U(0, 1) under H0 (KS, 40 runs)
    streams = np.random.SeedSequence(SEED + 1).spawn(40)
    p = [chi2_test(LOBE.correct_sample, LOBE.correct_pdf, "hemisphere", n=5000, rng=s).pvalue
         for s in streams]
    assert stats.kstest(p, "uniform").pvalue > SIG


def test_chi2_rejects_pdf_ignoring_failures():
    # pdf normalised to 1 over the valid region: the valid fraction 0.854 says otherwise
    r = chi2_test(LOBE.sample, LOBE.pdf, "hemisphere", n=2000, rng=SEED)
    assert not r.passed and r.pvalue == 0.0 and r.valid_pvalue < 1e-10
    assert "must integrate to the probability of a valid sample" in r.message
    assert r.pdf_integral == pytest.approx(1.0, abs=1e-3)
    # with the sanity checks off, the failure cell of the statistic still sees it
    # (expected ~ n (1 - 1) = 0 failures, 288 observed)
    r = chi2_test(LOBE.sample, LOBE.pdf, "hemisphere", n=2000, rng=SEED, normalization_atol=np.inf)
    assert not r.passed and np.isfinite(r.statistic) and np.isnan(r.valid_pvalue)
    # a pdf integrating to exactly 1 leaves the failures a cell of expected count 0
    r = chi2_test(lambda u: (w.square_to_cosine_hemisphere(u), u[:, 0] < 0.9),
                  w.square_to_cosine_hemisphere_pdf, "hemisphere", n=2000, rng=SEED,
                  normalization_atol=np.inf)
    assert not r.passed and "failed or fell outside bounds although the pdf integrates to 1" in r.message


@pytest.mark.parametrize("factor", [0.95, 1.05])
def test_chi2_rejects_failure_fraction_disagreeing_with_pdf_mass(factor):
    # pdf mass 0.811 or 0.896 against a valid fraction of 0.854 (both < 1)
    r = chi2_test(LOBE.correct_sample, lambda v: factor * LOBE.correct_pdf(v), "hemisphere",
                  n=20_000, rng=SEED)
    assert not r.passed and "binomial p" in r.message
    # and a sampler failing where its pdf says it should not (a grazing cut-off)
    cut = mutants.get("failure_cutoff_not_in_pdf")
    r = chi2_test(cut.sample, cut.pdf, "hemisphere", n=20_000, rng=SEED)
    assert not r.passed


def test_chi2_with_failures_still_rejects_pdf_above_one():
    r = chi2_test(LOBE.correct_sample, lambda v: 1.3 * LOBE.correct_pdf(v), "hemisphere", n=1000, rng=SEED)
    assert not r.passed and "> 1 over the hemisphere" in r.message


def test_chi2_failed_points_are_ignored_valid_ones_checked():
    def nan_failures(u):
        d, ok = LOBE.correct_sample(u)
        d[~ok] = np.nan                     # failed samples may carry anything
        return d, ok
    assert chi2_test(nan_failures, LOBE.correct_pdf, "hemisphere", n=20_000, rng=SEED,
                     significance=SIG).passed

    def below_but_valid(u):
        d, ok = LOBE.correct_sample(u)
        return d, np.ones(len(u), bool)     # failures not reported
    r = chi2_test(below_but_valid, LOBE.correct_pdf, "hemisphere", n=1000, rng=SEED)
    assert not r.passed and "outside the hemisphere domain" in r.message
    r = chi2_test(lambda u: LOBE.correct_sample(u)[0], LOBE.correct_pdf, "hemisphere", n=1000, rng=SEED)
    assert not r.passed and "returns (points, valid)" in r.message
    with pytest.raises(ValueError, match=r"valid mask of sample\(u\) must have shape \(100,\)"):
        chi2_test(lambda u: (LOBE.correct_sample(u)[0], np.ones(3, bool)), LOBE.correct_pdf,
                  "hemisphere", n=100)
    # boundaries: check_extremes judges the valid points only
    assert check_extremes(LOBE.correct_sample, LOBE.correct_pdf, "hemisphere").passed


def test_chi2_failures_with_bounds_join_the_rest_cell():
    # binned only near the pole: failures and samples outside bounds share one cell
    r = chi2_test(LOBE.correct_sample, LOBE.correct_pdf, "hemisphere", n=50_000, rng=SEED,
                  bounds=((0.5, 1.0), (0.0, TWO_PI)), significance=SIG)
    assert r.passed, r.message
    assert r.failed > 0 and r.outside_bounds > 0 and np.isnan(r.valid_pvalue)


# ------------------------------------------------------------ normalisation

def test_check_pdf_normalized():
    assert check_pdf_normalized(w.square_to_cosine_hemisphere_pdf, "hemisphere").passed
    r = check_pdf_normalized(lambda v: 1.001 * w.square_to_cosine_hemisphere_pdf(v), "hemisphere",
                             atol=1e-4)
    assert not r.passed and r.value == pytest.approx(1.001, rel=1e-9)
    r = check_pdf_normalized(lambda v: np.full(len(v), np.inf), "sphere")
    assert not r.passed and "not finite" in r.message
    r = check_pdf_normalized(w.square_to_uniform_disk_concentric_pdf, "disk", atol=1e-9)
    assert r.passed and r.value == pytest.approx(1.0, abs=1e-12)
    with pytest.raises(TypeError, match="pdf must be callable"):
        check_pdf_normalized(3, "disk")


# ------------------------------------------------------------ weight consistency

@pytest.mark.parametrize("bsdf", [Diffuse(), Phong(), Phong(k=1000.0), CoatedDiffuse(), DiffuseTransmitter()],
                         ids=["diffuse", "phong", "phong1000", "coated", "transmitter"])
def test_weight_consistency_passes_correct_bsdfs(bsdf):
    r = check_weight_consistency(bsdf, WO, n=5000, rng=SEED)
    assert r.passed, r.message
    grazing = np.array([0.999, 0.01, 0.0]) / np.linalg.norm([0.999, 0.01, 0.0])
    assert check_weight_consistency(bsdf, grazing, n=5000, rng=SEED).passed


def test_weight_consistency_delta_and_broken_outputs():
    assert check_weight_consistency(Mirror(), WO, n=10, rng=SEED).passed

    class NaNWeight(Diffuse):
        def sample(self, wo, u):
            wi, wt, p = super().sample(wo, u)
            wt[0] = np.nan
            return wi, wt, p

    class Negative(Diffuse):
        def sample(self, wo, u):
            wi, wt, p = super().sample(wo, u)
            return wi, -wt, p

    class TwoOutputs(Diffuse):
        def sample(self, wo, u):
            return super().sample(wo, u)[:2]

    for bad, text in ((NaNWeight(), "NaN or Inf"), (Negative(), "negative"), (TwoOutputs(), "tuple")):
        r = check_weight_consistency(bad, WO, n=100, rng=SEED)
        assert not r.passed and text in r.message
    with pytest.raises(TypeError, match=r"bsdf must have a callable eval"):
        check_weight_consistency(object(), WO)
    with pytest.raises(ValueError, match=r"wo must have shape \(3,\) or \(10, 3\)"):
        check_weight_consistency(Diffuse(), np.ones((3, 3)), n=10)


# ------------------------------------------------------------ bsdf_chi2_test

@pytest.mark.parametrize("bsdf,wo", [
    (Diffuse(), WO),
    (Phong(), WO),                                  # failures: weight 0 below the horizon
    (Phong(k=3.0), np.array([0.96, 0.28, 0.0])),    # near grazing: over a third fail
    (CoatedDiffuse(), WO),                          # mixed: delta coat excluded
    (DiffuseTransmitter(), -WO),                    # transmissive: sphere, wo inside
], ids=["diffuse", "phong", "phong-grazing", "coated", "transmitter"])
def test_bsdf_chi2_passes_correct_bsdfs(bsdf, wo):
    r = bsdf_chi2_test(bsdf, wo, n=100_000, rng=SEED, significance=SIG)
    assert r.passed, r.message
    assert r.domain == ("sphere" if getattr(bsdf, "transmissive", False) else "hemisphere")
    assert r.observed.sum() == r.n - r.failed - r.delta
    if isinstance(bsdf, CoatedDiffuse):       # delta count ~ Binomial(n, p_spec), 5 sigma
        assert abs(r.delta - 1e5 * 0.3) <= 5 * np.sqrt(1e5 * 0.3 * 0.7)
        assert r.failed == 0 and r.pdf_integral == pytest.approx(0.7, abs=1e-9)
        assert "delta-lobe samples" in r.message
    if isinstance(bsdf, Phong):
        assert r.failed > 0 and r.pdf_integral < 1


def test_bsdf_chi2_rejects_delta_probability_disagreeing_with_pdf():
    # the coat is chosen 30 % of the time but pdf() assumes 25 %: delta fraction
    # + pdf integral = 0.3 + 0.75 > 1
    r = bsdf_chi2_test(CoatedDiffuse(p_pdf=0.25), WO, n=20_000, rng=SEED)
    assert not r.passed and "binomial p" in r.message


def test_bsdf_chi2_rejects_broken_bsdfs():
    # a pdf 5 % too large, consistently in pdf() and sample(): weights stay
    # eval cos / pdf, so only the chi-square test sees it
    broken = mutants.pdf_scaled(Phong(), 1.05)
    assert check_weight_consistency(broken, WO, n=1000, rng=SEED).passed
    power = measure_power(lambda n, rng: bsdf_chi2_test(broken, WO, n=n, rng=rng),
                          [1024 * 4 ** j for j in range(5)], replicates=5, target=1.0, rng=SEED)
    assert power.n_reject is not None
    # a lobe sampled in a frame with a flipped tangent (wo off the plane x = 0)
    flipped = mutants.sample_tangent_flipped(Phong())
    power = measure_power(lambda n, rng: bsdf_chi2_test(flipped, WO, n=n, rng=rng),
                          [64 * 4 ** j for j in range(5)], replicates=5, target=1.0, rng=SEED)
    assert power.n_reject is not None
    # the same flip is invisible for a diffuse lobe (same distribution): not a false alarm
    assert bsdf_chi2_test(mutants.sample_tangent_flipped(Diffuse()), WO, n=50_000, rng=SEED,
                          significance=SIG).passed
    # wrappers forward the delta mask of mixed models
    coated = mutants.pdf_scaled(CoatedDiffuse(), 1.1)
    assert coated.has_delta and len(coated.sample(np.tile(WO, (4, 1)), np.full((4, 2), 0.5),
                                                  return_delta=True)) == 4
    assert not bsdf_chi2_test(coated, WO, n=20_000, rng=SEED).passed


def test_bsdf_chi2_reports_bad_sample_pdf():
    class NaNPdf(Phong):
        def sample(self, wo, u):
            wi, wt, p = super().sample(wo, u)
            p[:3] = np.nan
            return wi, wt, p
    r = bsdf_chi2_test(NaNPdf(), WO, n=1000, rng=SEED)
    assert not r.passed and "NaN, Inf or negative pdf for 3 of 1000" in r.message


def test_bsdf_chi2_bad_arguments():
    with pytest.raises(ValueError, match="bsdf must have a non-delta part"):
        bsdf_chi2_test(Mirror(), WO, n=100)
    with pytest.raises(ValueError, match=r"wo must lie above the horizon \(wo\[1\] > 0\)"):
        bsdf_chi2_test(Diffuse(), np.array([1.0, 0.0, 0.0]), n=100)
    with pytest.raises(ValueError, match="wo must hold unit vectors"):
        bsdf_chi2_test(Diffuse(), np.array([0.0, 2.0, 0.0]), n=100)
    with pytest.raises(ValueError, match=r"wo must be one direction, shape \(3,\)"):
        bsdf_chi2_test(Diffuse(), np.tile(WO, (2, 1)), n=100)
    with pytest.raises(TypeError, match="bsdf must have a callable pdf"):
        bsdf_chi2_test(object(), WO, n=100)


# ------------------------------------------------------------ inverse, extremes

def test_check_inverse():
    assert check_inverse(w.square_to_uniform_sphere, w.uniform_sphere_to_square, rng=SEED,
                         periodic=(False, True)).passed
    # u1 = 1 maps to phi = 2 pi, which inverts to 0: equal only modulo 1
    u = np.array([[0.3, 1.0]])
    assert not check_inverse(w.square_to_uniform_sphere, w.uniform_sphere_to_square, u=u).passed
    assert check_inverse(w.square_to_uniform_sphere, w.uniform_sphere_to_square, u=u,
                         periodic=(False, True)).passed
    r = check_inverse(w.square_to_uniform_sphere, lambda v: np.zeros((len(v), 3)), rng=SEED)
    assert not r.passed and "shape" in r.message


def test_check_extremes_boundary_points():
    r = check_extremes(w.square_to_cosine_hemisphere, w.square_to_cosine_hemisphere_pdf, "hemisphere")
    assert r.passed and r.n == 4 * 260
    r = check_extremes(w.square_to_uniform_sphere, w.square_to_uniform_hemisphere_pdf, "hemisphere")
    assert not r.passed and "outside the hemisphere" in r.message


# ------------------------------------------------------------ unbiasedness

def test_check_unbiased_numbers_and_objects():
    assert check_unbiased(1.0 + 3e-3, 1.0, stderr=1e-3).passed          # 3 sigma < 3.29
    assert not check_unbiased(1.0 + 4e-3, 1.0, stderr=1e-3).passed      # 4 sigma
    assert check_unbiased(SimpleNamespace(mean=2.0, stderr=0.1), 2.25, z=3.0).passed
    assert not check_unbiased(SimpleNamespace(mean=2.0, stderr=0.1), 2.35, z=3.0).passed
    # zero variance: exact to rounding, else biased
    assert check_unbiased(np.pi, np.pi, stderr=0.0).passed
    assert not check_unbiased(np.pi * (1 + 1e-12), np.pi, stderr=0.0).passed
    # RGB: Sidak over three components widens z
    r = check_unbiased(np.array([1.0, 2.0, 3.0]), [1.0, 2.0, 3.0 + 3.35e-3], stderr=1e-3)
    assert r.passed and r.threshold == pytest.approx(stats.norm.isf(sidak_significance(1e-3, 3) / 2))
    with pytest.raises(ValueError, match="stderr is required"):
        check_unbiased(1.0, 1.0)
    with pytest.raises(ValueError, match="stderr must not be given"):
        check_unbiased(SimpleNamespace(mean=1.0, stderr=0.1), 1.0, stderr=0.1)
    with pytest.raises(ValueError, match="stderr must be non-negative"):
        check_unbiased(1.0, 1.0, stderr=-1.0)
    with pytest.raises(ValueError, match="estimate.mean must be finite"):
        check_unbiased(np.nan, 1.0, stderr=1.0)


def _estimate_cos2(sample, pdf, n, rng):
    """IS estimate of int_H cos^2(theta) d(omega) = 2 pi / 3 (not proportional to
    any mutant's pdf, so its variance is not zero)."""
    x = sample(rng.random((n, 2)))
    valid = np.ones(n, bool)
    if isinstance(x, tuple):            # (points, valid): a failed sample contributes 0
        x, valid = x
    y = np.where(valid, x[:, 1] ** 2 / np.where(valid, pdf(x), 1.0), 0.0)
    return y.mean(), y.std(ddof=1) / np.sqrt(n)


def test_correct_estimator_is_unbiased():
    mean, se = _estimate_cos2(w.square_to_cosine_hemisphere, w.square_to_cosine_hemisphere_pdf,
                              100_000, np.random.default_rng(SEED))
    assert check_unbiased(mean, 2 * np.pi / 3, stderr=se, significance=SIG).passed


# ------------------------------------------------------------ mutants and power

N_GRID = [128 * 4 ** j for j in range(7)]  # 128 ... 524288
CASES = [(m.name, c) for m in mutants.MUTANTS.values() for c in m.caught_by]


def _run(mutant, check, sample, pdf):
    if check == "chi2":
        return lambda n, rng: chi2_test(sample, pdf, mutant.domain, n=n, rng=rng)
    if check == "unbiased":
        def run(n, rng):
            mean, se = _estimate_cos2(sample, pdf, n, rng)
            return check_unbiased(mean, 2 * np.pi / 3, stderr=se)
        return run
    if check == "inverse":
        inv = mutant.inverse if sample is mutant.sample else None
        return lambda n, rng: check_inverse(sample, inv, n=n, rng=rng, periodic=(False, True))
    raise AssertionError(check)


@pytest.mark.parametrize("name,check", CASES, ids=[f"{a}-{b}" for a, b in CASES])
def test_every_check_rejects_its_mutants(name, check):
    m = mutants.get(name)
    if check == "pdf_normalized":  # deterministic quadrature, no samples
        assert not check_pdf_normalized(m.pdf, m.domain).passed
        assert check_pdf_normalized(m.correct_pdf, m.domain).passed
        return
    if check == "extremes":  # deterministic boundary points
        r = check_extremes(m.sample, m.pdf, m.domain)
        assert not r.passed, name
        assert check_extremes(m.correct_sample, m.correct_pdf, m.domain).passed
        return
    power = measure_power(_run(m, check, m.sample, m.pdf), N_GRID, replicates=5, target=1.0,
                          rng=np.random.SeedSequence(SEED))
    assert power.n_reject is not None, f"{name} survives {check} up to n = {N_GRID[-1]}"
    # the correct pair passes the same check at the same n (family-wise 1e-3)
    n = power.n_reject
    if check == "inverse":
        ok = check_inverse(m.correct_sample, w.cosine_hemisphere_to_square, n=n, rng=SEED).passed
    elif check == "chi2":
        ok = chi2_test(m.correct_sample, m.correct_pdf, m.domain, n=n, rng=SEED, significance=SIG).passed
    else:
        mean, se = _estimate_cos2(m.correct_sample, m.correct_pdf, n, np.random.default_rng(SEED))
        ok = check_unbiased(mean, 2 * np.pi / 3, stderr=se, significance=SIG).passed
    assert ok


def test_mutants_that_only_boundaries_reveal_pass_chi2():
    # Why check_extremes exists: random u never hits 1.0, so chi2 cannot see these.
    for name in ("table_index_past_end", "cosine_unclamped_sqrt", "ggx_pdf_nan_at_horizon"):
        m = mutants.get(name)
        assert chi2_test(m.sample, m.pdf, m.domain, n=20_000, rng=SEED, significance=SIG).passed


@pytest.mark.parametrize("wrap", [mutants.weight_without_cos, mutants.weight_not_divided_by_pdf,
                                  lambda b: mutants.sample_pdf_scaled(b, 1.05)],
                         ids=["without_cos", "not_divided", "pdf_scaled"])
@pytest.mark.parametrize("bsdf", [Diffuse(), Phong()], ids=["diffuse", "phong"])
def test_weight_consistency_rejects_broken_weights(wrap, bsdf):
    broken = wrap(bsdf)
    power = measure_power(lambda n, rng: check_weight_consistency(broken, WO, n=n, rng=rng),
                          [1, 4, 16, 64], replicates=5, target=1.0, rng=SEED)
    assert power.n_reject is not None and power.n_reject <= 16
    assert "mutant BSDF" in repr(broken)


def test_mutant_registry():
    assert len(mutants.MUTANTS) >= 10
    for m in mutants.MUTANTS.values():
        assert set(m.caught_by) <= {"chi2", "pdf_normalized", "extremes", "inverse", "unbiased"}
        assert m.domain in ("square", "disk", "hemisphere", "sphere")
    with pytest.raises(ValueError, match="name must be one of"):
        mutants.get("nope")
    with pytest.raises(TypeError, match="bsdf must have a callable"):
        mutants.weight_without_cos(object())
    with pytest.raises(ValueError, match="factor must be finite and > 0"):
        mutants.pdf_scaled(Diffuse(), -1.0)


def test_measure_power_arguments():
    run = lambda n, rng: SimpleNamespace(passed=n < 100)  # noqa: E731
    p = measure_power(run, [10, 100, 1000], replicates=3, rng=SEED)
    assert p.n_reject == 100 and p.rejection_rate == (0.0, 1.0)
    p = measure_power(run, [10, 100, 1000], replicates=3, rng=SEED, stop=False)
    assert p.rejection_rate == (0.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="increasing"):
        measure_power(run, [100, 10])
    with pytest.raises(ValueError, match="target must lie"):
        measure_power(run, [10], target=0.0)
    with pytest.raises(TypeError, match="run must be callable"):
        measure_power(None, [10])
