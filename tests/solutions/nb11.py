"""Reference and planted wrong solutions of the lab notebook 11's exercises.

Not part of the installed package (see ``__init__``).
"""
import math

import numpy as np

from ._base import Solution


def cosine_bounce(u):
    """Malley / inversion: cos(theta) = sqrt(u) has density cos / pi per steradian."""
    c = np.sqrt(u)
    return c, c / math.pi


def cosine_bounce_uniform_pdf(u):
    """Cosine-distributed directions reported with the uniform pdf 1 / (2 pi)."""
    c = np.sqrt(u)
    return c, np.full(c.shape, 1.0 / (2.0 * math.pi))


def furnace_radiance(le, rho, depth):
    """L = L_e / (1 - rho) for unlimited paths, L_e (1 - rho^D) / (1 - rho) for D vertices."""
    le, rho, depth = (np.asarray(a, dtype=np.float64) for a in (le, rho, depth))
    partial = np.where(rho == 1.0, le * depth, le * (1.0 - rho ** depth) / np.where(rho == 1.0, 1.0, 1.0 - rho))
    return np.where(depth > 0, partial, le / (1.0 - rho))


def furnace_radiance_reflected_only(le, rho, depth):
    """The reflected part rho L alone: the emission of the first vertex forgotten."""
    return furnace_radiance(le, rho, depth) - np.asarray(le, dtype=np.float64)


SOLUTIONS = {
    "11.cosine_bounce": Solution((cosine_bounce,), (cosine_bounce_uniform_pdf,),
                                 "cosine-distributed directions with the uniform pdf: every bounce keeps 2 rho cos^2"),
    "11.furnace_exact": Solution((furnace_radiance,), (furnace_radiance_reflected_only,),
                                 "rho L_e / (1 - rho): the emission seen directly left out"),
}
