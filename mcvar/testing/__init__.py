"""Statistical and deterministic checks for samplers, pdfs and estimators (layer 3).

A kit that catches the bugs renderers actually ship:

* :func:`chi2_test`: does a sampler draw from the density its pdf claims?
  (Pearson's chi-square goodness of fit, after Mitsuba's ``chi2.py``; a
  sampler may report failed samples, and the pdf then integrates to the
  probability of a valid one);
* :func:`bsdf_chi2_test`: the same for a BSDF's ``sample`` and ``pdf`` at a
  fixed ``wo`` (failed samples and delta lobes excluded, their mass checked);
* :func:`check_pdf_normalized`: does the pdf integrate to 1 (adaptive
  cubature, with its error estimate)?
* :func:`check_weight_consistency`: is a BSDF's sample weight
  ``eval * |cos| / pdf``, and does ``sample`` report the pdf ``pdf`` gives?
* :func:`check_inverse`: do a warp and its inverse round-trip?
* :func:`check_extremes`: does a warp survive ``u = 0`` and ``u = 1.0``
  exactly (no index past an array, no NaN pdf at the pole or horizon)?
* :func:`check_unbiased`: is an estimate within ``z`` standard errors of a
  known value?

Every check returns a frozen result with ``passed`` and a ``message``; none
raises on a failing sampler (bad *arguments* raise ``ValueError`` /
``TypeError``). :mod:`mcvar.testing.mutants` holds deliberately broken
samplers that the checks must reject, and :func:`measure_power` measures how
many samples each check needs to reject one. :mod:`mcvar.testing.grade`
turns the checks into graders of exercises, :mod:`mcvar.testing.exercises`
holds the course's exercises (graders and stubs; their answers live in the
test suite, not here) and :mod:`mcvar.testing.bugs` the classes of the 'find
the bug' notebook.
"""
from ._chi2 import Chi2Result, Chi2Settings, bsdf_chi2_test, chi2_test, sidak_significance
from ._domains import DOMAINS, Domain
from .checks import (BSDFLike, CheckResult, PowerResult, check_extremes, check_inverse, check_pdf_normalized,
                     check_unbiased, check_weight_consistency, measure_power)
from . import grade
from .exercises import exercise

__all__ = [
    "DOMAINS",
    "Chi2Result",
    "CheckResult",
    "PowerResult",
    "BSDFLike",
    "sidak_significance",
    "chi2_test",
    "Chi2Settings",
    "bsdf_chi2_test",
    "check_pdf_normalized",
    "check_weight_consistency",
    "check_inverse",
    "check_extremes",
    "check_unbiased",
    "measure_power",
    "grade",
    "exercise",
]
