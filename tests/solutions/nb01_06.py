"""Reference and planted wrong solutions of the exercises of notebooks 01-06.

Not part of the installed package: a student's ``pip install mcvar`` does
not carry these (``tests/test_grade.py`` checks it). They use NumPy and
:mod:`mcvar.warps` only, as a student would.
"""
import math

import numpy as np

from mcvar import warps

from ._base import Solution, as_rng


def _jittered(n, rng=None):
    k = math.isqrt(n)
    g = as_rng(rng)
    i, j = np.divmod(np.arange(n), k)
    return np.stack([(i + g.random(n)) / k, (j + g.random(n)) / k], axis=1)

def _jittered_wrong(n, rng=None):
    # a cell per sample, but the jitter is only half a cell: stratified, not uniform
    k = math.isqrt(n)
    g = as_rng(rng)
    i, j = np.divmod(np.arange(n), k)
    return np.stack([(i + 0.5 * g.random(n)) / k, (j + 0.5 * g.random(n)) / k], axis=1)

def _radical_inverse2(i):
    i = np.asarray(i, dtype=np.uint64)
    out = np.zeros(i.shape)
    scale = 0.5
    while np.any(i):
        out += (i & np.uint64(1)) * scale
        i = i >> np.uint64(1)
        scale *= 0.5
    return out

def _hammersley(n, rng=None):
    i = np.arange(n)
    return np.stack([i / n, _radical_inverse2(i)], axis=1)

def _hammersley_wrong(n, rng=None):
    # the binary digits of i read in order instead of mirrored: y = i / n, every point on the diagonal
    i = np.arange(n)
    return np.stack([i / n, i / n], axis=1)

def _board(x):
    return ((np.floor(x[:, 0]) + np.floor(x[:, 1])) % 2 == 0).astype(np.float64)

def _checkerboard(n, rng=None):
    x = 2.0 * as_rng(rng).random((n, 2))          # uniform on [0, 2]^2, p = 1/4
    return float(np.mean(_board(x) / 0.25))

def _checkerboard_wrong(n, rng=None):
    x = 2.0 * as_rng(rng).random((n, 2))
    return float(np.mean(_board(x)))             # the mean of f, not the integral: forgot 1/p

def _cos2(w):
    return np.maximum(w[:, 1], 0.0) ** 2

def _cosine_estimate(n, rng=None):
    w = warps.square_to_cosine_hemisphere(as_rng(rng).random((n, 2)))
    return float(np.mean(_cos2(w) / warps.square_to_cosine_hemisphere_pdf(w)))

def _cosine_estimate_wrong(n, rng=None):
    w = warps.square_to_cosine_hemisphere(as_rng(rng).random((n, 2)))
    return float(np.mean(_cos2(w) * 2.0 * math.pi))   # the uniform estimator's 2 pi with cosine samples


class LambertianSolution:
    """Reference solution of exercise ``03.lambertian``: f = rho / pi, cosine sampling."""

    def __init__(self, albedo=0.8, *, pdf_without_cos=False):
        self.albedo = float(albedo)
        self._wrong = pdf_without_cos

    def eval(self, wo, wi):
        wi = np.asarray(wi, dtype=np.float64)
        up = (np.asarray(wo)[..., 1] > 0) & (wi[..., 1] > 0)
        return np.where(up, self.albedo / math.pi, 0.0)

    def pdf(self, wo, wi):
        wi = np.asarray(wi, dtype=np.float64)
        if self._wrong:   # the classic slip: uniform-hemisphere pdf for cosine samples
            return np.where(wi[..., 1] > 0, 1.0 / (2.0 * math.pi), 0.0)
        return np.where(wi[..., 1] > 0, wi[..., 1] / math.pi, 0.0)

    def sample(self, wo, u):
        wi = warps.square_to_cosine_hemisphere(u)
        p = self.pdf(wo, wi)
        with np.errstate(divide="ignore", invalid="ignore"):
            weight = np.where(p > 0, self.eval(wo, wi) * wi[:, 1] / np.where(p > 0, p, 1.0), 0.0)
        return wi, weight, p

def _schlick(cos_theta, n1, n2):
    r0 = ((n1 - n2) / (n1 + n2)) ** 2
    return r0 + (1.0 - r0) * (1.0 - cos_theta) ** 5

def _schlick_wrong(cos_theta, n1, n2):
    r0 = ((n1 - n2) / (n1 + n2)) ** 2
    return r0 + (1.0 - r0) * (1.0 - cos_theta) ** 4   # exponent 4: right at 0 and 90 degrees only

def _sphere_flip(u):
    u = np.asarray(u, dtype=np.float64)
    flip = u[:, 0] >= 0.5
    u0 = np.where(flip, 2.0 * u[:, 0] - 1.0, 2.0 * u[:, 0])       # reuse the coin's bit
    w = warps.square_to_uniform_hemisphere(np.stack([np.minimum(u0, 1.0), u[:, 1]], axis=1))
    w[flip, 1] *= -1.0
    return w

def _sphere_flip_pdf(w):
    return np.full(np.shape(w)[0], 1.0 / (4.0 * math.pi))

def _sphere_flip_pdf_wrong(w):
    return np.full(np.shape(w)[0], 1.0 / (2.0 * math.pi))          # forgot 'double the options, half the pdf'

def _sample_pixels(image, r):
    h = image.shape[0]
    theta = (np.arange(h) + 0.5) * math.pi / h
    pdf = (image * np.sin(theta)[:, None]).ravel()
    cdf = np.cumsum(pdf / pdf.sum())
    idx = np.searchsorted(cdf, r, side="right")            # upper_bound
    last = np.flatnonzero(pdf > 0)[-1]                      # r -> 1 with rounding: last bright pixel
    return np.minimum(idx, last)

def _sample_pixels_wrong(image, r):
    cdf = np.cumsum(image.ravel() / image.sum())            # forgot sin(theta): the poles too likely
    return np.minimum(np.searchsorted(cdf, r, side="right"), image.size - 1)

def _roulette(beta, u):
    q = np.minimum(0.95, beta)                # survival probability
    return np.where(u < q, beta / q, 0.0)

def _roulette_wrong(beta, u):
    q = np.minimum(0.95, beta)
    return np.where(u < q, beta, 0.0)         # survivors not re-weighted by 1/q

def _power_heuristic(p_own, p_other):
    a, b = p_own ** 2, p_other ** 2
    return np.where(a + b > 0, a / np.where(a + b > 0, a + b, 1.0), 0.0)

def _power_heuristic_wrong(p_own, p_other):
    s = p_own + p_other                       # squares the balance weight: weights no longer sum to 1
    return np.where(s > 0, (p_own / np.where(s > 0, s, 1.0)) ** 2, 0.0)

def _sample_variance(n, rng=None):
    x = as_rng(rng).random(n)
    return float(np.var(x, ddof=1))

def _sample_variance_wrong(n, rng=None):
    x = as_rng(rng).random(n)
    return float(np.var(x))                   # ddof = 0: biased by (n - 1) / n, consistent

def _quarter_disk(x):
    return (x[:, 0] ** 2 + x[:, 1] ** 2 < 1.0).astype(np.float64)

def _grid_estimate(n, rng=None):
    m = max(1, math.isqrt(n))
    c = (np.arange(m) + 0.5) / m
    x, y = np.meshgrid(c, c)
    return float(np.mean(_quarter_disk(np.stack([x.ravel(), y.ravel()], axis=1))))

def _grid_estimate_wrong(n, rng=None):
    return float(_quarter_disk(as_rng(rng).random((1, 2)))[0])   # one random sample, whatever n


SOLUTIONS = {
    "01.jittered": Solution((_jittered,), (_jittered_wrong,),
                            "a random offset of half a cell: one point per stratum, but never in the upper half "
                            "of any cell"),
    "01.hammersley": Solution((_hammersley,), (_hammersley_wrong,),
                              "digits not mirrored about the point: Phi(i) = i / n puts every point on the diagonal"),
    "02.checkerboard": Solution((_checkerboard,), (_checkerboard_wrong,),
                                "averages f without dividing by the pdf (estimates the mean 1/2, not the integral 2)"),
    "02.cosine": Solution((_cosine_estimate,), (_cosine_estimate_wrong,),
                          "multiplies by the uniform 2 pi while drawing cosine-distributed directions"),
    "03.lambertian": Solution((LambertianSolution(0.8),), (LambertianSolution(0.8, pdf_without_cos=True),),
                              "reports the uniform pdf 1/(2 pi) for cosine-distributed samples"),
    "03.schlick": Solution((_schlick,), (_schlick_wrong,),
                           "exponent 4 instead of 5 (agrees at normal and grazing incidence)"),
    "04.sphere_flip": Solution((_sphere_flip, _sphere_flip_pdf), (_sphere_flip, _sphere_flip_pdf_wrong),
                               "keeps the hemisphere's pdf 1/(2 pi): the pdf integrates to 2"),
    "04.envmap_cdf": Solution((_sample_pixels,), (_sample_pixels_wrong,),
                              "pixel probability proportional to L instead of L sin(theta)"),
    "05.roulette": Solution((_roulette,), (_roulette_wrong,),
                            "survivors keep their throughput instead of dividing it by the survival probability"),
    "05.mis_weight": Solution((_power_heuristic,), (_power_heuristic_wrong,),
                              "(p_own / (p_own + p_other))^2: the weights of a sample do not sum to 1"),
    "06.sample_variance": Solution((_sample_variance,), (_sample_variance_wrong,),
                                   "divides by n instead of n - 1 (biased by a factor 3/4 at n = 4, consistent)"),
    "06.grid_consistent": Solution((_grid_estimate,), (_grid_estimate_wrong,),
                                   "a single random sample whatever n: unbiased, but its error never falls"),
}
