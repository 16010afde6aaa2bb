"""The value a sweep compares with: exact, loaded from a file, or rendered from
independent chunks and cached (layer 6, module 3 of :mod:`mcvar.experiments`)."""
from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from .._validation import as_array, check_count
from .targets import Target
from .runs import CACHE_VERSION, SerialExecutor, _atomic_save, _digest, _h32, _map, _run, root_seed


# --------------------------------------------------------------------------
# References
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class Reference:
    """The value a sweep's estimates are compared with.

    Attributes
    ----------
    value : ndarray
        Exact value, or the mean of the reference chunks.
    variance : ndarray
        Variance of ``value`` itself per element (0 when exact or unknown):
        the sample variance across chunks divided by the number of chunks.
    mean_variance : float
        Variance of the element-mean of ``value`` (from the chunks' means, so
        correlations between pixels are included).
    chunks : int
        Independent chunks averaged (0 when exact or loaded without chunks).
    source : str
        ``'exact'``, ``'rendered: ...'``, ``'cache: ...'`` or ``'file: ...'``.
    """

    value: np.ndarray
    variance: np.ndarray
    mean_variance: float
    chunks: int
    source: str


def _reference_from_file(path: Path) -> Reference:
    if not path.is_file():
        raise FileNotFoundError(f"reference file {path} does not exist")
    if path.suffix == ".npz":
        with np.load(path) as data:
            value = as_array(data["value"], "reference value")
            variance = as_array(data["variance"], "reference variance", nonnegative=True) \
                if "variance" in data else np.zeros_like(value)
            mean_var = float(data["mean_variance"]) if "mean_variance" in data else 0.0
            chunks = int(data["chunks"]) if "chunks" in data else 0
        return Reference(value, variance, mean_var, chunks, f"file: {path}")
    if path.suffix == ".npy":
        value = as_array(np.load(path), "reference image", nonnegative=True)
        return Reference(value, np.zeros_like(value), 0.0, 0, f"file: {path} (variance unknown, taken as 0)")
    raise ValueError(f"reference must be a .npy image or an .npz with 'value' (and 'variance'); got {path}")


def compute_reference(target: Target, *, rng: int | None = None, executor: Executor | None = None,
                      cache_dir=None, path=None, progress: bool = False, seed=None) -> Reference:
    """The reference for ``target``: exact, loaded from ``path``, or rendered.

    A rendered reference averages ``target.reference_chunks`` chunks, each
    ``target.reference_task(rng)`` with its own spawned stream, and is cached
    in ``cache_dir`` under a hash of the target's key, the reference settings,
    the chunk count and the seed; a second call loads it.

    Parameters
    ----------
    rng : int, optional
        Root seed (an integer >= 0, default 0; the cache is keyed by it).
        ``seed=`` is its deprecated alias.
    path : str or Path, optional
        A user-supplied reference: ``.npy`` (an image; its variance is taken
        as 0) or ``.npz`` with ``value`` and optionally ``variance``,
        ``mean_variance``, ``chunks``.
    """
    seed = root_seed(rng, seed, where="compute_reference")
    if path is not None:
        return _reference_from_file(Path(path))
    if target.exact is not None:
        value = as_array(target.exact, "target.exact")
        return Reference(value, np.zeros_like(value), 0.0, 0, "exact")
    if target.reference_task is None:
        raise ValueError(f"target {target.name!r} has neither an exact value nor a reference_task; "
                         "pass reference=PATH")
    chunks = check_count(target.reference_chunks, "target.reference_chunks")
    key = _digest("reference", CACHE_VERSION, target.key, target.reference_settings, chunks, seed)
    cache = Path(cache_dir) / f"reference-{key}.npz" if cache_dir is not None else None
    if cache is not None and cache.is_file():
        ref = _reference_from_file(cache)
        return Reference(ref.value, ref.variance, ref.mean_variance, ref.chunks, f"cache: {cache}")
    streams = np.random.SeedSequence(seed, spawn_key=(_h32("reference"), _h32(target.key))).spawn(chunks)
    results: list = [None] * chunks
    executor = SerialExecutor() if executor is None else executor

    def keep(i, res):
        results[i] = res

    from tqdm.auto import tqdm

    with tqdm(total=chunks, desc=f"{target.name} reference", disable=not progress) as bar:
        _map(executor, _run, [(_ref_adapter(target.reference_task), "", "", 0, s) for s in streams],
             window=chunks, on_done=keep, progress_bar=bar)
    stack = np.stack([r[0] for r in results])
    value = stack.mean(axis=0)
    variance = stack.var(axis=0, ddof=1) / chunks
    means = stack.reshape(chunks, -1).mean(axis=1)
    mean_variance = float(means.var(ddof=1) / chunks)
    seconds = sum(r[1] for r in results)
    source = f"rendered: {target.reference_settings}, {chunks} chunks, {seconds:.1f} s"
    if cache is not None:
        _atomic_save(cache, value=value, variance=variance, mean_variance=mean_variance, chunks=chunks)
    return Reference(value, variance, mean_variance, chunks, source)


def _ref_adapter(task):
    return partial(_call_reference, task)


def _call_reference(task, method, sampler, spp, rng):
    return task(rng)
