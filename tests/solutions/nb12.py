"""The fixes of notebook 12's 'find the bug' exercises (and the bug as shipped).

Not part of the installed package (see ``__init__``). The planted wrong
solution of each is the class as :mod:`mcvar.testing.bugs` ships it.
"""
import math

import numpy as np

from mcvar import warps
from mcvar.optics import fresnel_dielectric
from mcvar.testing import bugs

from ._base import Solution


class FixedGlass(bugs.FresnelGlass):
    """F of the angle of ``wo`` itself (signed: from inside the roles swap), not of the refracted ray."""

    def reflect_probability(self, wo, wt):
        return fresnel_dielectric(wo[:, 1], 1.0, self.eta)


class FixedGGX(bugs.GGXReflection):
    """The half-vector density D(h) cos(theta_h) times the Jacobian 1 / (4 |wo . h|) of h -> wi."""

    def pdf(self, wo, wi):
        wo, wi = np.asarray(wo, dtype=np.float64), np.asarray(wi, dtype=np.float64)
        wo = np.broadcast_to(wo, wi.shape)
        h = wo + wi
        h = h / np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-300)
        up = (wo[:, 1] > 0) & (wi[:, 1] > 0)
        woh = np.abs(np.sum(wo * h, axis=1))
        return np.where(up, warps.square_to_ggx_pdf(h, self.alpha) / (4.0 * np.maximum(woh, 1e-300)), 0.0)


class FixedLatLongMap(bugs.LatLongMap):
    """The (theta, phi) density divided by the Jacobian sin(theta) of d omega = sin(theta) d theta d phi."""

    def pdf(self, w):
        theta, i, j = self._pixel(w)
        s = np.sin(theta)
        p = self.probabilities[i, j] * self.height * self.width / (2.0 * math.pi ** 2)
        return np.where(s > 0, p / np.where(s > 0, s, 1.0), 0.0)


SOLUTIONS = {
    "12.glass": Solution((FixedGlass(1.5),), (bugs.FresnelGlass(1.5),),
                         "Fresnel evaluated at the refracted ray's angle (the slide's fresnel(ni, nf, *rf)) "
                         "as if it were the angle of incidence"),
    "12.ggx_pdf": Solution((FixedGGX(0.3),), (bugs.GGXReflection(0.3),),
                           "the half vector's density reported as the density of wi: the 1 / (4 wo.h) "
                           "Jacobian dropped"),
    "12.envmap_pdf": Solution((FixedLatLongMap(bugs.BUG_MAP),), (bugs.LatLongMap(bugs.BUG_MAP),),
                              "the (theta, phi) density reported per steradian: the 1 / sin(theta) Jacobian "
                              "dropped"),
}
