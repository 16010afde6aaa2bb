"""Monte Carlo estimators that report their error (layer 3, a package).

The lecture's 'Monte Carlo Estimator' slide, ``(1/N) sum_j f(X_j) / p(X_j)``,
with what is needed to trust the number it returns:

- :class:`Estimate`: a mean with its per-sample variance, standard error and
  interval, and the error model used (``'iid'`` or randomized
  ``'replicates'``); independent runs merge exactly (Chan et al.), so 10^9
  samples taken in batches equal one pass, to rounding.
- :func:`estimate`: ``f``, a warp ``sample`` and its ``pdf`` over *any* 2D
  sampler of :mod:`mcvar.samplers` (importance sampling when the warp is not
  uniform, stratified or QMC estimation when the sampler is), with honest
  error bars for stratified and QMC points and a to-tolerance mode;
  :func:`estimate_mean` does the same for a ready-made per-sample
  contribution ``g(u)`` (e.g. :data:`mcvar.examples.PROBLEMS` methods).
- :func:`mis_estimate` (multi-sample MIS, ``n_k`` samples per strategy) and
  :func:`one_sample_mis`, weighted by :func:`balance_heuristic`,
  :func:`power_heuristic` or :func:`mis_weights`.
- :func:`replicate_study` and :func:`convergence_study`: R independent runs
  from ``SeedSequence(seed).spawn(R)``; empirical bias with its interval,
  variance, MSE, efficiency and the log-log error slope with its uncertainty;
  :func:`replicate_moments` and :func:`efficiency` (``1 / (MSE x time)``), the
  one implementation of replicate statistics, shared with :mod:`mcvar.experiments`.

Lecture slides: 'The Monte Carlo Estimator', 'Variance', 'Bias &
Consistency', 'Consistent Or Unbiased?', 'Multiple Importance Sampling'.

Modules, each importing only those listed before it
(``tests/test_layering.py``): :mod:`~mcvar.estimators.monte_carlo`
(``Estimate``, ``estimate``, ``estimate_mean``, ``contribution``),
:mod:`~mcvar.estimators.mis` (heuristics, MIS estimators,
``hemisphere_estimate``), :mod:`~mcvar.estimators.studies` (replicate and
convergence studies). Every public name is importable from
``mcvar.estimators`` itself.
"""
from .monte_carlo import Estimate, EstimateSettings, contribution, estimate, estimate_mean
from .mis import (balance_heuristic, hemisphere_estimate, mis_estimate, mis_weights, one_sample_mis,
                  one_sample_mis_contribution, power_heuristic)
from .studies import (ConvergenceStudy, ReplicateStudy, convergence_study, efficiency, replicate_moments,
                      replicate_study)

__all__ = [
    "Estimate",
    "estimate",
    "estimate_mean",
    "EstimateSettings",
    "contribution",
    "one_sample_mis_contribution",
    "hemisphere_estimate",
    "mis_estimate",
    "one_sample_mis",
    "balance_heuristic",
    "power_heuristic",
    "mis_weights",
    "ReplicateStudy",
    "replicate_study",
    "ConvergenceStudy",
    "convergence_study",
    "replicate_moments",
    "efficiency",
]
