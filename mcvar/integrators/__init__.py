"""Rendering methods and :func:`render` (layer 5): a package of registered methods.

=================  ===========================================================
module             holds
=================  ===========================================================
``registry``       :class:`Method`, :func:`register`, :data:`METHODS`
``settings``       :class:`PathSettings` (a path's depth, MIS, kernel, light
                   sampling, roulette, visible lights), the methods' strategies
``film``           :class:`BatchJob`, :class:`BatchResult`, :class:`Film`,
                   :func:`splat`, :class:`Render`
``stream``         the per-path sample stream: column layout, :class:`SampleStream`
``emitters``       next-event estimation (``Emitters.sample_li``/``pdf_li``) and
                   light subpaths (:func:`sample_le`, :func:`pdf_le`)
``directions``     :func:`sample_directions`: where a vertex chooses its next
                   direction (both loops; the seam for path guiding)
``state``          the wavefront: ``PathState``, scene tables, MIS weights of
                   emission, Russian roulette, shadow rays
``lambertian``     the loop written out for Lambertian triangles and one quad light
``path``           ``path``, ``path_bsdf``, ``direct``, ``direct_light``,
                   ``direct_bsdf``; :func:`trace_paths`
``aov``            ``albedo``, ``normal``, ``depth``, ``raster``
``position``       the ``position`` AOV (the example of a one-module method)
``light``          ``light`` (particle tracing); light and camera subpaths
``bdpt``           ``bdpt``: every (s, t) strategy weighted by MIS
``radiosity``      ``radiosity``: finite-element radiosity (patches, form
                   factors, solve, first-hit lookup)
``photon``         ``photon``: photon tracing, photon maps, visible points,
                   density estimation (Jensen 1996)
``sppm``           ``sppm``: stochastic progressive photon mapping
``allocation``     how samples are spread over pixels: :class:`Uniform`,
                   :class:`Adaptive` (unbiased two-stage), :func:`allocate`
``driver``         :func:`render` (every method, every allocation),
                   :class:`WorkerPool`, batches and seeds
``pssmlt``         primary-sample-space Metropolis light transport (``chain``)
``mmlt``           multiplexed Metropolis light transport over BDPT's strategies (``chain``)
=================  ===========================================================

A new method is one module that builds a :class:`Method` and calls
:func:`register`, plus one import line here (docs/integrators.md).
"""
from __future__ import annotations

from .registry import KINDS, METHODS, Method, get_method, register
from .settings import HEURISTICS, KERNELS, PathSettings
from .film import BatchJob, BatchResult, Film, Render, camera_result, splat
from .stream import SAMPLER_DIM, stream_dim
from .emitters import LIGHT_SAMPLING, VISIBLE_LIGHTS, Emitters, LightOrigins, VisibleLights, pdf_le, sample_le
from .state import RR_MAX_DEPTH, RR_START_DEPTH, shadow_rays as _shadow_rays
from .path import trace_camera_paths, trace_paths
from .aov import aov_method
from . import position  # noqa: F401  (registers the 'position' AOV: the example method)
from . import light, bdpt  # noqa: F401  (register 'light' and 'bdpt', issue 11)
from . import radiosity, photon, sppm  # noqa: F401  (register radiosity, photon, sppm)
from .allocation import ALLOCATIONS, PATHS_PER_BATCH, Adaptive, AdaptiveRender, Uniform, allocate
from .driver import BYTES_PER_PATH, MAX_RENDER_BYTES, WorkerPool, estimate_render_bytes, render
from .stream import WHOLE_SET_FLOATS, whole_pattern as _whole_pattern

from . import pssmlt  # noqa: F401  (registers 'pssmlt')
from . import mmlt  # noqa: F401  (registers 'mmlt', issue 22)

#: Method names accepted by :func:`render` when the package was imported
#: (:data:`METHODS` is the live registry).
INTEGRATORS = tuple(METHODS)

__all__ = ["INTEGRATORS", "HEURISTICS", "KERNELS", "KINDS", "METHODS", "Method", "register", "get_method",
           "BatchJob", "BatchResult", "Film", "Render", "splat", "camera_result", "render", "trace_paths",
           "trace_camera_paths", "WorkerPool", "PATHS_PER_BATCH", "MAX_RENDER_BYTES", "BYTES_PER_PATH",
           "estimate_render_bytes", "SAMPLER_DIM", "stream_dim", "Emitters", "LightOrigins", "sample_le", "pdf_le",
           "aov_method", "RR_START_DEPTH", "RR_MAX_DEPTH", "LIGHT_SAMPLING",
           "VISIBLE_LIGHTS", "VisibleLights", "PathSettings", "ALLOCATIONS", "Uniform", "Adaptive",
           "AdaptiveRender", "allocate"]
