"""A method's accuracy knob for the measured chart (``mcvar chart``): :class:`Knob`.

Most methods get better with samples per pixel; photon mapping with photons,
SPPM with iterations, radiosity with a finer mesh. A :class:`Knob` says what a
level counts and which keyword arguments of :func:`mcvar.integrators.render`
render level ``n``. A method declares its knob in its registration
(``Method(..., knob=...)``, :mod:`mcvar.integrators.registry`); a method
without one is measured in spp (:func:`spp_knob`). The chart
(:mod:`mcvar.experiments.chart`) reads it from the registry.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Callable, Mapping

__all__ = ["Knob", "spp_knob", "scaled_knob", "depth_knob"]


@dataclass(frozen=True)
class Knob:
    """A method's accuracy knob: what to render at level ``n``.

    Parameters
    ----------
    counts : str
        What a level counts (``'spp'``, ``'photons x 4096'``, ``'iterations'``,
        ``'mesh refinement'``), shown in the chart's settings.
    options : callable
        ``options(level) -> dict`` of keyword arguments of
        :func:`mcvar.integrators.render`: ``integrator``, ``spp`` and the
        method's own options (``max_depth``, ``photons``, ``radius`` ...).
        A module-level function or a :func:`functools.partial` of one, so
        other processes can run it (:func:`spp_knob`, :func:`scaled_knob`
        build such partials).
    quick, default : tuple of int
        Increasing levels (at least two, >= 1) of the quick (``--quick``) and
        the default chart.
    """

    counts: str
    options: Callable
    quick: tuple = (1, 4, 16, 64, 256)
    default: tuple = (1, 4, 16, 64, 256)

    def __post_init__(self):
        if not isinstance(self.counts, str):
            raise TypeError(f"knob.counts must be a string; got {type(self.counts).__name__}")
        if not callable(self.options):
            raise TypeError(f"knob.options must be callable (level -> dict); got {type(self.options).__name__}")
        for name in ("quick", "default"):
            levels = tuple(getattr(self, name))
            if (len(levels) < 2 or list(levels) != sorted(set(levels))
                    or not all(isinstance(v, int) and v >= 1 for v in levels)):
                raise ValueError(f"knob.{name} must hold >= 2 increasing positive levels; got {levels!r}")
            object.__setattr__(self, name, levels)


def _spp_options(integrator: str, level: int, **fixed) -> dict:
    return dict(integrator=integrator, spp=level, **fixed)


def spp_knob(integrator: str, **fixed) -> Knob:
    """The default knob: ``level`` samples per pixel of ``integrator`` (with ``fixed`` options)."""
    return Knob("spp", partial(_spp_options, integrator, **fixed))


def _scaled_options(integrator: str, scaled: Mapping, fixed: Mapping, level: int) -> dict:
    out = {"integrator": integrator}
    for name, (coef, power) in scaled.items():
        value = coef * level ** power
        out[name] = int(round(value)) if isinstance(coef, int) else float(value)
    out.update(fixed)
    return out


def scaled_knob(counts: str, integrator: str, scaled: Mapping, fixed: Mapping | None = None, *,
                quick: tuple = (1, 4, 16), default: tuple = (1, 4, 16, 64)) -> Knob:
    """A knob whose options are powers of the level: ``name = coef * level ** power``.

    ``scaled`` maps an option to ``(coef, power)`` (an int ``coef`` gives a
    rounded int); ``fixed`` options do not change with the level.

    Examples
    --------
    >>> knob = scaled_knob("photons", "photon", {"spp": (4, 0), "photons": (2048, 1)}, {"radius": 40.0})
    >>> knob.options(4)
    {'integrator': 'photon', 'spp': 4, 'photons': 8192, 'radius': 40.0}
    """
    return Knob(counts, partial(_scaled_options, integrator, dict(scaled), dict(fixed or {})), quick, default)


def _depth_options(options: Callable, depth: int, level: int) -> dict:
    return {**options(level), "max_depth": depth}


def depth_knob(knob: Knob, depth: int) -> Knob:
    """``knob`` with ``max_depth=depth`` added: the knob of a fixed-depth chart row (``'path:3'``)."""
    return Knob(knob.counts, partial(_depth_options, knob.options, int(depth)), knob.quick, knob.default)
