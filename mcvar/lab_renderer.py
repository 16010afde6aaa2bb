"""A student's small renderer, with the three bugs students make (layer 4).

The toy renderer of the lab *Is my renderer unbiased?*
(``notebooks/11_is_my_renderer_unbiased.ipynb``), plugged into mcvar the way
any renderer is (docs/guide-any-renderer.md)::

    mcvar converge --target mcvar.lab_renderer:evaluate --out out/lab

Each pixel of the 8 x 8 image looks into its own **furnace**: the inside of a
closed diffuse sphere whose walls all have albedo ``rho`` (RGB, different per
pixel) and emit ``L_e``. Every wall point sees the same radiance, so the
rendering equation ``L = L_e + rho L`` has the exact solution
``L = L_e / (1 - rho)`` (:data:`EXACT`), and a path tracer only has to get
its estimator right: the geometry cancels out. The path tracer below is the
loop every student writes: add the emission, sample a direction **uniformly**
on the hemisphere, multiply the throughput by ``f cos / pdf``, play Russian
roulette from the fourth vertex on.

Methods (:data:`METHODS`):

``'path'``
    Correct: ``f = rho / pi``, ``pdf = 1 / (2 pi)``, survivors divided by
    their survival probability. Unbiased.
``'no_cosine'``
    The throughput multiplied by ``f / pdf``: the cosine of the rendering
    equation forgotten. Each bounce keeps ``2 rho`` instead of ``rho``.
``'pdf_constant'``
    The pdf off by a constant: ``1 / pi`` (the cosine pdf's constant) for
    uniform directions. Each bounce keeps ``rho / 2``.
``'roulette_no_division'``
    Russian roulette without the division by the survival probability.

Every bug is a bias the bias test of ``mcvar converge`` sees at any spp;
none is visible as noise.
"""
from __future__ import annotations

import math

import numpy as np

from ._validation import as_rng, check_choice, check_count

__all__ = ["METHODS", "SAMPLERS", "SPP", "EXACT", "ALBEDO", "EMISSION", "RR_DEPTH", "evaluate", "furnace_render"]

METHODS = ("path", "no_cosine", "pdf_constant", "roulette_no_division")
SAMPLERS = ("random",)
SPP = (1, 4, 16, 64)

_Y, _X = np.mgrid[0:8, 0:8] / 7.0
#: Albedo per pixel and channel, in [0.2, 0.45] (so that even the bug without the cosine,
#: which keeps 2 rho per bounce, has a finite mean).
ALBEDO = np.stack([0.2 + 0.25 * _X, 0.2 + 0.25 * _Y, np.full_like(_X, 0.3)], axis=-1)
#: Emitted radiance of the walls, per pixel and channel.
EMISSION = np.stack([np.full_like(_X, 0.5), 0.3 + 0.4 * _X * _Y, 0.6 - 0.3 * _Y], axis=-1)
#: The exact image: L = L_e / (1 - rho) in every pixel.
EXACT = EMISSION / (1.0 - ALBEDO)
#: Russian roulette starts at this vertex.
RR_DEPTH = 3


def _uniform_bounce(u):
    """Uniform hemisphere sampling: cos(theta) = u is uniform, pdf 1 / (2 pi)."""
    return u, np.full(u.shape, 1.0 / (2.0 * math.pi))


def _trace(rho, le, g, sample_bounce, *, cosine: bool = True, divide: bool = True):
    """Mean radiance of furnace paths, one per row of ``rho`` / ``le`` (m, 3)."""
    n = rho.shape[0]
    radiance = np.zeros((n, 3))
    beta = np.ones((n, 3))
    alive = np.arange(n)
    f = rho / math.pi                                              # Lambertian BRDF
    depth = 0
    while alive.size and depth < 1000:
        radiance[alive] += beta[alive] * le[alive]                 # the wall's emission
        cos, pdf = sample_bounce(g.random(alive.size))             # cos theta of the new direction, its pdf
        cos, pdf = np.asarray(cos, dtype=np.float64), np.asarray(pdf, dtype=np.float64)
        if cos.shape != (alive.size,) or pdf.shape != (alive.size,):
            raise ValueError(f"sample_bounce(u) must return cos and pdf of shape ({alive.size},); got "
                             f"{cos.shape} and {pdf.shape}")
        if np.any(~(pdf > 0)) or np.any(~((cos >= 0) & (cos <= 1))):
            raise ValueError("sample_bounce(u) must return cos in [0, 1] and pdf > 0")
        if cosine:
            beta[alive] *= f[alive] * cos[:, None] / pdf[:, None]
        else:                                                      # the bug: f / pdf
            beta[alive] *= f[alive] / pdf[:, None]
        depth += 1
        if depth >= RR_DEPTH:
            q = np.minimum(0.95, beta[alive].max(axis=1))          # survival probability
            survive = g.random(alive.size) < q
            if divide:
                beta[alive[survive]] /= q[survive, None]
            alive = alive[survive]
    return radiance


def evaluate(method: str, sampler: str, spp: int, rng) -> np.ndarray:
    """One independent 8 x 8 RGB image from ``spp`` paths per pixel.

    Parameters
    ----------
    method : {'path', 'no_cosine', 'pdf_constant', 'roulette_no_division'}
    sampler : {'random'}
    spp : int
    rng : numpy Generator (or a seed)

    Returns
    -------
    ndarray, shape (8, 8, 3)
        Linear radiance, the mean of ``spp`` path estimates per pixel.
    """
    method = check_choice(method, "method", METHODS)
    check_choice(sampler, "sampler", SAMPLERS)
    spp = check_count(spp, "spp")
    g = as_rng(rng)
    rho = np.repeat(ALBEDO.reshape(-1, 3), spp, axis=0)          # (paths, 3)
    le = np.repeat(EMISSION.reshape(-1, 3), spp, axis=0)
    if method == "pdf_constant":                                   # the bug: 1 / pi for uniform directions
        bounce = lambda u: (u, np.full(u.shape, 1.0 / math.pi))   # noqa: E731
    else:
        bounce = _uniform_bounce
    radiance = _trace(rho, le, g, bounce, cosine=method != "no_cosine",
                      divide=method != "roulette_no_division")
    return radiance.reshape(8, 8, spp, 3).mean(axis=2)


def furnace_render(sample_bounce, spp: int, rng=None) -> np.ndarray:
    """The lab's correct path tracer with a bounce sampler of your own.

    Parameters
    ----------
    sample_bounce : callable
        ``sample_bounce(u) -> (cos, pdf)``: from uniform numbers ``u`` (m,),
        the cosine of each sampled direction with the normal and its density
        per steradian (the azimuth does not matter in a furnace).
    spp : int
    rng : seed

    Returns
    -------
    ndarray, shape (8, 8, 3)
    """
    if not callable(sample_bounce):
        raise TypeError(f"sample_bounce must be callable; got {type(sample_bounce).__name__}")
    spp = check_count(spp, "spp")
    g = as_rng(rng)
    rho = np.repeat(ALBEDO.reshape(-1, 3), spp, axis=0)
    le = np.repeat(EMISSION.reshape(-1, 3), spp, axis=0)
    return _trace(rho, le, g, sample_bounce).reshape(8, 8, spp, 3).mean(axis=2)
