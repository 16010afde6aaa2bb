"""Test helper: what the camera's rays see on a regular subpixel grid (shared by the region masks of
``test_mitsuba_reference`` and ``test_cornell_caustic``)."""
from __future__ import annotations

import numpy as np

from mcvar.tracer import Tracer


def subpixel_hits(scene, res: int, sub: int):
    """``(pix, hit)``: the pixel of each of the ``sub x sub`` centred subpixel rays of every pixel of a
    ``res x res`` image, and the camera ray's first hit (:meth:`mcvar.tracer.Tracer.intersect`)."""
    pix = np.repeat(np.arange(res * res), sub * sub)
    g = (np.arange(sub) + 0.5) / sub
    off = np.tile(np.stack(np.meshgrid(g, g), -1).reshape(-1, 2), (res * res, 1))
    d = scene.camera.ray_directions((res, res), pix, off)
    return pix, Tracer(scene).intersect(np.broadcast_to(scene.camera.position, d.shape), d)
