"""How MMLT evaluates its states: one strategy per state, or every strategy of a BDPT sample (layer 5).

:func:`evaluate_states` gives each state of :mod:`mcvar.integrators.mmlt` its
target ``f_d`` (the MIS-weighted contribution of the strategy its
connection number picks, times ``d + 1``) and its splat; :func:`bootstrap_values`
joins the subpaths of a state in every strategy of every depth (the
bootstrap's BDPT sample). Both run either BDPT's own connection code
(``kernel='general'``: :mod:`mcvar.integrators.bdpt`, every scene) or, on
Lambertian scenes lit by area lights, the kernel of
:mod:`mcvar.integrators.mmlt_lambertian` (the same values in one
vectorised pass). The state's layout is :class:`mcvar.integrators.mmlt.StateLayout`
(passed in; read through its attributes).

References
----------
.. [1] T. Hachisuka, A. S. Kaplanyan, C. Dachsbacher, "Multiplexed
   Metropolis Light Transport", ACM Transactions on Graphics 33(4)
   (SIGGRAPH 2014).
.. [2] E. Veach, "Robust Monte Carlo Methods for Light Transport
   Simulation", PhD thesis, Stanford 1997, ch. 10.
"""
from __future__ import annotations

import numpy as np

from ..envmap import LUMINANCE_WEIGHTS
from .bdpt import _connect_emitter, _connect_inner, _mis_weight
from .light import PathNumbers, _connect_camera, camera_subpath, light_subpath
from .mmlt_lambertian import connect_lambertian, lambertian_scene, trace_lambertian

__all__ = ["KERNELS", "evaluate_states", "strategy_columns", "bootstrap_values", "bootstrap_splats"]

#: Values of the ``kernel`` option: 'auto' (the Lambertian kernel where the scene allows it), 'general'
#: (BDPT's own connections: every scene), 'lambertian' (an error where it does not apply).
KERNELS = ("auto", "general", "lambertian")

_LUM = np.asarray(LUMINANCE_WEIGHTS)


class _Rows:
    """A subpath's ``(depth, n)`` field seen through a map of rows (``a[i, idx] = base[i, rows[idx]]``)."""

    __slots__ = ("base", "rows")

    def __init__(self, base, rows):
        self.base, self.rows = base, rows

    def __getitem__(self, key):
        i, idx = key
        return self.base[i, self.rows[idx]]


class _Subset:
    """The paths ``rows`` of a :class:`~mcvar.integrators.light.Subpath`, renumbered ``0 .. len(rows) - 1``
    (the chains of one strategy among those traced with the same number of vertices)."""

    def __init__(self, sub, rows):
        self._sub, self._rows = sub, rows
        self.length = sub.length[rows]
        self.point = sub.point[rows]
        self.pixel = sub.pixel[rows]

    def __getattr__(self, name):
        return _Rows(getattr(self._sub, name), self._rows)


def _film_position(x, res):
    """Pixels and in-pixel offsets of the film numbers (columns 0, 1) of states ``x``."""
    width, height = res
    col = np.minimum((x[:, 0] * width).astype(np.intp), width - 1)
    row = np.minimum((x[:, 1] * height).astype(np.intp), height - 1)
    offsets = np.stack([x[:, 0] * width - col, x[:, 1] * height - row], axis=1)
    return row * width + col, offsets


def _subpaths(ctx, layout, x, cam_cap, light_cap):
    """The camera subpaths (``cam_cap`` vertices each, None: none) and light subpaths (``light_cap``)
    of states ``x``, each traced in one wavefront (:class:`~mcvar.integrators.light.PathNumbers`
    with per-path caps): ``(C, L, rays)``."""
    C = L = None
    rays = 0
    if cam_cap is not None and x.shape[0]:
        pixel, offsets = _film_position(x, ctx.res)
        numbers = PathNumbers(None, x[:, layout.camera_vertices], cap=cam_cap)
        C = camera_subpath(ctx.scene, ctx.tracer, ctx.res, pixel, offsets, int(cam_cap.max()), numbers,
                           roulette=False)
        rays += C.rays
    if light_cap is not None and x.shape[0]:
        numbers = PathNumbers(np.ascontiguousarray(x[:, layout.light_origin]), x[:, layout.light_vertices],
                              cap=light_cap)
        L = light_subpath(ctx.scene, ctx.tracer, ctx.em, x.shape[0], int(light_cap.max()), numbers,
                          roulette=False)
        rays += L.rays
    return C, L, rays


def _connect(ctx, L, C, s: int, t: int):
    """BDPT's connection of strategy ``(s, t)`` (:mod:`mcvar.integrators.bdpt`): ``(paths, pixel,
    value, weight, rays)`` for the paths that carry light, weighted by BDPT's MIS weight."""
    if t == 1:
        k, pix, value, weight = _connect_camera(ctx, L, s, _mis_weight)
        return k, pix, value, weight, k.size
    if s == 0:
        k, value, weight = _connect_emitter(ctx, C, t)
        return k, C.pixel[k], value, weight, 0
    k, value, weight = _connect_inner(ctx, L, C, s, t)
    return k, C.pixel[k], value, weight, k.size


def _kernel(ctx, kernel: str) -> bool:
    """Whether the Lambertian kernel (:mod:`mcvar.integrators.mmlt_lambertian`) evaluates: ``kernel``
    'auto' (where the scene allows it), 'general' (BDPT's own code) or 'lambertian'."""
    if kernel == "general":
        return False
    ok = lambertian_scene(ctx.scene)
    if kernel == "lambertian" and not ok:
        raise ValueError(f"kernel='lambertian' needs Lambertian materials and area lights only; scene "
                         f"{ctx.scene.name!r} has other materials, a point light or an environment map")
    return ok


def evaluate_states(ctx, layout, x: np.ndarray, depth: np.ndarray, kernel: str = "auto", work=None):
    """The target and the splat of each state: ``(f (m,), pixel (m,), rgb (m, 3), rays)``.

    State ``x[j]`` at depth ``depth[j]`` picks strategy ``s = floor(u (d + 1))``
    (``u`` its connection number), ``t = d + 1 - s``; the camera subpath of
    ``t`` vertices and the light subpath of ``s`` vertices are traced from its
    streams (:class:`~mcvar.integrators.light.PathNumbers`), the camera
    subpaths of all states in one wavefront and the light subpaths in
    another (each path stops at its own length), and joined by BDPT's
    connection of that strategy, weighted by BDPT's MIS weight
    (:func:`~mcvar.integrators.bdpt._mis_weight`), one call per strategy.
    ``rgb = (d + 1) w_{s,t} C_{s,t}`` (0 for paths that carry no light, with
    ``pixel = -1``), ``f = Y(rgb)``. ``E f = b_d`` for uniform states.
    With ``kernel`` 'auto' a Lambertian scene is evaluated by the Lambertian
    kernel instead (the same values in one vectorised pass:
    :mod:`mcvar.integrators.mmlt_lambertian`); 'general' forces BDPT's code.
    """
    m = x.shape[0]
    n_strat = depth + 1
    s = np.minimum((x[:, layout.strategy] * n_strat).astype(np.intp), depth)
    t = n_strat - s
    if _kernel(ctx, kernel):
        C, L, pix, rays = trace_lambertian(ctx, layout, x, t, s, work)
        f, pixel, rgb, r = connect_lambertian(ctx, C, L, pix, np.arange(m), s, t, depth)
        return f, pixel, rgb, rays + r
    rgb = np.zeros((m, 3))
    pixel = np.full(m, -1, dtype=np.intp)
    cam_rows, light_rows = np.flatnonzero(t >= 2), np.flatnonzero(s >= 1)
    C, _, rays_c = _subpaths(ctx, layout, x[cam_rows], t[cam_rows] if cam_rows.size else None, None)
    _, L, rays_l = _subpaths(ctx, layout, x[light_rows], None, s[light_rows] if light_rows.size else None)
    rays = rays_c + rays_l
    code = s * (layout.max_depth + 2) + t
    order = np.argsort(code, kind="stable")
    keys, starts = np.unique(code[order], return_index=True)
    for key, grp in zip(keys.tolist(), np.split(order, starts[1:])):
        sv, tv = divmod(key, layout.max_depth + 2)
        Lg = _Subset(L, np.searchsorted(light_rows, grp)) if sv >= 1 else None
        Cg = _Subset(C, np.searchsorted(cam_rows, grp)) if tv >= 2 else None
        if (Lg is not None and not np.any(Lg.length >= sv)) or (Cg is not None and not np.any(Cg.length >= tv)):
            continue                                  # no path of the group has the vertices
        k, pix, value, weight, r = _connect(ctx, Lg, Cg, sv, tv)
        rays += r
        rgb[grp[k]] = value * (weight * n_strat[grp[k]])[:, None]
        pixel[grp[k]] = pix
    f = rgb @ _LUM
    pixel[f <= 0.0] = -1
    return f, pixel, rgb, rays


def strategy_columns(max_depth: int):
    """``(depth, s)`` of every strategy of depths ``1 .. max_depth``: the columns of :func:`bootstrap_values`."""
    return [(d, s) for d in range(1, max_depth + 1) for s in range(d + 1)]


def bootstrap_values(ctx, layout, x: np.ndarray, kernel: str = "auto", work=None):
    """Every strategy's target at the camera and light numbers of states ``x``: ``(f (m, n_strategies), rays)``.

    One bidirectional sample per state (the BDPT of
    :func:`~mcvar.integrators.bdpt.bdpt_contributions` at a fixed depth):
    a camera subpath of ``max_depth + 1`` and a light subpath of
    ``max_depth`` vertices, joined in every way. Column ``j`` holds
    ``f_d`` of the state with strategy ``(d, s) = strategy_columns(max_depth)[j]``
    (its connection number anywhere in ``[s, s + 1) / (d + 1)``): the
    subpaths of a state with fewer vertices are prefixes of these (no Russian
    roulette), so the values are :func:`evaluate_states`' (tested). ``mean_j
    sum_s f[:, (d, s)] / (d + 1)`` is BDPT's estimate of ``b_d``.
    """
    f, _, _, rays = bootstrap_splats(ctx, layout, x, kernel, work)
    return f, rays


def bootstrap_splats(ctx, layout, x: np.ndarray, kernel: str = "auto", work=None):
    """:func:`bootstrap_values` with the splats: ``(f, pixel, rgb, rays)``, shapes ``(m, n)``, ``(m, n)``,
    ``(m, n, 3)`` for ``n`` strategies; ``rgb = (d + 1) w_{s,t} C_{s,t}``, ``pixel`` its film pixel
    (-1 where it carries no light). ``sum_{s} rgb[:, (d, s)] / (d + 1)`` splatted at its pixels is one
    BDPT sample of the depth-``d`` image (MMLT's ``direct_depth`` part)."""
    D = layout.max_depth
    m = x.shape[0]
    cols = strategy_columns(D)
    if _kernel(ctx, kernel):
        C, L, pix, rays = trace_lambertian(ctx, layout, x, np.full(m, D + 1), np.full(m, D), work)
        dep, s = (np.tile(np.array([c[i] for c in cols]), m) for i in (0, 1))
        f, pixel, rgb, r = connect_lambertian(ctx, C, L, pix, np.repeat(np.arange(m), len(cols)), s, dep + 1 - s,
                                              dep)
        return f.reshape(m, len(cols)), pixel.reshape(m, len(cols)), rgb.reshape(m, len(cols), 3), rays + r
    C, L, rays = _subpaths(ctx, layout, x, np.full(m, D + 1), np.full(m, D))
    rgb = np.zeros((m, len(cols), 3))
    pixel = np.full((m, len(cols)), -1, dtype=np.intp)
    s_max, t_max = int(L.length.max()), int(C.length.max())
    for j, (d, s) in enumerate(cols):
        if s > s_max or d + 1 - s > t_max:
            continue                                  # no path has the vertices
        k, pix, value, weight, r = _connect(ctx, L, C, s, d + 1 - s)
        rays += r
        rgb[k, j] = value * (weight * (d + 1))[:, None]
        pixel[k, j] = pix
    f = rgb @ _LUM
    pixel[f <= 0.0] = -1
    return f, pixel, rgb, rays
