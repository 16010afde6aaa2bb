"""Convergence experiments: sweeps, replicates, references, verdicts (layer 6, a package).

A *sweep* runs one target (an integrand of :mod:`mcvar.examples` or a scene
rendered by :func:`mcvar.integrators.render`) for every combination of
method x sampler x spp level x replicate, and turns the replicates into the
numbers the lecture's 'Variance', 'Bias & Consistency' and 'Rendering
Algorithm Chart' slides talk about: per-pixel variance, squared bias, MSE,
relative MSE, wall time, efficiency ``1 / (MSE x time)``, log-log convergence
rates with their standard errors, a test of whether the bias is zero, and a
verdict per method (unbiased, consistent, both or neither).

Runs are independent tasks submitted to any :class:`concurrent.futures.Executor`
(a process pool by default, :class:`SerialExecutor` in-process, or a Dask
client's ``client.get_executor()``). Each replicate's random stream is derived
from the seed and the configuration, never from the order of execution, so the
numbers are identical whichever executor runs them. Finished runs can be cached
on disk, so an interrupted sweep resumes where it stopped.

Modules, each importing only those listed before it
(``tests/test_layering.py``): :mod:`~mcvar.experiments.targets`,
:mod:`~mcvar.experiments.denoising` (a denoised render as a biased but
consistent method), :mod:`~mcvar.experiments.runs` (streams, executors, caches),
:mod:`~mcvar.experiments.reference`, :mod:`~mcvar.experiments.analysis`
(metrics, fits, verdicts), :mod:`~mcvar.experiments.sweeps`,
:mod:`~mcvar.experiments.chart` (the lecture's rendering-methods chart, measured),
and the equal-time comparison of issue 21: :mod:`~mcvar.experiments.compare_args` (its scenes,
methods and options), :mod:`~mcvar.experiments.scene_references` (one cached reference per scene),
:mod:`~mcvar.experiments.equal_time` (one method for a given wall time),
:mod:`~mcvar.experiments.compare_matrix` (the matrix), :mod:`~mcvar.experiments.view_independence`
(radiosity's two views of one solve), :mod:`~mcvar.experiments.slide_pairs` (the lecture's pairs,
BDPT's strategy grid) and :mod:`~mcvar.experiments.compare`, which gathers their public names.
Every public name is importable from ``mcvar.experiments`` itself.
"""
from .targets import Target, integrand_target, lecture_target, load_target, make_target, parse_method, scene_target
from .denoising import DENOISE_SUFFIX, denoise_tv, denoise_weight, denoised_target, photo_target
from .runs import CACHE_VERSION, SerialExecutor, root_seed, run_seed
from .reference import Reference, compute_reference
from .analysis import BlockBias, ConfigMetrics, MethodFits, Verdict, block_bias_test, image_bias_verdict
from .sweeps import SweepResult, SweepSettings, sweep
from .chart import ChartResult, ChartRow, Knob, measure_chart, register_knob
from .compare import CompareResult, equal_time_render, measure_compare, measure_pairs, scene_reference

__all__ = [
    "Target",
    "Reference",
    "ConfigMetrics",
    "MethodFits",
    "Verdict",
    "BlockBias",
    "block_bias_test",
    "image_bias_verdict",
    "SweepResult",
    "SerialExecutor",
    "integrand_target",
    "lecture_target",
    "scene_target",
    "make_target",
    "load_target",
    "parse_method",
    "run_seed",
    "root_seed",
    "compute_reference",
    "sweep",
    "SweepSettings",
    "denoise_tv",
    "denoise_weight",
    "denoised_target",
    "photo_target",
    "DENOISE_SUFFIX",
    "ChartResult",
    "ChartRow",
    "Knob",
    "measure_chart",
    "register_knob",
    "CompareResult",
    "equal_time_render",
    "measure_compare",
    "measure_pairs",
    "scene_reference",
]
