"""The slides' slips, measured: the numbers of ``docs/slips.md`` and the page itself.

Every number on the page is a placeholder ``[[key|format]]`` of :data:`TEMPLATE`,
filled from :func:`measure` (mcvar computes each one, fixed seeds). Regenerate
the page with::

    PYTHONPATH=. python docs/slips.py            # writes docs/slips.md

``tests/test_slips.py`` parses the committed page against the template (every
word outside the placeholders must match), recomputes every number and checks
that the page states it: within the rounding of its printed digits plus
``z`` standard errors for the Monte Carlo ones (``z`` Sidak-corrected over all
of them, family-wise alpha = 1e-3).

The measurements are short (about ten seconds on a shared 2-core machine);
each slip's function names the slide it answers.
"""
from __future__ import annotations

import math
import re
import sys
from pathlib import Path

import numpy as np

PAGE = Path(__file__).with_name("slips.md")
_PLACEHOLDER = re.compile(r"\[\[([a-z0-9_.]+)\|([^\]]+)\]\]")
_NUMBER = r"([-+]?(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?)"
SEED = 20_261_201


def _est(values) -> tuple[float, float]:
    """Mean and standard error of iid values."""
    v = np.asarray(values, float).ravel()
    return float(v.mean()), float(v.std(ddof=1) / math.sqrt(v.size))


def _exact(x) -> tuple[float, float]:
    return float(x), 0.0


# ----------------------------------------------------------------------------
# BRDFs
# ----------------------------------------------------------------------------
def _passthrough(rng):
    """'A BRDF is a passthrough function ... f_r = <0.85, 0.90, 0.50>' (Types of Reflectance Functions)."""
    from mcvar import bsdf as B, warps
    from mcvar.estimators import estimate
    out = {}
    est = estimate(lambda w: np.full(len(w), 0.85) * w[:, 1], sample=warps.square_to_uniform_hemisphere,
                   pdf=warps.square_to_uniform_hemisphere_pdf, n=200_000, rng=rng)
    out["passthrough.reflected"] = (est.mean, est.stderr)
    out["passthrough.exact"] = _exact(0.85 * math.pi)
    out["passthrough.f_right"] = _exact(0.85 / math.pi)
    wo = np.array([[0.3, 0.9, 0.1]]) / np.linalg.norm([0.3, 0.9, 0.1])
    alb = B.directional_albedo(B.Lambertian(0.85), wo, n=4096, rng=rng)
    out["passthrough.lambertian"] = _exact(alb.mean[0, 0])      # cosine sampling: every weight is 0.85
    return out


def _steradians(rng):
    """'[1/sr] ... measured in steradians' (Radiometric Description of BRDF)."""
    from scipy import integrate
    f_sr = 0.8 / math.pi
    deg2 = (math.pi / 180.0) ** 2            # one square degree in steradians
    f_deg = f_sr * deg2                       # the same BRDF per square degree
    # L_o = int f L cos over the hemisphere (L = 1), integrated in square degrees with f per square degree
    # (d omega in square degrees = sin(theta) d theta_deg d phi_deg)
    lo_deg = integrate.dblquad(lambda t, p: f_deg * math.cos(math.radians(t)) * math.sin(math.radians(t)),
                               0, 360, 0, 90)[0]
    return {"sr.f_sr": _exact(f_sr), "sr.f_deg": _exact(f_deg), "sr.hemisphere_deg": _exact(2 * math.pi / deg2),
            "sr.lo_deg": _exact(lo_deg)}


def _diffuse_average(rng):
    """'Colors sampled from uniform hemisphere blend all colors into one average color' (Diffuse Exitant Radiance)."""
    from mcvar import bsdf as B, warps
    n = 200_000
    r1, r2 = rng.spawn(2)
    lam = B.Lambertian(1.0)
    wo = np.tile([[0.0, 1.0, 0.0]], (n, 1))
    s = lam.sample(wo, r1.random((n, 2)))
    field = lambda w: np.maximum(w[:, 1], 0.0)           # a sky brighter overhead: L_i = cos(theta)
    lo = s.weight[:, 0] * field(s.wi)                      # the Lambertian's own estimator of L_o
    uni = field(warps.square_to_uniform_hemisphere(r2.random((n, 2))))
    return {"diffuse.cosine": _est(lo), "diffuse.uniform": _est(uni),
            "diffuse.exact_cosine": _exact(2 / 3), "diffuse.exact_uniform": _exact(1 / 2)}


def _lambertian_weight(rng):
    """'Easy! Pick any outgoing ray' (Lambertian Material): cosine sampling's weight is the albedo."""
    from mcvar import bsdf as B
    lam = B.Lambertian(0.8)
    wo = np.tile(np.array([[0.5, 0.6, -0.62]]) / np.linalg.norm([0.5, 0.6, -0.62]), (100_000, 1))
    s = lam.sample(wo, rng.random((100_000, 2)))
    return {"lambert.max_dev": _exact(np.max(np.abs(s.weight - 0.8)))}


# ----------------------------------------------------------------------------
# Materials: refraction, total internal reflection, Fresnel
# ----------------------------------------------------------------------------
def _tir(rng):
    """'0 < 1 - (1 - cos^2 theta) < 1' (Refractive Material: the TIR derivation)."""
    from mcvar import optics, warps
    n = 200_000
    w = warps.square_to_uniform_hemisphere(rng.random((n, 2))) * [1, -1, 1]   # inside the glass (below)
    _, tir = optics.refract(w, 1.0, 1.5)
    c = np.abs(w[:, 1])
    dropped = 1.0 - (1.0 - c * c)                       # the slide's expression without (eta_i / eta_t)^2
    return {"tir.fraction": _est(tir), "tir.exact": _exact(math.cos(optics.critical_angle(1.5, 1.0))),
            "tir.critical": _exact(math.degrees(optics.critical_angle(1.5, 1.0))),
            "tir.dropped_negative": _exact(np.mean(dropped < 0))}


def _eta2(rng):
    """'Simply pick the refracted direction!' (Refractive Material): radiance scales by (eta_t / eta_i)^2."""
    from mcvar import optics
    from mcvar.geometry import spherical_to_direction
    out = {}
    for label, theta_deg in (("0", 0.0), ("45", 45.0)):
        # a small cone of incident directions (half-angle 0.05 deg) around theta, refracted into glass:
        # ratio of solid angles by the area of the refracted patch on the sphere (a fine grid of it)
        d = math.radians(0.05)
        k = 201
        tt, pp = np.meshgrid(np.linspace(-d, d, k), np.linspace(-d, d, k), indexing="ij")
        inside = tt ** 2 + pp ** 2 <= d * d
        # directions around the axis at theta, via a tangent-plane grid
        axis = spherical_to_direction(np.array([math.radians(theta_deg)]), np.array([0.0]))[0]
        e1 = np.cross(axis, [0.0, 0.0, 1.0]); e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        grid = axis + tt[..., None] * e1 + pp[..., None] * e2
        grid /= np.linalg.norm(grid, axis=-1, keepdims=True)
        t, _ = optics.refract(grid.reshape(-1, 3), 1.0, 1.5)
        t = t.reshape(k, k, 3)
        # solid angle of each refracted grid cell: |d t/du x d t/dv| du dv
        du = np.gradient(t, axis=0); dv = np.gradient(t, axis=1)
        cell_t = np.linalg.norm(np.cross(du, dv), axis=-1)
        du0 = np.gradient(grid, axis=0); dv0 = np.gradient(grid, axis=1)
        cell_i = np.linalg.norm(np.cross(du0, dv0), axis=-1)
        ratio = cell_i[inside].sum() / cell_t[inside].sum()            # d omega_i / d omega_t
        cos_i = axis[1]; cos_t = -float(optics.refract(axis[None], 1.0, 1.5)[0][0, 1])
        fres = float(optics.fresnel_dielectric(cos_i, 1.0, 1.5))
        out[f"eta2.radiance_{label}"] = _exact((1 - fres) * ratio * cos_i / cos_t)
        out[f"eta2.transmit_{label}"] = _exact(1 - fres)
    out["eta2.exact"] = _exact(1.5 ** 2)
    return out


def _schlick(rng):
    """'cos theta is the same as n . omega' (Schlick's Approximation) inside the dense medium."""
    from mcvar import optics
    theta_c = optics.critical_angle(1.5, 1.0)
    th = np.linspace(theta_c + 1e-9, math.pi / 2, 20_001)
    c = np.cos(th)
    exact = optics.fresnel_dielectric(c, 1.5, 1.0)            # 1: total internal reflection
    r0 = ((1.5 - 1.0) / 2.5) ** 2
    inside = r0 + (1 - r0) * (1 - c) ** 5                      # Schlick with the cosine in the glass
    right = optics.fresnel_schlick(c, 1.5, 1.0)                # with the transmitted cosine (mcvar)
    c45 = math.cos(math.radians(45.0))
    below = np.cos(np.linspace(0.0, theta_c - 1e-9, 20_001))     # below the critical angle, glass to air
    exact_below = optics.fresnel_dielectric(below, 1.5, 1.0)
    return {"schlick.below_mcvar": _exact(np.max(np.abs(optics.fresnel_schlick(below, 1.5, 1.0) - exact_below))),
            "schlick.below_inside": _exact(np.max(np.abs(r0 + (1 - r0) * (1 - below) ** 5 - exact_below))),
            "schlick.at45": _exact(r0 + (1 - r0) * (1 - c45) ** 5),
            "schlick.max_err": _exact(np.max(np.abs(exact - inside))),
            "schlick.mean_err": _exact(np.mean(np.abs(exact - inside))),
            "schlick.mcvar_err": _exact(np.max(np.abs(exact - right)))}


# ----------------------------------------------------------------------------
# Environment lighting
# ----------------------------------------------------------------------------
def _envmap_map():
    from mcvar.envmap import EnvironmentMap
    h, w = 32, 64
    theta = (np.arange(h) + 0.5) * math.pi / h
    phi = (np.arange(w) + 0.5) * 2 * math.pi / w
    lum = (0.2 + np.cos(theta)[:, None] ** 2) * (1.0 + 0.5 * np.cos(phi)[None, :])
    return EnvironmentMap(np.repeat(lum[..., None], 3, axis=-1))


def _envmap_jacobian(rng):
    """'PDF of a pixel should be proportional to its flux ... L sin theta' (Creating A PDF), without the sin."""
    from mcvar.piecewise import PiecewiseConstant1D
    from mcvar.testing import chi2_test
    env = _envmap_map()
    h, w = env.height, env.width
    table = PiecewiseConstant1D(env.luminance.ravel())           # P ~ L: the sin(theta) left out
    edges = np.cos(np.arange(h + 1) * math.pi / h)

    def wrong(u):
        k, _, t = table.sample_discrete(u[:, 0])
        i, j = np.divmod(k, w)
        cos_t = edges[i] - u[:, 1] * (edges[i] - edges[i + 1])
        sin_t = np.sqrt(np.maximum(0.0, 1 - cos_t ** 2))
        p = (j + t) * 2 * math.pi / w
        return np.stack([sin_t * np.cos(p), cos_t, sin_t * np.sin(p)], -1)

    r1, r2 = rng.spawn(2)
    bad = chi2_test(wrong, env.pdf, "sphere", n=200_000, rng=r1)
    good = chi2_test(lambda u: env.sample(u)[0], env.pdf, "sphere", n=200_000, rng=r2)
    out = {}
    for name, res in (("wrong", bad), ("right", good)):
        ratio = res.statistic / res.dof
        # sd of chi2/dof: sqrt(2 dof + 8 lambda) / dof, lambda = noncentrality ~ statistic - dof
        lam = max(res.statistic - res.dof, 0.0)
        out[f"env.chi2_{name}"] = (ratio, math.sqrt(2 * res.dof + 8 * lam) / res.dof)
    out["env.dof"] = _exact(good.dof)
    # 'divide contribution by PDF of selected pixel': dividing by P_ij, not P_ij / Omega_ij
    u = rng.random((200_000, 2))
    d, pdf = env.sample(u)
    i, j = env.direction_to_pixel(d)
    p_pixel = env.pixel_probabilities()[i, j]
    y = env.luminance[i, j]
    exact = float(np.sum(env.luminance * env.pixel_solid_angle[:, None]))
    out["env.integral"] = _exact(exact)
    out["env.divided_pdf"] = _est(y / pdf)
    out["env.divided_pixel"] = _est(y / p_pixel)
    return out


def _undivided(rng):
    """The 'Importance Sampling' code slide: trace_ray(rf) with no division by the pdf."""
    from mcvar.envmap import sky_with_sun
    env = sky_with_sun(height=64, width=128)
    normal = np.array([0.0, 1.0, 0.0])
    y = np.array([0.2126, 0.7152, 0.0722])
    d, pdf = env.sample(rng.random((200_000, 2)))
    f = (env.radiance(d) @ y) * np.maximum(0.0, d @ normal)
    return {"undiv.exact": _exact(env.irradiance(normal) @ y), "undiv.divided": _est(f / pdf),
            "undiv.undivided": _est(f)}


# ----------------------------------------------------------------------------
# Monte Carlo, bias, consistency, variance
# ----------------------------------------------------------------------------
def _rays(rng):
    """'Both rasterization and direct illumination only ever trace one ray!' (Direct VS Rasterization)."""
    from mcvar.integrators import render
    from mcvar.scene import load_scene
    scene = load_scene("cornell")
    out = {}
    for method in ("raster", "direct_light", "direct"):
        per = [render(scene, integrator=method, spp=4, res=16, rng=g).rays / (16 * 16 * 4) for g in rng.spawn(4)]
        out[f"rays.{method}"] = _est(per) if np.ptp(per) > 0 else _exact(per[0])
    return out


def _unbiased_consistent(rng):
    """'An unbiased renderer ... approaches ground truth with infinite sampling' (Biased vs. Unbiased Renderer)."""
    from mcvar.examples import INTEGRANDS, checkerboard, fixed_grid_estimate, single_sample_estimate
    single = np.array([single_sample_estimate(checkerboard, upper=(2, 2), rng=g) for g in rng.spawn(2000)])
    disk = INTEGRANDS["disk"]
    out = {"unb.single_mean": _est(single), "unb.single_rmse": _exact(math.sqrt(np.mean((single - 2) ** 2)))}
    for m in (8, 64, 512):
        out[f"unb.grid_{m}"] = _exact(fixed_grid_estimate(disk.f, m) - disk.exact)
    return out


def _variance_wording(rng):
    """'Variance is how far we are from the average, on average' (Variance)."""
    x = rng.random(1_000_000)
    return {"var.board_mad": _exact(2.0), "var.board_var": _exact(4.0),
            "var.u_mad": _est(np.abs(x - 0.5)), "var.u_var": _est((x - 0.5) ** 2),
            "var.u_sd": _exact(math.sqrt(1 / 12))}


def _consistency_definition(rng):
    """'lim P(|I - I_n| > 0) = 0' (Bias & Consistency), already in notebooks 02 and 06."""
    from scipy import stats
    n = 1024
    k = np.arange(n + 1)
    pk = stats.binom.pmf(k, n, 0.5)
    return {"cdef.p0": _exact(pk[k != n // 2].sum())}


# ----------------------------------------------------------------------------
# Samplers
# ----------------------------------------------------------------------------
def _jitter_distance(rng):
    """'Ensures distance between samples, but not enough!' (Jittered Sampling)."""
    from scipy.spatial import cKDTree
    from mcvar import samplers as S
    out = {}
    n, sets = 256, 200
    cell = 1 / 16
    for name in ("jittered", "random", "blue_noise"):
        mins = []
        for g in rng.spawn(sets):
            p = S.get_sampler(name)(n, rng=g)
            dist, _ = cKDTree(p).query(p, k=2)
            mins.append(dist[:, 1].min() / cell)
        mins = np.array(mins)
        out[f"jit.{name}_min"] = _est(mins)
        out[f"jit.{name}_p01"] = _est(mins < 0.1)
    return out


def _n_rooks(rng):
    """'Randomly shuffle (x, y) coordinates until rooks condition satisfied' (N-Rooks Sampling)."""
    from mcvar import samplers as S
    n, trials = 16, 10_000
    diag = np.arange(n)
    ok = 0
    for _ in range(trials):
        x = rng.permutation(diag)                  # shuffle the x coordinates of the diagonal points
        ok += len(set(x.tolist())) == n and len(set(diag.tolist())) == n
    rooks = [all(len(set(np.floor(S.n_rooks(n, rng=g)[:, j] * n).astype(int))) == n for j in (0, 1))
             for g in rng.spawn(1000)]
    return {"rooks.shuffle_ok": _exact(ok / trials), "rooks.mcvar_ok": _exact(np.mean(rooks)),
            "rooks.random_columns": _exact(math.exp(math.lgamma(n + 1) - n * math.log(n)))}


def _hammersley(rng):
    from mcvar import samplers as S
    return {"ham.phi13": _exact(S.radical_inverse(13, 2))}


def _grid_discrepancy(rng):
    from mcvar import discrepancy as D, samplers as S
    return {"grid.star": _exact(D.star(S.grid(256))), "grid.sobol": _exact(D.star(S.sobol(256, rng=SEED)))}


def _blue_anisotropy(rng):
    from mcvar import discrepancy as D, samplers as S
    vals = [D.power_spectrum(S.blue_noise(1024, rng=g)).anisotropy for g in rng.spawn(4)]
    grid = D.power_spectrum(S.grid(1024)).anisotropy
    return {"blue.aniso": _est(vals), "blue.grid_aniso": _exact(grid)}


def _brdf_pdf(rng):
    from mcvar import bsdf as B
    from mcvar.geometry import spherical_to_direction
    from scipy import integrate
    lam = B.Lambertian(0.8)
    wo = np.array([[0.0, 1.0, 0.0]])
    f = lambda t: lam.eval(wo, spherical_to_direction(np.array([t]), np.array([0.0])))[0, 0]
    return {"pdf.int_f": _exact(integrate.quad(lambda t: 2 * math.pi * f(t) * math.sin(t), 0, math.pi / 2)[0])}


def _mirror(rng):
    d = math.radians(0.1)
    return {"mirror.cone": _exact(math.pi * math.sin(d) ** 2)}


# ----------------------------------------------------------------------------
# Rendering methods
# ----------------------------------------------------------------------------
def _image_mean(r):
    n_pix = r.image.shape[0] * r.image.shape[1]
    return r.image.mean((0, 1)), np.sqrt((r.variance / r.spp).sum((0, 1))) / n_pix


def _bdpt_point(rng):
    """'Unbiased algorithm - no longer trying to connect rays through non-volume sources' (Bidirectional Path Tracing)."""
    from mcvar.integrators import render
    from mcvar.scene import load_scene
    scene = load_scene("cornell-point")
    y = np.array([0.2126, 0.7152, 0.0722])
    g_b, g_l, g_p = rng.spawn(3)
    # replicates: light tracing splats, so a render's per-pixel variance is not defined
    means = {m: [float(render(scene, integrator=m, spp=4, res=16, rng=g).image.mean((0, 1)) @ y) for g in gg.spawn(8)]
             for m, gg in (("bdpt", g_b), ("light", g_l))}
    (mb, sb), (ml, sl) = _est(means["bdpt"]), _est(means["light"])
    pb = render(scene, integrator="path_bsdf", spp=16, res=16, rng=g_p)
    return {"bdpt.mean": (mb, sb), "bdpt.light_mean": (ml, sl), "bdpt.z": ((mb - ml) / math.hypot(sb, sl), 1.0),
            "bdpt.path_bsdf": _exact(float(pb.image.max()))}


def _mh_darkness(rng):
    """'Transition probability is relative darkness f(x')/f(x_i)' (Metropolis Hasting: Sampling An Image)."""
    from mcvar import mcmc
    image = np.full((8, 16), 0.1)
    image[:, :8] = 1.0                                   # left half bright, right half 10x darker
    g1, g2 = rng.spawn(2)
    walk = mcmc.image_walk(image, 4000, chains=64, sigma=0.05, rng=g1)
    bright = walk.estimate(lambda x: (x[..., 0] < 0.5).astype(float))
    f = lambda u: np.where(u[:, 0] < 0.5, 1.0, 0.1)
    dark = mcmc.metropolis(lambda u: 1.0 / f(u), 2, 4000, chains=64, sigma=0.05, rng=g2)   # accept f(x)/f(x')
    darkest = dark.estimate(lambda x: (x[..., 0] < 0.5).astype(float))
    return {"mh.bright": (float(bright.mean), float(bright.stderr)), "mh.exact": _exact(1 / 1.1),
            "mh.dark": (float(darkest.mean), float(darkest.stderr)), "mh.exact_dark": _exact(0.1 / 1.1)}


def _mis_average(rng):
    """'MIS allows us to take both rays and average them together' (Multiple Importance Sampling).

    Direct light at a glossy point (local frame, normal +y): a light of radiance 1 filling a cone of
    half-angle ``alpha`` about the normal, a normalised Phong lobe ``(k + 2) / (2 pi) cos^k`` about it.
    Exact: ``1 - cos(alpha)^(k + 2)``. Strategies: sample the light (uniform in the cone) or the BSDF
    (the Phong lobe); one ray of each per sample, the same budget for averaging and for MIS.
    """
    from mcvar import warps
    from mcvar.estimators import balance_heuristic
    out = {}
    n = 100_000
    for label, k, alpha in (("a", 200.0, 30.0), ("b", 5.0, 2.0)):
        cmax = math.cos(math.radians(alpha))

        def f(w, k=k, cmax=cmax):
            return (w[:, 1] > cmax) * (k + 2) / (2 * math.pi) * np.maximum(w[:, 1], 0) ** (k + 1)

        p_light = lambda v, c=cmax: warps.square_to_uniform_cone_pdf(v, c)
        p_brdf = lambda v, k=k: warps.square_to_phong_lobe_pdf(v, k)
        g1, g2 = rng.spawn(2)
        x_l = warps.square_to_uniform_cone(g1.random((n, 2)), cmax)     # one light ray ...
        x_b = warps.square_to_phong_lobe(g2.random((n, 2)), k)          # ... and one BSDF ray per sample
        c_l, c_b = f(x_l) / p_light(x_l), f(x_b) / p_brdf(x_b)
        avg = 0.5 * (c_l + c_b)                                          # the slide's 'average them together'
        mis = (balance_heuristic(p_light(x_l), p_brdf(x_l)) * c_l
               + balance_heuristic(p_brdf(x_b), p_light(x_b)) * c_b)    # Veach's balance heuristic
        out[f"mis.{label}_exact"] = _exact(1 - cmax ** (k + 2))
        out[f"mis.{label}_avg"] = _est(avg)
        out[f"mis.{label}_mis"] = _est(mis)
        for name, x in (("light", c_l), ("bsdf", c_b), ("avg", avg), ("mis", mis)):
            out[f"mis.{label}_var_{name}"] = _var(x)
    return out


def _var(x) -> tuple[float, float]:
    """Sample variance of iid values and its standard error, ``sqrt((m4 - s^4) / n)``."""
    x = np.asarray(x, float)
    d = x - x.mean()
    v = float(np.mean(d * d) * x.size / (x.size - 1))
    return v, float(math.sqrt(max(np.mean(d ** 4) - v * v, 0.0) / x.size))


def _chart_rows(rng):
    """The Rendering Algorithm Chart's rows 'Photon Mapping: yes / no' and 'Finite Element Radiosity: no / no'."""
    from mcvar.experiments.chart import emitter_pixels
    from mcvar.integrators import render
    from mcvar.scene import load_scene
    scene, res = load_scene("cornell"), 8
    g_ref, g_ph, g_sppm, g_rad = rng.spawn(4)
    ref = render(scene, integrator="path", spp=4096, res=res, rng=g_ref).image
    off = ~emitter_pixels("cornell", res)          # pixels that see the light are left out (as the chart does)

    def mse(options, gg, reps=4):
        return _est([np.mean(((render(scene, res=res, rng=g, **options).image - ref) ** 2)[off])
                     for g in gg.spawn(reps)])
    out = {}
    for lvl, g in zip((1, 16, 64), g_ph.spawn(3)):      # fixed gather radius 40, more photons
        out[f"chart.photon_{lvl}"] = mse(dict(integrator="photon", spp=4, photons=2048 * lvl, radius=40.0), g)
    for lvl, g in zip((1, 16), g_sppm.spawn(2)):        # SPPM: the radius shrinks with the iterations
        out[f"chart.sppm_{lvl}"] = mse(dict(integrator="sppm", spp=lvl, batch_spp=lvl, photons=8192, radius=40.0), g)
    for lvl, g in zip((1, 4, 16), g_rad.spawn(3)):      # radiosity: patch size 280 / sqrt(level)
        root = math.sqrt(lvl)
        out[f"chart.radiosity_{lvl}"] = mse(dict(integrator="radiosity", spp=4 * lvl, patch_size=280.0 / root,
                                                 rays_per_side=int(round(16 * root)), emitter_rays=4096 * lvl), g)
    return out


def _copper(rng):
    """'Copper absorbs some colors, and emits the rest' (Copper Exitant Radiance)."""
    from mcvar import bsdf as B
    cu = B.Conductor.preset("copper")
    out = {}
    for ch, name in enumerate("rgb"):
        out[f"copper.r0_{name}"] = _exact(cu.reflectance[ch])
    return out


def _lambert_directions(rng):
    """'Light is equally likely to be reflected in each output direction' (Lambertian Material)."""
    from mcvar import bsdf as B
    n = 200_000
    wo = np.tile([[0.0, 1.0, 0.0]], (n, 1))
    s = B.Lambertian(0.8).sample(wo, rng.random((n, 2)))      # reflected directions of light from the normal
    cos30 = math.cos(math.radians(30.0))
    return {"lambdir.within30": _est(s.wi[:, 1] > cos30), "lambdir.exact": _exact(0.25),
            "lambdir.solid_angle": _exact(1 - cos30)}


MEASUREMENTS = (_passthrough, _steradians, _diffuse_average, _lambertian_weight, _tir, _eta2, _schlick,
                _envmap_jacobian, _undivided, _rays, _unbiased_consistent, _variance_wording,
                _consistency_definition, _jitter_distance, _n_rooks, _hammersley, _grid_discrepancy,
                _blue_anisotropy, _brdf_pdf, _mirror, _bdpt_point, _mh_darkness, _mis_average, _chart_rows,
                _copper, _lambert_directions)


def measure(seed: int = SEED) -> dict[str, tuple[float, float]]:
    """Every number of the page: ``{key: (value, standard_error)}``, standard error 0 for exact ones."""
    out = {}
    for fn, g in zip(MEASUREMENTS, np.random.SeedSequence(seed).spawn(len(MEASUREMENTS))):
        out.update(fn(np.random.default_rng(g)))
    return out


# ----------------------------------------------------------------------------
# The page
# ----------------------------------------------------------------------------
TEMPLATE = r"""# The slides' slips, measured

The lecture (`brdfs-and-variance-lecture.md`) gets most things right, and the course notebooks
reproduce its claims with numbers. Some sentences of the slides are wrong or say less than they
seem to. This page lists each of them: the slide it is on (a few words quoted), what is right, and
**the number that shows it**, computed by mcvar. Every number below is recomputed by
`tests/test_slips.py` (fixed seeds; Monte Carlo values within a few standard errors, given as
`± stderr`); the page is generated by `docs/slips.py` (`PYTHONPATH=. python docs/slips.py`).
The notebook where the topic is taught ends its lesson with a short *Slips in the slides* cell.

| # | slide | the slip | right | notebook |
|---|---|---|---|---|
| 1 | Types of Reflectance Functions | a BRDF "reflects 85 %" when $f_r = 0.85$ | $f_r = 0.85$ reflects $0.85\pi$ | 03 |
| 2 | Radiometric Description of BRDF | "measured in steradians" | per steradian | 03 |
| 3 | Diffuse Exitant Radiance | a *uniform* hemisphere average | a cosine-weighted average | 03 |
| 4 | Lambertian Material | "pick any outgoing ray" (no number) | cosine sampling's weight is exactly the albedo | 03 |
| 5 | Refractive Material (TIR) | $0 < 1 - (1 - \cos^2\theta) < 1$ | the $(\eta_i/\eta_t)^2$ decides | 03 |
| 6 | Refractive Material | "simply pick the refracted direction" | radiance scales by $(\eta_t/\eta_i)^2$ | 03 |
| 7 | Schlick's Approximation | "$\cos\theta$ is $n \cdot \omega$" inside the glass | the cosine on the less dense side | 03 |
| 8 | Creating A PDF / Importance Sampling | pixel probability as the pdf | a pdf per solid angle | 04 |
| 9 | Importance Sampling (code) | `trace_ray(rf)`, no division | divide by the pdf | 04 |
| 10 | Direct VS Rasterization | "only ever trace one ray" | direct lighting traces shadow rays | 05 |
| 11 | Multiple Importance Sampling | "average them together" | weights that follow the pdfs | 05 |
| 12 | Biased vs. Unbiased Renderer | unbiased "approaches ground truth" | that is consistency | 06 |
| 13 | Variance | "how far from the average, on average" | the *mean squared* distance | 06 |
| 14 | Jittered Sampling | "ensures distance between samples" | no minimum distance at all | 01 |
| 15 | N-Rooks Sampling | "shuffle until rooks condition satisfied" | a permutation always satisfies it | 01 |
| 16 | Bidirectional Path Tracing | unbiased because it does not connect through point sources | it does connect through them | 07 |
| 17 | Metropolis Hasting: Sampling An Image | "relative darkness" | relative brightness | 08 |
| 18 | Rendering Algorithm Chart | photon mapping "consistent: yes" | only as the radius shrinks | 09 |
| 19 | Rendering Algorithm Chart | radiosity "consistent: no" | consistent under mesh refinement | 09 |
| 20 | Copper Exitant Radiance | copper "absorbs some colors, and emits the rest" | it reflects the rest | 03 |
| 21 | Lambertian Material | light "equally likely to be reflected in each output direction" | equal radiance; the directions follow the cosine | 03 |

Rows 1 to 19 are the slips issue 25 lists; 20 and 21 were found on the way. Slips flagged earlier in the
notebooks, with their numbers, are collected [at the end](#flagged-earlier-in-the-notebooks).

## BRDFs and materials (notebook 03)

### 1. 'A BRDF is a passthrough function': $f_r = 0.85$ does not reflect 85 %

**Slide** *Types of Reflectance Functions*: "an incoming ray ... reflects 85% of red ... Written as
$f_r(\mathbf{p}, \omega_i \rightarrow \omega_o) = \langle 0.85, 0.90, 0.50 \rangle$".

**Right.** A BRDF is a density per steradian, not a fraction. The fraction of light a constant BRDF
reflects is its directional albedo $\int_{H^2} f_r \cos\theta_i\,d\omega_i = \pi f_r$: a constant
$f_r = 0.85$ reflects $0.85\pi$ times the incident light, creating energy. Reflecting 85 % takes
$f_r = 0.85/\pi$.

**Measured.** $\int 0.85\cos\theta\,d\omega$ by uniform hemisphere sampling:
[[passthrough.reflected|.3f]] ± [[passthrough.reflected.se|.3f]] (exact $0.85\pi$ = [[passthrough.exact|.4f]]).
The albedo-0.85 Lambertian has $f_r$ = [[passthrough.f_right|.4f]] per sr and `directional_albedo` gives
[[passthrough.lambertian|.4f]].

### 2. 'Measured in steradians': per steradian

**Slide** *Radiometric Description of BRDF*: "$\left[\frac{1}{\text{sr}}\right]$ ... measured in steradians".

**Right.** $f_r = dL_o / dE_i$ has units $\mathrm{sr}^{-1}$: its value depends on the unit of solid
angle the way a density does, and it is measured *per* steradian.

**Measured.** The Lambertian of albedo 0.8 is $f_r$ = [[sr.f_sr|.4f]] per steradian, which is
[[sr.f_deg|.3e]] per square degree (the hemisphere holds [[sr.hemisphere_deg|.1f]] square degrees).
Integrated in square degrees, $\int f_r \cos\theta\,d\omega$ with the per-square-degree value still
gives [[sr.lo_deg|.4f]]: the number changes with the unit, the reflected radiance does not.

### 3. Diffuse exitant radiance is a cosine-weighted average, not a uniform one

**Slide** *Diffuse Exitant Radiance*: "Colors sampled from uniform hemisphere blend all colors into
one average color."

**Right.** $L_o = \frac{\rho}{\pi}\int L_i \cos\theta_i\,d\omega_i$: the average of $L_i$ weighted by
$\cos\theta_i/\pi$. Light near the normal counts more than light near the horizon.

**Measured** (a white Lambertian under a sky $L_i = \cos\theta$, brighter overhead): the exitant
radiance, estimated with the Lambertian's own sampler, is [[diffuse.cosine|.4f]] ± [[diffuse.cosine.se|.4f]]
(exact $2/3$ = [[diffuse.exact_cosine|.4f]]); the uniform hemisphere average of the same field is
[[diffuse.uniform|.4f]] ± [[diffuse.uniform.se|.4f]] (exact [[diffuse.exact_uniform|.4f]]).

### 4. 'Pick any outgoing ray': cosine sampling's weight is exactly the albedo

**Slide** *Lambertian Material*: "Easy! Pick any outgoing ray $w_o$".

**Right, and the number.** With $f_r = \rho/\pi$ and the cosine pdf $\cos\theta/\pi$, every sample's
weight $f_r\cos\theta/p$ equals $\rho$: a zero-variance estimate of the albedo whatever the direction.

**Measured.** Over 100 000 cosine samples of `Lambertian(0.8)`, the largest $|$weight $- 0.8|$ is
[[lambert.max_dev|.1f]].

### 5. The TIR derivation drops $(\eta_i/\eta_t)^2$

**Slide** *Refractive Material*: "We know that $0 < \cos^2\theta < 1$ and so $0 < 1 - (1 - \cos^2\theta) < 1$.
But if $\eta_i/\eta_t > 1$ then it is possible that ... $< 0$".

**Right.** The middle inequality has lost the factor: the expression is
$1 - (\eta_i/\eta_t)^2 (1 - \cos^2\theta_i)$, negative exactly when $\sin\theta_i > \eta_t/\eta_i$.
Without the factor it is $\cos^2\theta_i \ge 0$ and there is never total internal reflection.

**Measured** (directions uniform over the hemisphere inside glass, $\eta = 1.5$, through
`mcvar.optics.refract`): a fraction [[tir.fraction|.4f]] ± [[tir.fraction.se|.4f]] is totally reflected
(exact $\cos\theta_c$ = [[tir.exact|.4f]], critical angle [[tir.critical|.2f]] degrees); the slide's
expression is negative for a fraction [[tir.dropped_negative|.1f]] of them.

### 6. Refraction changes radiance by $(\eta_t/\eta_i)^2$

**Slide** *Refractive Material*: "BRDF represented by dirac delta ... All radiance gets reflected,
nothing absorbed ... Simply pick the refracted direction!"

**Right.** Refraction squeezes a cone of directions into a smaller one
($d\omega_t = (\eta_i/\eta_t)^2 \frac{\cos\theta_i}{\cos\theta_t}\,d\omega_i$), so the transmitted
radiance is $L_t = (1 - F)\,(\eta_t/\eta_i)^2\,L_i$. (Renderers may transport $L/\eta^2$, which is
conserved, instead; `mcvar.bsdf` does, and says so.)

**Measured** by refracting a small cone of directions into glass ($\eta = 1.5$) and comparing the
solid angles: at normal incidence $L_t/L_i$ = [[eta2.radiance_0|.4f]], the Fresnel transmittance
[[eta2.transmit_0|.4f]] times $(\eta_t/\eta_i)^2$ = [[eta2.exact|.4f]]; at 45 degrees
[[eta2.radiance_45|.4f]] = [[eta2.transmit_45|.4f]] times the same factor.

### 7. Schlick with the cosine inside the dense medium misses total internal reflection

**Slide** *Schlick's Approximation*: "$R(\theta) = R_0 + (1 - R_0)(1 - \cos\theta)^5$ ... $\cos\theta$ is the
same as $n \cdot \omega$".

**Right.** Going from glass to air, Schlick's formula must use the cosine of the angle on the less
dense side (the transmitted one), and $R = 1$ beyond the critical angle.

**Measured** (glass to air, beyond the critical angle, where the exact Fresnel reflectance is 1):
with the cosine inside the glass, Schlick gives [[schlick.at45|.4f]] at 45 degrees; its largest error
there is [[schlick.max_err|.4f]] and its mean error (over the angle) [[schlick.mean_err|.4f]].
`mcvar.optics.fresnel_schlick`, with the transmitted cosine, errs by [[schlick.mcvar_err|.1f]] there. Below the
critical angle, where the exact reflectance climbs to 1, the incident cosine errs by up to
[[schlick.below_inside|.4f]] and the transmitted one by up to [[schlick.below_mcvar|.4f]].

### 20. Copper reflects the colours it does not absorb; it emits nothing

**Slide** *Copper Exitant Radiance*: "Copper absorbs some colors, and emits the rest, giving it a 'warm
brown' color."

**Right.** A metal emits no light (no $L_e$ at these temperatures): it *reflects* the rest, with a Fresnel
reflectance that depends on the wavelength.

**Measured** (`Conductor.preset("copper")`, Johnson and Christy's indices at 659.5, 548.6 and 450.9 nm):
the reflectance at normal incidence is [[copper.r0_r|.4f]] (R), [[copper.r0_g|.4f]] (G),
[[copper.r0_b|.4f]] (B); the remainder is absorbed.

### 21. A Lambertian surface does not send light equally in every direction

**Slide** *Lambertian Material*: "Light is equally likely to be reflected in each output direction".

**Right.** The reflected *radiance* is the same in every direction; the reflected *light* (flux per solid
angle) falls with $\cos\theta_o$, so directions near the normal are more likely.

**Measured** (directions of light reflected by `Lambertian(0.8)`, 200 000 samples): a fraction
[[lambdir.within30|.4f]] ± [[lambdir.within30.se|.4f]] leaves within 30 degrees of the normal
($\sin^2 30°$ = [[lambdir.exact|.4f]]), while that cone holds only [[lambdir.solid_angle|.4f]] of the
hemisphere's solid angle.

## Environment lighting (notebook 04)

### 8. The pixel probability is not a pdf per solid angle

**Slides** *Creating A PDF* ("Solid angle is $\sin\theta\,d\theta\,d\phi$ ... Simplifies to $L\sin\theta$")
and *Importance Sampling* ("Divide contribution by PDF of selected pixel").

**Right.** A direction drawn by picking pixel $(i, j)$ with probability $P_{ij}$ has the density
$P_{ij}/\Omega_{ij}$ per steradian ($\Omega_{ij}$ the pixel's solid angle; with a uniform point in the
image square, $P_{ij} HW / (2\pi^2 \sin\theta)$): the estimator divides by that, not by $P_{ij}$.
And the $\sin\theta$ in $P_{ij}$ must be there: without it the samples crowd the poles.

**Measured** on a 32 x 64 map. Chi-square of the samples against the per-solid-angle pdf
(`mcvar.testing.chi2_test`, [[env.dof|.0f]] degrees of freedom), as $\chi^2/\mathrm{dof}$:
[[env.chi2_right|.3f]] ± [[env.chi2_right.se|.3f]] with $P \propto L\sin\theta$, and
[[env.chi2_wrong|.1f]] ± [[env.chi2_wrong.se|.1f]] with $P \propto L$ (the $\sin\theta$ left out).
Estimating $\int L\,d\omega$ = [[env.integral|.4f]]: dividing by the pdf per steradian gives
[[env.divided_pdf|.4f]], dividing by the pixel probability gives [[env.divided_pixel|.1f]] ± [[env.divided_pixel.se|.1f]].

### 9. The importance-sampling code never divides by the pdf

**Slide** *Importance Sampling* (the code): `ray rf = ray_from_index(i); trace_ray(rf);`. The bullet
list says "Divide contribution by PDF of selected pixel"; the code does not.

**Measured** (irradiance of an upward surface under `sky_with_sun()`, luminance, 200 000 importance
samples): exact [[undiv.exact|.4f]]; divided by the pdf [[undiv.divided|.4f]] ± [[undiv.divided.se|.4f]];
undivided, as the code does, [[undiv.undivided|.1f]] ± [[undiv.undivided.se|.1f]].

## Rendering (notebook 05)

### 10. Direct lighting traces more than one ray

**Slide** *Direct VS Rasterization*: "Both rasterization and direct illumination only ever trace
**one ray!**"

**Right.** Rasterization finds the first hit (one ray per sample); direct illumination also asks
whether the light is visible from it: a shadow ray per hit, and with MIS a BSDF ray as well.

**Measured** (`render(...).rays` per camera sample on the Cornell box, 16 x 16, 4 spp): `raster`
[[rays.raster|.2f]], `direct_light` [[rays.direct_light|.3f]] ± [[rays.direct_light.se|.3f]],
`direct` (MIS) [[rays.direct|.3f]] ± [[rays.direct.se|.3f]] (camera rays that leave the box trace nothing more).

### 11. MIS does not average the two rays

**Slide** *Multiple Importance Sampling*: "MIS allows us to take both rays and average them together".

**Right.** Averaging the light-sampled and the BSDF-sampled estimates is unbiased but keeps a quarter
of each strategy's variance, $(V_L + V_B)/4$: half the worse one's standard deviation survives. MIS weights each sample by how likely *each*
strategy was to produce it (balance heuristic $w_k = p_k / \sum_l p_l$), which is what removes the noise.

**Measured** (direct light at a glossy point: a light filling a cone about the normal, a Phong lobe
about it; one light ray and one BSDF ray per sample; variance per sample):

| case | exact | average | MIS (balance) | var light | var BSDF | var average | var MIS |
|---|---|---|---|---|---|---|---|
| sharp lobe ($k = 200$), big light (30°) | [[mis.a_exact|.4f]] | [[mis.a_avg|.4f]] ± [[mis.a_avg.se|.4f]] | [[mis.a_mis|.4f]] ± [[mis.a_mis.se|.4f]] | [[mis.a_var_light|.3g]] ± [[mis.a_var_light.se|.2g]] | [[mis.a_var_bsdf|.3e]] | [[mis.a_var_avg|.3g]] ± [[mis.a_var_avg.se|.2g]] | [[mis.a_var_mis|.4f]] ± [[mis.a_var_mis.se|.4f]] |
| rough lobe ($k = 5$), small light (2°) | [[mis.b_exact|.4e]] | [[mis.b_avg|.3e]] ± [[mis.b_avg.se|.1e]] | [[mis.b_mis|.4e]] ± [[mis.b_mis.se|.1e]] | [[mis.b_var_light|.3e]] | [[mis.b_var_bsdf|.3e]] ± [[mis.b_var_bsdf.se|.1e]] | [[mis.b_var_avg|.3e]] ± [[mis.b_var_avg.se|.1e]] | [[mis.b_var_mis|.3e]] ± [[mis.b_var_mis.se|.1e]] |

## Bias, consistency and variance (notebook 06)

### 12. 'Approaches ground truth with infinite sampling' is consistency, not unbiasedness

**Slide** *Biased vs. Unbiased Renderer*: "An unbiased renderer ... Approaches ground truth with
infinite sampling".

**Right.** Unbiased means correct *on average* at every sample count; approaching the truth is
consistency. Neither implies the other.

**Measured** on the lecture's own examples. The single-sample estimator of the checkerboard
(*Consistent Or Unbiased?* 2) is unbiased: mean [[unb.single_mean|.3f]] ± [[unb.single_mean.se|.3f]]
over 2000 runs ($I = 2$), but its root-mean-square error is [[unb.single_rmse|.3f]] however long it runs.
The fixed $m \times m$ grid on the quarter disk (*Consistent Or Unbiased?* 1) is biased at every $m$
and consistent: bias [[unb.grid_8|.3e]] at $m = 8$, [[unb.grid_64|.3e]] at $m = 64$,
[[unb.grid_512|.3e]] at $m = 512$.

### 13. Variance is the mean *squared* distance from the average

**Slide** *Variance*: "Variance is how far we are from the average, on average".

**Right.** "How far from the average, on average" is the mean absolute deviation $E|X - EX|$;
the variance is $E[(X - EX)^2]$, in squared units, and its square root (the standard deviation) is the
error scale.

**Measured.** The uniform estimator's contribution on the checkerboard is 0 or 4: it is
[[var.board_mad|.0f]] from its average on average, and its variance is [[var.board_var|.0f]]. For $U$
uniform on $[0, 1)$ (a million samples): $E|U - 1/2|$ = [[var.u_mad|.4f]] ± [[var.u_mad.se|.4f]],
variance [[var.u_var|.4f]] ± [[var.u_var.se|.4f]], standard deviation [[var.u_sd|.4f]].

## Samplers (notebook 01)

### 14. Jittering does not ensure any distance between samples

**Slide** *Jittered Sampling*: "Ensures distance between samples, but not enough!"

**Right.** Two points in neighbouring cells can be arbitrarily close: jittering bounds the gaps
(every cell holds a point), not the distances. A minimum distance is what Poisson-disk (blue-noise)
sampling guarantees.

**Measured** (256 points, 200 sets each; distances in units of the cell side $1/16$): the smallest
distance between two points of a set is on average [[jit.jittered_min|.3f]] ± [[jit.jittered_min.se|.3f]]
for jittered points, [[jit.random_min|.4f]] ± [[jit.random_min.se|.4f]] for random ones and
[[jit.blue_noise_min|.3f]] ± [[jit.blue_noise_min.se|.4f]] for blue noise; a fraction
[[jit.jittered_p01|.3f]] ± [[jit.jittered_p01.se|.3f]] of the jittered sets has two points closer than a
tenth of a cell ([[jit.random_p01|.3f]] ± [[jit.random_p01.se|.3f]] of the random sets,
[[jit.blue_noise_p01|.1f]] of the blue-noise ones).

### 15. 'Shuffle until the rooks condition is satisfied': one shuffle always satisfies it

**Slide** *N-Rooks Sampling*: "All samples start on the diagonal, randomly shuffle (x, y) coordinates
until rooks condition satisfied ... Possibility of not terminating".

**Right.** The diagonal holds each row and each column once; shuffling the x coordinates among the
points permutes the columns, and a permutation holds each column once again. The first shuffle always
works: there is nothing to retry and no risk of not terminating. (Drawing each column at random
instead would succeed with probability $n!/n^n$.)

**Measured** ($n = 16$): the fraction of 10 000 shuffles of the diagonal that satisfy the rooks
condition is [[rooks.shuffle_ok|.4f]]; of 1000 sets of `mcvar.samplers.n_rooks`, [[rooks.mcvar_ok|.4f]];
a random column per point succeeds with probability [[rooks.random_columns|.3e]].

## Light transport (notebooks 07 to 09)

### 16. BDPT connects through point sources, and is unbiased

**Slide** *Bidirectional Path Tracing*: "Unbiased algorithm - No longer trying to connect rays through
non-volume sources".

**Right.** BDPT's strategies *do* connect to point lights (the $s = 1$ light vertex) and to the pinhole
($t = 1$); what makes it unbiased is that every strategy divides by its pdf and the MIS weights of the
strategies that can make a path sum to 1. Connecting is how point sources are seen at all.

**Measured** on `cornell-point` (a point light; 16 x 16, 8 replicates of 4 spp): BDPT's image mean
(luminance) is [[bdpt.mean|.4f]] ± [[bdpt.mean.se|.4f]], light tracing's (which connects every vertex
to the pinhole) [[bdpt.light_mean|.4f]] ± [[bdpt.light_mean.se|.4f]]: $z$ = [[bdpt.z|.2f]]. A path tracer
that never connects (`path_bsdf`) renders the room [[bdpt.path_bsdf|.1f]] everywhere.

### 17. Metropolis moves towards *brightness*

**Slide** *Metropolis Hasting: Sampling An Image*: "Transition probability is 'relative darkness'
$f(x')/f(x_i)$".

**Right.** The acceptance $\min(1, f(x')/f(x_i))$ is the relative *brightness* of the proposal: a
brighter proposal is always taken, and the walk spends its time in proportion to $f$.

**Measured** (`mcvar.mcmc.image_walk` on an image whose left half is 10 times brighter than its right;
64 chains of 4000 steps): the walk spends a fraction [[mh.bright|.4f]] ± [[mh.bright.se|.4f]] of its
time in the bright half ($1/1.1$ = [[mh.exact|.4f]]). Accepting by relative darkness, $f(x_i)/f(x')$,
puts it in the bright half [[mh.dark|.4f]] ± [[mh.dark.se|.4f]] of the time ([[mh.exact_dark|.4f]]).

### 18. Photon mapping is consistent only as the radius shrinks

**Slide** *Rendering Algorithm Chart*: "Photon Mapping: consistent? yes; unbiased? no".

**Right.** With a fixed gather radius the density estimate averages the irradiance over a disk: a
blur that no number of photons removes, so plain photon mapping is *not* consistent. Progressive
photon mapping (SPPM) shrinks the radius as photons accumulate, and that is consistent.

**Measured** (Cornell box, 8 x 8, MSE against a 4096-spp path-traced reference, pixels that see the
light left out, 4 replicates): fixed radius 40, with 2048 x 1, 16 and 64 photons:
[[chart.photon_1|.2e]] ± [[chart.photon_1.se|.1e]], [[chart.photon_16|.2e]] ± [[chart.photon_16.se|.1e]],
[[chart.photon_64|.2e]] ± [[chart.photon_64.se|.1e]]; SPPM after 1 and 16 iterations:
[[chart.sppm_1|.2e]] ± [[chart.sppm_1.se|.1e]], [[chart.sppm_16|.2e]] ± [[chart.sppm_16.se|.1e]].
`mcvar chart` ([the chart, measured](chart.md)) runs the bias and consistency tests on every method.

### 19. Finite-element radiosity is consistent under mesh refinement

**Slide** *Rendering Algorithm Chart*: "Finite Element Radiosity: consistent? no; unbiased? no".

**Right.** Radiosity (on a diffuse scene) is biased at any fixed mesh, but the error falls as the mesh
is refined (with the form-factor rays): it is consistent in that knob.

**Measured** (same setting; patch size $280/\sqrt{\ell}$ at levels $\ell$ = 1, 4, 16):
[[chart.radiosity_1|.2e]] ± [[chart.radiosity_1.se|.1e]], [[chart.radiosity_4|.2e]] ± [[chart.radiosity_4.se|.1e]],
[[chart.radiosity_16|.2e]] ± [[chart.radiosity_16.se|.1e]].

## Flagged earlier in the notebooks

| slide | slip | the number | notebook |
|---|---|---|---|
| Hammersley Sampling | "$1101 \Rightarrow 0.1011 = ... = 11/16 = 0.6975$" | $\Phi_2(13)$ = [[ham.phi13|.4f]] | 01 |
| Low-Discrepancy Sampling | "A uniform grid has the lowest discrepancy" | star discrepancy at $n = 256$: grid [[grid.star|.4f]], Sobol' [[grid.sobol|.4f]] | 01 |
| Blue Noise | "No preferred directions (anisotropic)" | it is *isotropic*: anisotropy [[blue.aniso|.2f]] ± [[blue.aniso.se|.2f]] (1 = isotropic), grid [[blue.grid_aniso|.1f]] | 01 |
| Reflectance Functions | "Represented as a Probability Distribution Function" | $\int f_r\,d\omega$ of the albedo-0.8 Lambertian = [[pdf.int_f|.4f]], not 1 | 03 |
| Dirac Delta Distribution | mirror $f_r = \langle 1.0, 1.0, 1.0 \rangle$ | $f_r = 1$ in a cone of 0.1 degrees reflects [[mirror.cone|.2e]] | 03 |
| Bias & Consistency | $\lim P(\lvert I - \hat I_n \rvert > 0) = 0$ | plain MC on the board: $P$ = [[cdef.p0|.4f]] at $n = 1024$ (tends to 1) | 02, 06 |
| Path Tracing Can Be Biased | connecting to the light "biases our renderer" | measured unbiased in notebook 05 (NEE divides by its pdf) | 05 |
"""


def _scaled(key: str, values: dict) -> tuple[float, float]:
    """Value and standard error of a placeholder key (``name`` or ``name.se``)."""
    if key.endswith(".se"):
        return values[key[:-3]][1], 0.0
    return values[key]


def render(values: dict) -> str:
    """The page with every placeholder filled from ``values`` (:func:`measure`)."""
    return _PLACEHOLDER.sub(lambda m: format(_scaled(m.group(1), values)[0], m.group(2)), TEMPLATE)


def placeholders() -> list[tuple[str, str]]:
    """``(key, format)`` of every number on the page, in order."""
    return _PLACEHOLDER.findall(TEMPLATE)


def parse(page: str) -> list[tuple[str, str]]:
    """The numbers a page states, ``[(key, printed text)]`` in order.

    Raises ``ValueError`` if any text outside the placeholders differs from :data:`TEMPLATE`.
    """
    parts = _PLACEHOLDER.split(TEMPLATE)
    static = parts[::3]
    pattern = _NUMBER.join(re.escape(s) for s in static)
    m = re.fullmatch(pattern, page, flags=re.DOTALL)
    if m is None:
        raise ValueError("the page's text differs from docs/slips.py's TEMPLATE: regenerate it "
                         "(PYTHONPATH=. python docs/slips.py)")
    return list(zip(parts[1::3], m.groups()))


def write(values: dict | None = None) -> Path:
    PAGE.write_text(render(measure() if values is None else values))
    return PAGE


if __name__ == "__main__":
    import time
    t = time.perf_counter()
    print(write(), f"({time.perf_counter() - t:.1f} s)", file=sys.stderr)
