"""What :func:`~mcvar.experiments.compare_matrix.measure_compare` may be asked: the scenes, the
methods, their options in the comparison and the validation of the arguments (issue 21).

The one call to :func:`mcvar.integrators.render` of the comparison is :func:`_render` here, so that
tests can count or replace it in one place.
"""
from __future__ import annotations

import math
import zlib

import numpy as np

from .._validation import check_count

__all__ = ["DEFAULT_METHODS", "DEFAULT_SCENES", "COMPARE_OPTIONS", "compare_scenes", "compare_methods",
           "transport_methods", "default_methods", "check_compare_args"]

#: The preferred order of the light-transport methods in the matrix; every other registered
#: transport method (:func:`transport_methods`, e.g. one registered later) follows in
#: registration order (:func:`default_methods`).
DEFAULT_METHODS = ("path", "path_bsdf", "direct", "direct_light", "direct_bsdf", "light", "bdpt", "pssmlt",
                   "mmlt", "photon", "sppm", "radiosity")

#: The scenes of issue 21 (``cornell`` is the diffuse box radiosity is for).
DEFAULT_SCENES = ("cornell", "cornell-point", "cornell-door", "cornell-caustic", "veach-mis")

#: Options of the methods in the comparison (low accuracy per round, so that rounds fit in seconds).
COMPARE_OPTIONS = {
    "photon": {"photons": 16384},
    "sppm": {"photons": 16384},
    "radiosity": {"patch_size": 140.0, "rays_per_side": 32, "emitter_rays": 16384},
}


def _render(scene, **kwargs):
    """:func:`mcvar.integrators.render` (one name, so tests can count the calls)."""
    from ..integrators import render

    return render(scene, **kwargs)


def _registered() -> dict:
    from ..integrators import METHODS

    return METHODS


def compare_scenes() -> tuple:
    """Scene names :func:`measure_compare` accepts (those of :data:`mcvar.scene.SCENES`)."""
    from ..scene import SCENES

    return tuple(SCENES)


def compare_methods() -> tuple:
    """Methods :func:`measure_compare` accepts: every registered one (:data:`mcvar.integrators.METHODS`)."""
    return tuple(_registered())



def transport_methods() -> tuple:
    """The registered methods that estimate light transport: every one but the first-hit methods
    without a solve (the AOVs and rasterization, which estimate no image of the scene's light)."""
    return tuple(name for name, m in _registered().items() if m.kind != "first_hit" or m.prepare is not None)


def default_methods() -> tuple:
    """The methods of the matrix by default: :func:`transport_methods`, those of
    :data:`DEFAULT_METHODS` first in its order, then the others in registration order."""
    known = transport_methods()
    return tuple(m for m in DEFAULT_METHODS if m in known) + tuple(m for m in known if m not in DEFAULT_METHODS)


def _names(value, name: str, known: tuple) -> tuple:
    if isinstance(value, str):
        value = [v.strip() for v in value.split(",") if v.strip()]
    try:
        value = tuple(dict.fromkeys(value))
    except TypeError:
        raise TypeError(f"{name} must be a comma-separated string or a sequence of names; got {value!r}") from None
    if not value:
        raise ValueError(f"{name} must name at least one of {known}")
    unknown = [v for v in value if v not in known]
    if unknown:
        raise ValueError(f"{name}: unknown {unknown}; expected names from {known}")
    return value


def check_compare_args(scenes, methods, seconds, res, seeds=1) -> tuple:
    """Validate the comparison's arguments before any work: ``(scenes, methods, seconds, res, seeds)``.

    Unknown scene or method names, ``seconds <= 0`` (or not finite), ``res <= 0``
    and ``seeds <= 0`` are a ValueError naming the argument.
    """
    scenes = _names(scenes, "scenes", compare_scenes())
    methods = _names(methods, "methods", compare_methods())
    try:
        seconds = float(seconds)
    except (TypeError, ValueError):
        raise TypeError(f"seconds must be a number; got {seconds!r}") from None
    if not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds must be finite and > 0; got {seconds}")
    res = check_count(res, "res")
    seeds = check_count(seeds, "seeds")
    return scenes, methods, seconds, res, seeds


def _options(method: str, options=None) -> dict:
    """The comparison's options of ``method`` that the registered method accepts."""
    wanted = dict(COMPARE_OPTIONS.get(method, {}))
    wanted.update((options or {}).get(method, {}))
    accepted = _registered()[method].options
    return {k: v for k, v in wanted.items() if k in accepted}


def _seed_sequence(*parts) -> np.random.SeedSequence:
    return np.random.SeedSequence([p if isinstance(p, int) else zlib.crc32(str(p).encode()) for p in parts])

