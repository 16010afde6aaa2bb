"""mcvar: Monte Carlo estimation and its variance, measured.

A teaching and measurement toolkit for physically based rendering: samplers
and their discrepancy, warps with their pdfs, BSDFs, environment maps,
estimators that report their standard error, and a small vectorised ray
tracer whose images are used to measure bias, variance and efficiency.

Modules are imported on demand (``import mcvar.samplers``); see
``docs/conventions.md`` for the conventions they share.
"""
from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("mcvar")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
