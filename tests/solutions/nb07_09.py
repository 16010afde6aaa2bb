"""Reference and planted wrong solutions of the exercises of notebooks 07-09.

Not part of the installed package (see ``__init__``).
"""
import math

import numpy as np

from ._base import Solution


# 07.bdpt_weight --------------------------------------------------------------

def bdpt_power_weight(pdfs, s):
    """Power heuristic (beta = 2) over every strategy; one that cannot make the path has pdf 0."""
    p2 = np.asarray(pdfs, dtype=np.float64) ** 2
    return p2[:, s] / p2.sum(axis=1)


def bdpt_uniform_weight(pdfs, s):
    """1 / k over all k strategies, including those that cannot produce the path (pdf 0)."""
    pdfs = np.asarray(pdfs, dtype=np.float64)
    return np.full(pdfs.shape[0], 1.0 / pdfs.shape[1])


# 07.light_splat --------------------------------------------------------------

def light_splat(cos_light, cos_camera, distance, film_area):
    """G W_e: cos_l cos_c / d^2 times the pinhole's importance 1 / (A cos_c^4)."""
    return cos_light * cos_camera / distance ** 2 / (film_area * cos_camera ** 4)


def light_splat_without_cos4(cos_light, cos_camera, distance, film_area):
    """W_e = 1 / A: the film treated as if every pixel saw the same solid angle."""
    return cos_light * cos_camera / distance ** 2 / film_area


# 08.large_step ---------------------------------------------------------------

def large_step_acceptance(f_x, f_y, q_x, q_y):
    """Metropolis-Hastings: min(1, f(y) q(x) / (f(x) q(y)))."""
    num, den = f_y * q_x, f_x * q_y
    return np.where(den > 0, np.minimum(1.0, num / np.where(den > 0, den, 1.0)), 1.0)


def large_step_acceptance_symmetric(f_x, f_y, q_x, q_y):
    """The slide's min(1, f(y) / f(x)): right only for a symmetric (uniform) large step."""
    return np.where(f_x > 0, np.minimum(1.0, f_y / np.where(f_x > 0, f_x, 1.0)), 1.0)


# 08.chain_stderr -------------------------------------------------------------

def batch_means_stderr(h, batches=40):
    """Batch means: the spread of the means of 40 consecutive batches."""
    h = np.asarray(h, dtype=np.float64)
    m = h.size // batches
    means = h[:m * batches].reshape(batches, m).mean(axis=1)
    return float(means.std(ddof=1) / math.sqrt(batches))


def naive_stderr(h):
    """s / sqrt(N): an iid error bar for correlated samples, too narrow by sqrt(tau)."""
    h = np.asarray(h, dtype=np.float64)
    return float(h.std(ddof=1) / math.sqrt(h.size))


# 09.photon_density -----------------------------------------------------------

def photon_radiance(dist2, power, radius, f):
    """sum over photons within the radius of f Phi / (pi r^2)."""
    inside = dist2 < radius ** 2
    return float(np.sum(f * power[inside]) / (math.pi * radius ** 2))


def photon_radiance_radius_unsquared(dist2, power, radius, f):
    """Squared distances compared with the radius, not its square: a disk of radius sqrt(r)."""
    inside = dist2 < radius
    return float(np.sum(f * power[inside]) / (math.pi * radius ** 2))


# 09.jacobi -------------------------------------------------------------------

def jacobi_step(b, e, rho, f):
    """B' = E + rho (F B)."""
    return e + rho * (f @ b)


def jacobi_step_without_albedo(b, e, rho, f):
    """B' = E + F B: every patch reflects everything it receives."""
    return e + f @ b


SOLUTIONS = {
    "07.bdpt_weight": Solution((bdpt_power_weight,), (bdpt_uniform_weight,),
                               "uniform weights 1/k over all strategies, also those that cannot produce the path: "
                               "paths beyond x = 1/2 get weights summing to 2/3"),
    "07.light_splat": Solution((light_splat,), (light_splat_without_cos4,),
                               "the pinhole's importance taken as 1 / A, without its 1 / cos^4 (vignetting)"),
    "08.large_step": Solution((large_step_acceptance,), (large_step_acceptance_symmetric,),
                              "the slide's f(x')/f(x) for a large step drawn from a non-uniform q"),
    "08.chain_stderr": Solution((batch_means_stderr,), (naive_stderr,),
                                "s / sqrt(N) for a chain with tau = 19: the intervals cover a third of the time"),
    "09.photon_density": Solution((photon_radiance,), (photon_radiance_radius_unsquared,),
                                  "dist2 < radius instead of dist2 < radius**2"),
    "09.jacobi": Solution((jacobi_step,), (jacobi_step_without_albedo,),
                          "B' = E + F B: the albedo forgotten"),
}
