"""Every method on every scene at equal wall time (layer 6; ``mcvar compare``, issue 21).

This module gathers the comparison's public names; each part lives in a module of its own:
:mod:`~mcvar.experiments.compare_args` (the scenes, methods and their options),
:mod:`~mcvar.experiments.scene_references` (the shared cached reference of each scene),
:mod:`~mcvar.experiments.equal_time` (one method for a given wall time),
:mod:`~mcvar.experiments.compare_matrix` (the matrix, its cells and winners),
:mod:`~mcvar.experiments.view_independence` (radiosity's two views of one solve) and
:mod:`~mcvar.experiments.slide_pairs` (the lecture's pairs, the BDPT strategy grid, forward
tracing without the camera connection).

The lecture says what each rendering method is *for*: bidirectional tracing
reaches lights that are hard to find, Metropolis 'rendered in the same time'
beats path tracing, photon mapping is for caustics, radiosity for diffuse
light. :func:`measure_compare` measures those claims the way they are made:
each method renders each scene for the same wall time ``seconds``, and its
image is compared with one shared high-spp reference of that scene.

Equal time
----------
A method renders in *rounds*: independent renders of ``b`` samples per pixel
(fresh random streams, so the rounds are independent estimates), combined as
the spp-weighted mean, until the time spent reaches ``seconds``. The first
round has 1 spp; each next round is sized from the measured rate to take
``min(remaining, seconds / 4)``, so the time used exceeds ``seconds`` by at
most the last round. Two exceptions, because their estimate is not a mean of
independent rounds:

* ``sppm`` (:data:`PROGRESSIVE`) shrinks its radius over the iterations of
  one run: a 1-iteration pilot measures the cost of an iteration, then one
  run of as many iterations as fit in the time left (pilot time counted,
  its image discarded).
* ``radiosity`` (:data:`REUSE_PREPARED`) solves once (``Method.prepare``)
  and every round looks the same solve up: the solve is view independent,
  re-solving per round would only repeat it. The solve's time is counted.

Error and efficiency
--------------------
``mse`` is the mean over pixels and channels of ``(image - reference)^2``
(optionally inside a region of the image), the median over ``seeds``
independent runs; ``seconds`` is the median wall time used; efficiency is
``1 / (mse x seconds)`` [1]_ (lecture, 'Efficiency'). The reference is
rendered once per scene and resolution by the method whose estimate is
close to normal there (:data:`REFERENCES`; heavy-tailed path tracing would
make a reference whose error hides in a few pixels), in independent chunks
whose spread gives its own noise (``reference_noise``: compare it with the
MSEs), and is cached on disk keyed by every setting that changes it.

A method that cannot render a scene (its ``check_scene`` raises ValueError)
gets that reason in its cell instead of a number.

References
----------
.. [1] E. Veach, "Robust Monte Carlo Methods for Light Transport
   Simulation", PhD thesis, Stanford University, 1997, sec. 1.4.4 (efficiency).
"""
from __future__ import annotations

from .compare_args import (COMPARE_OPTIONS, DEFAULT_METHODS, DEFAULT_SCENES, _names, _options, _registered,
                           _render, _seed_sequence, check_compare_args, compare_methods, compare_scenes,
                           default_methods, transport_methods)
from .scene_references import REFERENCES, SceneReference, _reference_key, scene_reference
from .equal_time import PROGRESSIVE, REUSE_PREPARED, TimedRender, equal_time_render
from .compare_matrix import (COMPARE_COLUMNS, RUN_COLUMNS, Cell, CompareResult, CompareSettings, _region_slices,
                             _region_text, compare_settings, measure_compare)
from .view_independence import radiosity_views
from .slide_pairs import (CAUSTIC_REGION, METROPOLIS_METHODS, PAIRS, SPHERES_CAUSTIC_REGION, StrategyGrid,
                          forward_pinhole_hits, measure_pairs, measure_strategy_grid)

__all__ = ["DEFAULT_METHODS", "DEFAULT_SCENES", "REFERENCES", "COMPARE_OPTIONS", "PROGRESSIVE", "REUSE_PREPARED",
           "COMPARE_COLUMNS", "RUN_COLUMNS", "SceneReference", "TimedRender", "Cell", "CompareResult",
           "CompareSettings", "compare_settings", "check_compare_args", "scene_reference", "equal_time_render",
           "measure_compare", "radiosity_views", "compare_scenes", "compare_methods", "transport_methods",
           "default_methods", "CAUSTIC_REGION", "SPHERES_CAUSTIC_REGION", "PAIRS", "METROPOLIS_METHODS",
           "measure_pairs", "StrategyGrid", "measure_strategy_grid", "forward_pinhole_hits"]
