"""Independent runs: config-derived random streams, executors, on-disk caches
(layer 6, module 2 of :mod:`mcvar.experiments`)."""
from __future__ import annotations

import hashlib
import os
import time
from concurrent.futures import Executor, Future, FIRST_COMPLETED, wait
from pathlib import Path

import numpy as np

from .._validation import check_count


#: Bumped when the meaning of a cached run or reference changes.
CACHE_VERSION = 1


# --------------------------------------------------------------------------
# Streams, executors, caches
# --------------------------------------------------------------------------

def _h32(text: str) -> int:
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:4], "little")


def _digest(*parts) -> str:
    return hashlib.sha256("|".join(map(str, parts)).encode()).hexdigest()[:24]


def root_seed(rng=None, seed=None, *, where: str = "") -> int:
    """The integer root seed of a cached experiment.

    ``rng`` is an integer >= 0 (None: 0), not a Generator: finished runs and
    references are cached on disk by it, and every stream is spawned from it
    by configuration (:func:`run_seed`). ``seed`` is the deprecated former
    name of ``rng`` (a ``DeprecationWarning``; both at once is a ``TypeError``).
    """
    if seed is not None:
        if rng is not None:
            raise TypeError(f"{where or 'this function'} got both rng= and its deprecated alias seed=; "
                            "pass rng= only")
        import warnings

        warnings.warn(f"{where or 'this function'}(seed=...) is deprecated: pass rng= (the same integer)",
                      DeprecationWarning, stacklevel=3)
        rng = seed
    if rng is None:
        return 0
    if isinstance(rng, (np.random.Generator, np.random.SeedSequence, np.random.BitGenerator)):
        raise TypeError(f"rng must be an integer seed >= 0 here (runs and references are cached by it); "
                        f"got {type(rng).__name__}")
    return check_count(rng, "rng", allow_zero=True)


def run_seed(rng: int, target_key: str, method: str, sampler: str, spp: int, replicates: int):
    """The ``replicates`` independent streams of one configuration.

    ``SeedSequence(rng, spawn_key=(h(target), h(method), h(sampler), spp))``
    spawned ``replicates`` times, with ``h`` the first 32 bits of SHA-256: the
    streams depend only on the seed and the configuration, never on the order
    in which runs execute, and distinct configurations get distinct streams.
    """
    seed = root_seed(rng, where="run_seed")
    root = np.random.SeedSequence(seed, spawn_key=(_h32(target_key), _h32(method),
                                                  _h32(sampler), int(spp)))
    return root.spawn(check_count(replicates, "replicates"))


class SerialExecutor(Executor):
    """A :class:`concurrent.futures.Executor` that runs each task in this
    process when it is submitted (for debugging, tests and one-core runs)."""

    def submit(self, fn, /, *args, **kwargs):
        future = Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except Exception as exc:  # KeyboardInterrupt propagates
            future.set_exception(exc)
        return future


def _run(evaluate, method, sampler, spp, seed_seq):
    rng = np.random.default_rng(seed_seq)
    start = time.perf_counter()
    value = np.asarray(evaluate(method, sampler, spp, rng), dtype=np.float64)
    seconds = time.perf_counter() - start
    return value, seconds


def _atomic_save(path: Path, **arrays) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


def _map(executor, fn, jobs, *, window, on_done, progress_bar):
    """Submit ``fn(*job)`` for every job, at most ``window`` pending at once;
    call ``on_done(index, result)`` as each finishes. On any exception (or
    KeyboardInterrupt) pending tasks are cancelled and it is re-raised."""
    pending: dict = {}
    jobs = list(jobs)
    nxt = 0
    try:
        while nxt < len(jobs) or pending:
            while nxt < len(jobs) and len(pending) < window:
                pending[executor.submit(fn, *jobs[nxt])] = nxt
                nxt += 1
            done, _ = wait(list(pending), return_when=FIRST_COMPLETED)
            for fut in sorted(done, key=pending.__getitem__):
                index = pending.pop(fut)
                on_done(index, fut.result())
                progress_bar.update(1)
    except BaseException:
        for fut in pending:
            fut.cancel()
        raise
