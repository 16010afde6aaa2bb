"""Emitters of a scene file as mcvar's: parallelogram lights and environment images (layer 3.5).

:func:`as_parallelogram` finds the quads among an area emitter's triangles
(mcvar's next-event estimation samples parallelograms); :func:`unrefine`
and :func:`envmap_to_mcvar` turn a Mitsuba ``envmap`` image into mcvar's
lat-long orientation.
"""
from __future__ import annotations

import math

import numpy as np

from .xml import Node

__all__ = ["as_parallelogram", "unrefine", "envmap_to_mcvar"]


def as_parallelogram(a, b, tol=1e-9):
    """``(origin, e1, e2)`` if triangles ``a`` and ``b`` share an edge and together form a
    parallelogram, with ``cross(e1, e2)`` along ``a``'s normal; else None."""
    atol = tol * (1.0 + max(np.abs(a).max(), np.abs(b).max()))
    if np.allclose(a[0], b[0], rtol=0, atol=atol) and np.allclose(a[2], b[1], rtol=0, atol=atol):
        # the split (v0, v1, v2), (v0, v2, v3) of mcvar's builders: origin v0, edges v1 - v0, v3 - v0
        v0, v1, v2, v3 = a[0], a[1], a[2], b[2]
        if np.allclose(v1 + v3, v0 + v2, rtol=0, atol=atol) and \
                np.cross(v1 - v0, v2 - v0) @ np.cross(v2 - v0, v3 - v0) > 0:
            return v0.copy(), v1 - v0, v3 - v0
    shared = [(i, j) for i in range(3) for j in range(3) if np.allclose(a[i], b[j], rtol=0, atol=tol * (1 + np.abs(a).max()))]
    if len(shared) != 2:
        return None
    (i0, j0), (i1, j1) = shared
    x = a[3 - i0 - i1]
    y = b[3 - j0 - j1]
    s, t = a[i0], a[i1]
    scale = 1.0 + max(np.abs(a).max(), np.abs(b).max())
    if not np.allclose(x + y, s + t, rtol=0, atol=tol * scale):
        return None
    e1, e2 = s - x, t - x
    n_a = np.cross(a[1] - a[0], a[2] - a[0])
    n_b = np.cross(b[1] - b[0], b[2] - b[0])
    if n_a @ n_b <= 0:
        return None                                   # the two triangles face different ways
    if np.cross(e1, e2) @ n_a < 0:
        e1, e2 = e2, e1
    return x.copy(), e1, e2


def unrefine(image):
    """mcvar's lat-long image back from the refined bitmap ``mcvar.interop.mitsuba`` writes, or ``image``.

    The exporter writes a map of ``H x W`` pixels as ``(k H + 1) x k W``
    texels: every pixel's column repeated ``k`` times, rows repeated ``k - 1``
    times with the mean of the two neighbouring rows on each edge, so that
    Mitsuba's bilinear lookup integrates like mcvar's nearest one. That
    layout is recognised exactly (to float32 rounding) and undone; any other
    image is used as it is (Mitsuba interpolates it bilinearly, mcvar looks
    it up nearest: the same integral over each pixel, not the same values).
    """
    img = np.asarray(image, dtype=np.float64)
    hh, ww = img.shape[:2]
    for k in range(min(ww, hh - 1), 1, -1):
        if ww % k or (hh - 1) % k:
            continue
        h, w = (hh - 1) // k, ww // k
        base = img[1::k][:h]                                    # the first inside row of each pixel row
        cols = base[:, ::k]
        tol = 1e-6 * max(np.abs(img).max(), 1e-30)
        if not np.allclose(np.repeat(cols, k, axis=1), base, rtol=0, atol=tol):
            continue
        node = np.arange(hh)
        inside = node % k != 0
        fine = np.repeat(cols, k, axis=1)
        if not np.allclose(img[inside], fine[node[inside] // k], rtol=0, atol=tol):
            continue
        edge = node[~inside] // k
        mean = 0.5 * (fine[np.clip(edge - 1, 0, h - 1)] + fine[np.clip(edge, 0, h - 1)])
        if np.allclose(img[~inside], mean, rtol=0, atol=tol):
            return cols
    return img


def envmap_to_mcvar(image, to_world, node: Node):
    """A Mitsuba ``envmap`` image as mcvar's lat-long image (same directions, same radiance).

    Mitsuba looks a world direction ``d`` up at ``u = atan2(x, -z) / (2 pi)``,
    ``v = acos(y) / pi`` of ``to_world^-1 d``; mcvar at ``phi = atan2(z, x)``
    (column ``phi W / (2 pi)``), theta from +y. Both have row 0 at +y and
    azimuth growing the same way, so for a ``to_world`` that rotates about
    +y by ``alpha`` mcvar's column ``j`` is Mitsuba's column
    ``j + W / 4 + W alpha / (2 pi)`` (mod W): an exact column roll when
    that is an integer; anything else is an error.
    """
    img = np.asarray(image, dtype=np.float64)
    width = img.shape[1]
    m = to_world[:3, :3]
    alpha = math.atan2(m[0, 2], m[0, 0])
    expected = np.array([[math.cos(alpha), 0.0, math.sin(alpha)], [0.0, 1.0, 0.0],
                         [-math.sin(alpha), 0.0, math.cos(alpha)]])
    if not np.allclose(m, expected, atol=1e-9):
        raise node.error("an envmap's to_world must be a rotation about +y (mcvar's environment is "
                         "oriented with +y up)")
    shift = width / 4.0 + width * alpha / (2.0 * math.pi)
    if abs(shift - round(shift)) > 1e-6:
        raise node.error(f"the envmap's rotation about +y must move it by whole columns: width {width} "
                         f"and angle {math.degrees(alpha):g} deg give a shift of {shift:g} columns")
    return np.roll(img, -int(round(shift)) % width, axis=1)
