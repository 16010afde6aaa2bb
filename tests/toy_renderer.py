"""A tiny 'renderer' for tests of ``mcvar converge --target toy_renderer:evaluate``.

An 8 x 8 gradient image estimated with Monte Carlo noise: ``'mc'`` is
unbiased (Gamma(spp, 1/spp) multiplicative noise, mean 1), ``'dim'`` loses
10 % of the light (biased, not consistent), like a renderer that stops paths
early.
"""
import numpy as np

METHODS = ("mc", "dim")
SPP = (1, 4, 16, 64)
_Y, _X = np.mgrid[0:8, 0:8] / 7.0
EXACT = np.stack([0.2 + 0.6 * _X, 0.2 + 0.6 * _Y, np.full_like(_X, 0.5)], axis=-1)


def evaluate(method, sampler, spp, rng):
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}; got {method!r}")
    scale = 1.0 if method == "mc" else 0.9
    return scale * EXACT * rng.gamma(spp, 1.0 / spp, size=EXACT.shape)


def reference(rng):
    """Not used when EXACT is set; kept to show the optional hook."""
    return EXACT * rng.gamma(4096, 1.0 / 4096, size=EXACT.shape)


NOT_CALLABLE = 3
