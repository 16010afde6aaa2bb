"""Argument checks shared by every mcvar module (layer 0).

One helper per rule, so that every public function reports bad input the same
way: a ``TypeError`` for the wrong kind of object, a ``ValueError`` for the
wrong value or shape, each naming the argument, the rule and what was received.
Comparisons are written so that NaN fails them.
"""
from __future__ import annotations

import numbers
from typing import Iterable

import numpy as np

__all__ = [
    "NotAnIntegerError",
    "UNIT_TOLERANCE",
    "as_rng",
    "check_count",
    "check_choice",
    "check_positive",
    "check_probability",
    "as_array",
    "as_points",
    "as_directions",
    "as_unit_directions",
    "as_unit_square",
    "as_rgb",
    "MEMORY_BUDGET",
    "check_bool",
    "check_budget",
    "format_bytes",
]

#: Largest ``| |v| - 1 |`` accepted where a function needs unit vectors
#: (:func:`as_unit_directions`): loose enough for vectors normalised in
#: float32 or rotated by a few frames, tight enough that a direction of length
#: 2 (or 1.001) is refused instead of silently giving a wrong pdf.
UNIT_TOLERANCE = 1e-6


#: Memory budget, in bytes, of the work an option implies (photon maps,
#: bootstrap candidates, radiosity matrices, ...): 4 GiB, the same default as
#: ``mcvar.integrators.MAX_RENDER_BYTES`` and ``mcvar.samplers.MAX_BYTES``.
#: :func:`check_budget` reads it at call time, so assigning
#: ``mcvar._validation.MEMORY_BUDGET = 16 * 2**30`` raises it for the session
#: (docs/conventions.md, 'Memory').
MEMORY_BUDGET = 4 * 2 ** 30


class NotAnIntegerError(ValueError, TypeError):
    """A count that is not a whole number (``2.5``, ``4.0``, ``"4"``).

    It is both a ``ValueError`` (the issue tracker's contract: "non-integer n
    -> ValueError") and a ``TypeError`` (the style guide's rule for the wrong
    kind of object), so either ``except`` clause catches it, the way
    ``numpy.exceptions.AxisError`` is both a ``ValueError`` and an
    ``IndexError``.
    """


def as_rng(rng=None) -> np.random.Generator:
    """Normalise ``rng`` to a :class:`numpy.random.Generator`.

    Accepts ``None`` (fresh entropy), an ``int`` seed, a
    :class:`numpy.random.SeedSequence` or a ``Generator`` (returned as is, so
    the caller's stream advances). Anything else is a ``TypeError``.
    """
    if rng is None or isinstance(rng, (np.random.Generator, np.random.SeedSequence)):
        return np.random.default_rng(rng)
    if isinstance(rng, (bool, np.bool_)):
        raise TypeError(f"rng must be None, an int seed, a SeedSequence or a numpy Generator; got {rng!r}")
    if isinstance(rng, numbers.Integral):
        if int(rng) < 0:
            raise ValueError(f"rng must be a non-negative int seed; got {rng}")
        return np.random.default_rng(int(rng))
    raise TypeError(
        "rng must be None, an int seed, a SeedSequence or a numpy Generator; "
        f"got {type(rng).__name__}"
    )


def check_count(n, name: str = "n", *, allow_zero: bool = False) -> int:
    """Return ``n`` as a Python int after checking it is a whole number >= 1.

    ``bool``, floats (even ``4.0``) and strings raise
    :class:`NotAnIntegerError` (a ``ValueError`` and a ``TypeError``): a sample
    count is never fractional. ``allow_zero=True`` admits 0 (empty outputs).
    """
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, numbers.Integral):
        raise NotAnIntegerError(f"{name} must be an integer; got {type(n).__name__} {n!r}")
    n = int(n)
    low = 0 if allow_zero else 1
    if not n >= low:
        raise ValueError(f"{name} must be >= {low}; got {n}")
    return n


def check_choice(value, name: str, choices: Iterable[str]) -> str:
    """Check that ``value`` is one of the strings ``choices``."""
    choices = tuple(choices)
    if not isinstance(value, str):
        raise TypeError(f"{name} must be a string, one of {choices}; got {type(value).__name__}")
    if value not in choices:
        raise ValueError(f"{name} must be one of {choices}; got {value!r}")
    return value


def check_positive(x, name: str, *, allow_zero: bool = False, allow_inf: bool = False) -> float:
    """Return the real scalar ``x`` as float after checking ``x > 0`` (or ``>= 0``)."""
    if isinstance(x, (bool, np.bool_)) or not isinstance(x, numbers.Real):
        raise TypeError(f"{name} must be a real number; got {type(x).__name__} {x!r}")
    x = float(x)
    ok = (x >= 0.0) if allow_zero else (x > 0.0)
    if not ok or (not allow_inf and not np.isfinite(x)):
        rule = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be finite and {rule}; got {x}")
    return x


def check_probability(x, name: str) -> float:
    """Return ``x`` as float after checking ``0 <= x <= 1``."""
    if isinstance(x, (bool, np.bool_)) or not isinstance(x, numbers.Real):
        raise TypeError(f"{name} must be a real number; got {type(x).__name__} {x!r}")
    x = float(x)
    if not 0.0 <= x <= 1.0:
        raise ValueError(f"{name} must lie in [0, 1]; got {x}")
    return x


class _ComplexInput(TypeError):
    pass


def _real_array(x, dtype):
    arr = np.asarray(x)
    if arr.dtype.kind == "c":  # np.asarray(..., float) would drop the imaginary part with a warning
        raise _ComplexInput
    return arr.astype(dtype, copy=False)


def as_array(x, name: str, *, ndim=None, last=None, finite: bool = True,
             nonnegative: bool = False, dtype=np.float64) -> np.ndarray:
    """Convert ``x`` to a float array and check its shape and values.

    Parameters
    ----------
    ndim : int, optional
        Required number of dimensions.
    last : int, optional
        Required length of the last axis (coordinates on the last axis).
    finite : bool
        Reject NaN and +-Inf.
    nonnegative : bool
        Reject negative entries.
    """
    try:
        arr = np.asarray(x, dtype=dtype) if np.dtype(dtype).kind == "c" else _real_array(x, dtype)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be array-like of real numbers; got {type(x).__name__}"
                        + (" with complex values" if isinstance(exc, _ComplexInput) else "")) from exc
    if ndim is not None and arr.ndim != ndim:
        raise ValueError(f"{name} must have {ndim} dimensions; got shape {arr.shape}")
    if last is not None and (arr.ndim == 0 or arr.shape[-1] != last):
        raise ValueError(f"{name} must have shape (..., {last}); got shape {arr.shape}")
    if finite and arr.size and not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite (no NaN or Inf)")
    if nonnegative and arr.size and not np.all(arr >= 0):
        raise ValueError(f"{name} must be non-negative; minimum is {np.nanmin(arr)}")
    return arr


def as_points(points, name: str = "points", *, d=None, unit: bool = False) -> np.ndarray:
    """Check an ``(n, d)`` point set and return it as float64.

    ``unit=True`` also requires every coordinate to lie in the closed unit
    interval [0, 1] (the domain of samplers and warps).
    """
    arr = as_array(points, name, ndim=2)
    if d is not None and arr.shape[1] != d:
        raise ValueError(f"{name} must have shape (n, {d}); got shape {arr.shape}")
    if unit and arr.size and not (np.all(arr >= 0.0) and np.all(arr <= 1.0)):
        raise ValueError(f"{name} must lie in [0, 1]^d; got values in [{arr.min()}, {arr.max()}]")
    return arr


def as_unit_directions(v, name: str = "directions", *, ndim=None) -> np.ndarray:
    """Check an array of unit 3D vectors, shape ``(..., 3)``, and return it as float64.

    The one rule for every function that *evaluates* something at directions
    (warp pdfs and inverses, BSDFs, environment-map lookups): each row must
    have length 1 within :data:`UNIT_TOLERANCE`, otherwise a ``ValueError``
    naming ``name``, the first offending row and its length. Nothing is
    normalised silently: a pdf evaluated at ``2 v`` would be wrong, and
    normalising would hide the caller's bug. Zero vectors and NaN fail too.
    """
    arr = as_array(v, name, ndim=ndim, last=3)
    if arr.size:
        length = np.sqrt(np.einsum("...i,...i->...", arr, arr))
        bad = ~(np.abs(length - 1.0) <= UNIT_TOLERANCE)
        if np.any(bad):
            where = np.unravel_index(int(np.argmax(bad)), bad.shape)
            at = f"row {where[0] if len(where) == 1 else where}" if where else "the vector"
            raise ValueError(
                f"{name} must hold unit vectors (| |v| - 1 | <= {UNIT_TOLERANCE}; "
                f"normalise with mcvar.geometry.normalize); {at} has length {float(length[where])!r}")
    return arr


def as_unit_square(u, name: str = "u") -> np.ndarray:
    """Check warp input: an ``(n, 2)`` array of points in [0, 1]^2 (1.0 included)."""
    return as_points(u, name, d=2, unit=True)


def as_directions(v, name: str = "directions") -> np.ndarray:
    """Check an array of 3D vectors, shape ``(..., 3)``, finite, as float64."""
    return as_array(v, name, last=3)


def as_rgb(value, name: str, *, upper: float | None = None, why: str = "") -> np.ndarray:
    """An RGB parameter: a scalar (grey, repeated) or three values, each in
    ``[0, upper]``, returned as a new float64 array of shape ``(3,)``.

    ``bool`` is a ``TypeError``; NaN, Inf, a negative channel, a channel above
    ``upper`` or another shape raise ``ValueError`` naming ``name``. ``why``
    is appended to the ``upper`` message (e.g. ``'energy conservation'``).
    """
    if isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be a number or 3 numbers (RGB); got bool")
    arr = as_array(value, name)
    if arr.ndim == 0:
        arr = np.full(3, float(arr))
    if arr.shape != (3,):
        raise ValueError(f"{name} must be a scalar or an RGB triple, shape (3,); got shape {arr.shape}")
    if not np.all(arr >= 0.0):
        raise ValueError(f"{name} must be >= 0 in every channel (non-negative); got {arr.tolist()}")
    if upper is not None and not np.all(arr <= upper):
        reason = f" ({why})" if why else ""
        raise ValueError(f"{name} must be <= {upper} in every channel{reason}; got {arr.tolist()}")
    return np.array(arr, dtype=np.float64)


def check_bool(value, name: str) -> bool:
    """Return ``value`` as a Python bool after checking it is ``bool`` or ``numpy.bool_``.

    ``'no'``, ``0``, ``1`` and ``None`` are a ``TypeError``: a string is truthy
    whatever it says, so accepting it would silently turn ``'no'`` into yes.
    """
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be a bool (True or False); got {type(value).__name__} {value!r}")
    return bool(value)


def format_bytes(b: float) -> str:
    """``b`` bytes in the largest binary unit below it: ``'3.5 GiB'``."""
    b = float(b)
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(b) < 1024.0 or unit == "PiB":
            return f"{b:.3g} {unit}"
        b /= 1024.0
    return f"{b:.3g} PiB"  # pragma: no cover


def check_budget(name: str, value, needed_bytes: float, *, per_unit: float | None = None,
                 budget: float | None = None, what: str = "", unit_name: str | None = None) -> None:
    """The one rule for sizes an option implies: refuse before allocating.

    Parameters
    ----------
    name : str
        The option (``'photons'``, ``'n_bootstrap'``, ``'patch_size'``).
    value
        Its value, quoted in the message (None: ``name`` already says it,
        e.g. ``'patch_size=1 with rays_per_side=256'``).
    needed_bytes : float
        Estimated peak memory (computed in float, so that ``2**40`` of
        anything does not overflow).
    per_unit : float, optional
        Bytes per unit of the option, for a count: the message then says the
        largest value that fits (``budget // per_unit``).
    budget : float, optional
        Bytes allowed; default :data:`MEMORY_BUDGET` (read at call time).
    what : str
        What the memory holds (``'the photon map'``), for the message.
    unit_name : str, optional
        The count ``per_unit`` is per, in the 'at most ... fits' part
        (default ``name``).

    Raises
    ------
    ValueError
        ``needed_bytes > budget`` (or NaN), naming ``name``, what it needs and
        what would fit.
    """
    limit = float(MEMORY_BUDGET if budget is None else budget)
    need = float(needed_bytes)
    if need <= limit:
        return
    fit = ""
    if per_unit is not None and per_unit > 0:
        fit = f"; at most {name if unit_name is None else unit_name}={int(limit // per_unit)} fits"
    held = f" ({what})" if what else ""
    label = name if value is None else f"{name}={value!r}"
    raise ValueError(f"{label} needs about {format_bytes(need)} of memory{held}, more than the "
                     f"budget of {format_bytes(limit)}{fit} (raise mcvar._validation.MEMORY_BUDGET "
                     "if the machine has the memory)")


def settings_with(cls, settings, options: dict, where: str):
    """``settings`` (an instance of the frozen dataclass ``cls``; None: its defaults) with the
    keyword ``options`` replacing fields, the way a function taking a settings record keeps
    its documented keywords: an unknown keyword is a ``TypeError`` naming the accepted ones.

    Examples
    --------
    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class S:
    ...     n: int = 1
    >>> settings_with(S, None, {"n": 3}, "f")
    S(n=3)
    """
    from dataclasses import fields, replace

    if settings is None:
        settings = cls()
    elif not isinstance(settings, cls):
        raise TypeError(f"{where}: settings must be a {cls.__name__}; got {type(settings).__name__}")
    names = [f.name for f in fields(cls)]
    unknown = [k for k in options if k not in names]
    if unknown:
        raise TypeError(f"{where}() got unexpected keyword argument(s) {', '.join(map(repr, unknown))}; "
                        f"its settings ({cls.__name__}) are {', '.join(names)}")
    return replace(settings, **options) if options else settings


def seed_alias(options: dict, where: str, *, name: str = "rng") -> dict:
    """``options`` with the deprecated keyword ``seed`` renamed to ``rng`` (a DeprecationWarning;
    both at once is a TypeError). mcvar's Python API says ``rng`` everywhere; ``--seed`` stays
    the command line's word."""
    if "seed" not in options:
        return options
    import warnings

    options = dict(options)
    if name in options:
        raise TypeError(f"{where}() got both {name}= and its deprecated alias seed=; pass {name}= only")
    warnings.warn(f"{where}(seed=...) is deprecated: pass {name}= (the same integer)", DeprecationWarning,
                  stacklevel=3)
    options[name] = options.pop("seed")
    return options
