"""The film: what one batch gets and returns, and how batches add up to an image.

A batch (:class:`BatchJob`) returns per-pixel *sums* (:class:`BatchResult`):
camera methods the sums of their samples and of their squares, splatting
methods the sums of contributions landing at arbitrary pixels
(:func:`splat`). :class:`Film` adds batches in batch order and turns them
into the image and a per-sample variance: from the squared sums for camera
methods, from the spread of independent batches for the others.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..scene import Scene
from ..tracer import Tracer
from .settings import PathSettings

__all__ = ["BatchJob", "BatchResult", "Film", "Render", "splat", "camera_result"]


@dataclass
class BatchJob:
    """Everything one batch of a render gets (built in the process that runs it).

    Attributes
    ----------
    scene : Scene
    tracer : Tracer
        Built once per render and process, in the render's precision.
    res : tuple
        ``(W, H)``.
    spp : int
        Samples per pixel of this batch; for ``splat`` and ``chain`` methods
        the work budget expressed as the same number of paths, ``W H spp``.
    sampler : str
        The render's sampler name (:data:`mcvar.samplers.SAMPLERS`).
    u : ndarray or None
        This batch's sample stream, ``(W H spp, dim)`` in path order
        (pixel-major: the ``spp`` samples of pixel 0 first); None: every
        dimension is drawn from ``rng`` (the ``random`` sampler).
        Column layout: :mod:`mcvar.integrators.stream`.
    rng : numpy.random.Generator
        This batch's own stream (dimensions beyond ``u``).
    settings : PathSettings
        The render's path settings (``max_depth``, ``heuristic``, ...;
        :class:`~mcvar.integrators.settings.PathSettings`).
    options : dict
        The method's options with defaults filled in.
    prepared : object or None
        What the method's ``prepare`` returned.
    pixels : ndarray of int or None
        The flat pixel indices (row-major, ``y W + x``) this batch samples,
        ``spp`` samples each (adaptive allocation: the pixels of one
        allocation level); None: every pixel of the image.
    """

    scene: Scene
    tracer: Tracer
    res: tuple
    spp: int
    sampler: str
    u: np.ndarray | None
    rng: np.random.Generator
    settings: PathSettings = field(default_factory=PathSettings)
    options: dict = field(default_factory=dict)
    prepared: object | None = None
    pixels: np.ndarray | None = None

    @property
    def n_pixels(self) -> int:
        """Pixels this batch samples (``W H`` unless :attr:`pixels` is given)."""
        return self.res[0] * self.res[1] if self.pixels is None else int(self.pixels.shape[0])

    @property
    def pixel_index(self) -> np.ndarray:
        """The flat indices of the pixels this batch samples, (n_pixels,)."""
        return np.arange(self.res[0] * self.res[1]) if self.pixels is None else self.pixels

    @property
    def max_depth(self) -> int | None:
        return self.settings.max_depth

    @property
    def heuristic(self) -> str:
        return self.settings.heuristic


@dataclass
class BatchResult:
    """What a batch returns.

    Attributes
    ----------
    sum : ndarray, shape (n_pix, 3)
        Per pixel, the sum of this batch's sample contributions (camera,
        first_hit) or of its splats (splat, chain), scaled so that this
        batch's image is ``sum / spp``.
    sum_sq : ndarray, shape (n_pix, 3), or None
        Per-pixel sums of squared samples (camera, first_hit); None when
        samples are not per pixel: the film then estimates the variance
        from independent batches (needs >= 2 batches).
    rays : int
        Rays traced.
    extra : dict
        Method-specific arrays, summed over batches like ``sum`` (e.g. BDPT's
        per-(s, t) images); the render divides them by its spp.
    """

    sum: np.ndarray
    sum_sq: np.ndarray | None
    rays: int
    extra: dict = field(default_factory=dict)


def splat(sum_array, pixel_index, values) -> None:
    """Add ``values`` (m, 3) at flat pixels ``pixel_index`` (m,) of ``sum_array`` (n_pix, 3), in place.

    Repeated pixels add up (``np.bincount`` per channel: unlike ``a[i] += v``
    it does not drop repeats, and is faster than ``np.add.at``).
    """
    pixel_index = np.asarray(pixel_index, dtype=np.int64).reshape(-1)
    values = np.asarray(values, dtype=np.float64).reshape(pixel_index.shape[0], sum_array.shape[1])
    n_pix = sum_array.shape[0]
    if pixel_index.size and (pixel_index.min() < 0 or pixel_index.max() >= n_pix):
        raise ValueError(f"pixel_index must lie in [0, {n_pix}); got [{pixel_index.min()}, {pixel_index.max()}]")
    for c in range(sum_array.shape[1]):
        sum_array[:, c] += np.bincount(pixel_index, weights=values[:, c], minlength=n_pix)


def camera_result(job: BatchJob, radiance, rays: int, name: str = "") -> BatchResult:
    """A camera batch's result from per-path radiance ``(W H spp, 3)`` in path order."""
    if not np.all(np.isfinite(radiance)):
        raise FloatingPointError(f"{name or 'the method'} produced non-finite radiance (a bug, please report)")
    per_pixel = np.asarray(radiance).reshape(job.n_pixels, job.spp, 3)
    return BatchResult(per_pixel.sum(axis=1), np.einsum("psc,psc->pc", per_pixel, per_pixel), int(rays))


class Film:
    """Accumulates :class:`BatchResult` s into an image and its variance.

    Parameters
    ----------
    n_pixels : int
    per_sample : bool
        True (camera, first_hit): batches carry ``sum_sq`` and the variance
        is the per-sample variance of each pixel's samples. False (splat,
        chain): the variance comes from the spread of independent batches,
        scaled to a per-sample variance: with batch images ``I_b`` of
        ``n_b`` samples and ``N = sum n_b``, ``s^2 = sum_b n_b (I_b - I)^2 /
        (B - 1)`` (unbiased for ``var(I_b) = sigma^2 / n_b``), so that
        ``variance / spp`` is the variance of the image for either kind.

    Attributes
    ----------
    counts : ndarray of int64, (n_pixels,)
        Samples added per pixel (camera batches of a subset of pixels add
        only to theirs: adaptive allocation).
    spp : int
        Samples per pixel added by whole-image batches (the common count;
        for a film of pixel subsets, ``counts`` tells).
    """

    def __init__(self, n_pixels: int, per_sample: bool):
        self.per_sample = per_sample
        self.total = np.zeros((n_pixels, 3))
        self.total_sq = np.zeros((n_pixels, 3))
        self.counts = np.zeros(n_pixels, dtype=np.int64)
        self.spp = 0
        self.batches = 0
        self.rays = 0
        self.extra: dict = {}

    def add(self, result: BatchResult, spp: int, pixels=None) -> None:
        """Add one batch of ``spp`` samples per pixel (of every pixel, or of ``pixels``)."""
        if pixels is not None:
            if not self.per_sample or result.sum_sq is None:
                raise ValueError("batches of a subset of pixels must be camera batches with sum_sq")
            self.total[pixels] += result.sum
            self.total_sq[pixels] += result.sum_sq
            self.counts[pixels] += spp
        else:
            self.total += result.sum
            if self.per_sample:
                if result.sum_sq is None:
                    raise ValueError("a camera / first_hit batch must return sum_sq")
                self.total_sq += result.sum_sq
            else:
                self.total_sq += result.sum * result.sum / spp     # n_b I_b^2
            self.counts += spp
            self.spp += spp
        for key, value in result.extra.items():
            self.extra[key] = self.extra[key] + value if key in self.extra else np.array(value, dtype=np.float64)
        self.batches += 1
        self.rays += int(result.rays)

    def image(self, res) -> np.ndarray:
        """Per-pixel mean (H, W, 3); 0 where a pixel has no samples."""
        w, h = res
        n = np.maximum(self.counts, 1)[:, None]
        return (self.total / n).reshape(h, w, 3)

    def variance(self, res) -> np.ndarray | None:
        """Per-sample variance (H, W, 3), or None when it cannot be estimated
        (camera: a pixel with fewer than 2 samples has variance 0 unless every
        pixel has, then None)."""
        w, h = res
        n = self.counts[:, None]
        if self.per_sample:
            if self.counts.max(initial=0) < 2:
                return None
            with np.errstate(invalid="ignore", divide="ignore"):
                var = np.where(n > 1, (self.total_sq - self.total * self.total / n) / (n - 1), 0.0)
        else:
            if self.batches < 2:
                return None
            var = (self.total_sq - self.total * self.total / n) / (self.batches - 1)
        return np.maximum(var, 0.0).reshape(h, w, 3)


@dataclass(frozen=True, eq=False)
class Render:
    """The result of :func:`mcvar.integrators.render`.

    Attributes
    ----------
    image : ndarray, shape (H, W, 3), float64
        Mean linear radiance per pixel (row 0 at the top).
    spp : int
        Samples per pixel actually completed (fewer than asked if interrupted).
    seconds : float
        Wall-clock time.
    interrupted : bool
        True if Ctrl-C (``KeyboardInterrupt``) stopped the render early.
    variance : ndarray, shape (H, W, 3), or None
        Per-sample variance of each pixel's radiance (``ddof = 1``), None for
        fewer than 2 spp (camera methods) or 2 batches (splat and chain
        methods, whose variance comes from independent batches). Under iid
        pixel sampling ``variance / spp`` is the variance of the pixel mean;
        stratified and QMC samples are not independent, so there it is only
        an upper-bound-like indicator.
    rays : int
        Rays traced (camera, extension and shadow rays).
    scene, method, sampler, res, max_depth, heuristic, batch_spp, workers, precision
        The settings used (``res`` is ``(W, H)``; ``integrator`` is an alias
        of ``method``).
    options : dict
        The method's options (defaults filled in).
    extra : dict
        Method-specific images (summed over batches, divided by spp).
    """

    image: np.ndarray
    spp: int
    seconds: float
    interrupted: bool
    variance: np.ndarray | None
    rays: int
    scene: str
    method: str
    sampler: str
    res: tuple
    max_depth: int | None
    heuristic: str
    batch_spp: int
    workers: int
    precision: str
    options: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)

    @property
    def integrator(self) -> str:
        """Alias of :attr:`method` (the name before issue 20)."""
        return self.method

    @property
    def standard_error(self) -> np.ndarray | None:
        """``sqrt(variance / spp)`` per pixel (iid model), or None."""
        if self.variance is None:
            return None
        return np.sqrt(self.variance / self.spp)

    @property
    def paths_per_second(self) -> float:
        """Camera paths (pixel samples) per second."""
        w, h = self.res
        return w * h * self.spp / self.seconds if self.seconds > 0 else float("nan")
