"""The settings of a path: :class:`PathSettings`, validated once, carried from
``render`` (and ``mcvar render``) to the loops; and :class:`Strategies`, which
estimators a path method combines.

One frozen record instead of seven loose arguments: the driver builds it from
the keywords of :func:`mcvar.integrators.render`, a :class:`~mcvar.integrators.film.BatchJob`
carries it, and :class:`~mcvar.integrators.state.Transport` and the two loops
(:mod:`~mcvar.integrators.path`, :mod:`~mcvar.integrators.lambertian`) read
it. A bad value is a ``ValueError`` / ``TypeError`` naming the field, raised
when the record is made, before any work.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Literal

import numpy as np

from .._validation import check_choice, check_count
from ..estimators import balance_heuristic, power_heuristic
from .emitters import LIGHT_SAMPLING, VISIBLE_LIGHTS

__all__ = ["PathSettings", "Strategies", "STRATEGIES", "HEURISTICS", "KERNELS", "PATH_OPTIONS", "REUSE_MAX"]

#: MIS heuristics by name (Veach 1997, sec. 9.2: balance, and power with beta = 2).
HEURISTICS = {"power": power_heuristic, "balance": balance_heuristic}
#: Values of the ``kernel`` setting: ``auto`` picks the Lambertian kernel where
#: the scene allows it, ``general`` and ``lambertian`` force one.
KERNELS = ("auto", "general", "lambertian")
#: Largest tile of path reuse (``PathSettings.reuse``): a wavefront's connections are
#: ``(reuse, n)`` blocks, 40 MB at 16 for 65,536 paths; measured useful up to 8.
REUSE_MAX = 16


def _number_in_unit_interval(value, name: str) -> float:
    """``value`` as a float in (0, 1]; TypeError / ValueError naming ``name`` otherwise."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number in (0, 1]; got {type(value).__name__}")
    value = float(value)
    if not 0.0 < value <= 1.0:          # NaN fails too
        raise ValueError(f"{name} must lie in (0, 1]; got {value}")
    return value


def _optional_count(value, name: str) -> int | None:
    return None if value is None else check_count(value, name)


@dataclass(frozen=True)
class PathSettings:
    """How a camera path is traced: depth, MIS, kernel, light sampling, roulette.

    Attributes
    ----------
    max_depth : int or None
        Maximum path segments (1 = emitters seen directly, 2 = + direct
        light, ...; a fixed depth is biased); None: Russian roulette
        (unbiased, capped at :data:`~mcvar.integrators.state.RR_MAX_DEPTH`).
    heuristic : {'power', 'balance'}
        MIS weights (Veach and Guibas 1995, eq. 8 and 9).
    kernel : {'auto', 'general', 'lambertian'}
        Which loop runs the path methods (:mod:`mcvar.integrators.path`).
    light_sampling : {'area', 'solid_angle'}
        How NEE samples quad lights (:data:`~mcvar.integrators.emitters.LIGHT_SAMPLING`).
    rr_depth : int or None
        Segments before Russian roulette starts (None:
        :data:`~mcvar.integrators.state.RR_START_DEPTH`).
    rr_threshold : float in (0, 1]
        Roulette survival ``min(0.95, max(beta) / rr_threshold)``; 1 is pbrt's
        rule, smaller values a weight window
        (:func:`~mcvar.integrators.state.roulette`).
    visible_lights : {'sampled', 'exact'}
        ``exact``: the emission of lights seen directly by camera rays is the
        closed-form image of :class:`~mcvar.integrators.emitters.VisibleLights`
        plus sampled differences (a control variate).
    caustics : {'path', 'light'}
        ``light``: caustic paths (the first camera vertex non-specular, the
        last vertex before the light specular: ``E D (D|S)* S L``) are left
        to light tracing (:mod:`mcvar.integrators.caustics`; renders add its
        splats), where the scene allows it; ``path``: path tracing finds them.
    glass_splits : int >= 0
        A camera path whose vertices so far are all :class:`mcvar.bsdf.Glass`
        follows *both* lobes at its first ``glass_splits`` vertices
        (reflection weighted ``F``, refraction ``1 - F``) instead of choosing
        one with those probabilities: the same expectation without the
        variance of the choice, which holds most of the error of the light
        seen in and through a glass sphere (0: choose, the default).
    reuse : int >= 1
        Path reuse (:mod:`mcvar.integrators.reuse`; Bekaert et al. 2002): the
        camera samples of this many neighbouring pixels share their paths from
        the second vertex on, each pixel weighting them by the balance
        heuristic. Unbiased; per-pixel variance of indirect light down up to
        this factor, noise correlated within a tile. Lambertian kernel only
        (1: off, the default; at most :data:`REUSE_MAX`).

    Examples
    --------
    >>> PathSettings(max_depth=3).heuristic
    'power'
    >>> PathSettings(rr_threshold=0.2).rr_threshold
    0.2
    """

    max_depth: int | None = None
    heuristic: Literal["power", "balance"] = "power"
    kernel: Literal["auto", "general", "lambertian"] = "auto"
    light_sampling: Literal["area", "solid_angle"] = "area"
    rr_depth: int | None = None
    rr_threshold: float = 1.0
    visible_lights: Literal["sampled", "exact"] = "sampled"
    caustics: Literal["path", "light"] = "path"
    glass_splits: int = 0
    reuse: int = 1

    def __post_init__(self):
        checked = {
            "max_depth": _optional_count(self.max_depth, "max_depth"),
            "heuristic": check_choice(self.heuristic, "heuristic", tuple(HEURISTICS)),
            "kernel": check_choice(self.kernel, "kernel", KERNELS),
            "light_sampling": check_choice(self.light_sampling, "light_sampling", LIGHT_SAMPLING),
            "rr_depth": _optional_count(self.rr_depth, "rr_depth"),
            "rr_threshold": _number_in_unit_interval(self.rr_threshold, "rr_threshold"),
            "visible_lights": check_choice(self.visible_lights, "visible_lights", VISIBLE_LIGHTS),
            "caustics": check_choice(self.caustics, "caustics", ("path", "light")),
            "glass_splits": check_count(self.glass_splits, "glass_splits", allow_zero=True),
            "reuse": check_count(self.reuse, "reuse"),
        }
        if checked["reuse"] > REUSE_MAX:
            raise ValueError(f"reuse must be at most {REUSE_MAX} pixels a tile; got {checked['reuse']}")
        for key, value in checked.items():          # normalised: Python ints and floats
            object.__setattr__(self, key, value)

    @classmethod
    def from_keywords(cls, given: dict, *, settings: "PathSettings | None" = None,
                      where: str = "render") -> "PathSettings":
        """Pop this record's fields out of ``given`` (keywords) and make the record.

        ``settings``: a record given as a whole; then none of its fields may
        also be given one by one (``ValueError``).
        """
        mine = {f.name: given.pop(f.name) for f in fields(cls) if f.name in given}
        if settings is None:
            return cls(**mine)
        if not isinstance(settings, cls):
            raise TypeError(f"{where}: settings must be a PathSettings; got {type(settings).__name__}")
        if mine:
            raise ValueError(f"{where}: give settings=PathSettings(...) or its fields "
                             f"({', '.join(sorted(mine))}) as keywords, not both")
        return settings


#: The fields of :class:`PathSettings` a method declares in its ``options``
#: when it reads them (``max_depth`` and ``heuristic`` apply to every method).
PATH_OPTIONS = ("kernel", "light_sampling", "rr_depth", "rr_threshold", "visible_lights", "caustics", "glass_splits", "reuse")


@dataclass(frozen=True)
class Strategies:
    """Which estimators a path method combines (the lecture's 'Previous Methods').

    Attributes
    ----------
    nee : bool
        Connect to lights (next-event estimation).
    bsdf_hits : bool
        Count emission found by BSDF sampling after the first segment.
    mis : bool
        Weight the two strategies by the MIS heuristic (else weight 1 each).
    depth : int or None
        The method's own depth (``direct*``: 2).
    """

    nee: bool
    bsdf_hits: bool
    mis: bool
    depth: int | None


#: The path and direct-lighting methods' strategies, by method name.
STRATEGIES = {
    "direct": Strategies(True, True, True, 2),
    "direct_light": Strategies(True, False, False, 2),
    "direct_bsdf": Strategies(False, True, False, 2),
    "path": Strategies(True, True, True, None),
    "path_bsdf": Strategies(False, True, False, None),
}
