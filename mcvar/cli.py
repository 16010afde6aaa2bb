"""The ``mcvar`` command (layer 7).

Subcommands::

    mcvar samplers  --n 256 --out DIR        every sampler's points, spectra, discrepancy vs n
    mcvar render    cornell --spp 64 ...     one image, .npy (linear), .png (sRGB) or .exr
    mcvar converge  TARGET --out DIR         variance / bias / MSE / efficiency vs spp report
    mcvar converge  --target MOD:FUNC ...    the same for your own renderer's evaluate function
    mcvar demo      [--out DIR]              the default Cornell-box convergence report
    mcvar chart     --out DIR [--quick]      the lecture's rendering-methods chart, measured
    mcvar compare   --scenes A,B --methods m1,m2 --seconds T   every method on every scene at equal time

Each subcommand parses its options and calls one library function; all the
work (and its validation) lives in the library so notebooks and tests use the
same code.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from . import __version__


def _int_list(text: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from exc
    if not values:
        raise argparse.ArgumentTypeError("expected at least one integer")
    return values


def _name_list(text: str) -> list[str]:
    values = [v.strip() for v in text.split(",") if v.strip()]
    if not values:
        raise argparse.ArgumentTypeError("expected at least one name")
    return values


def _cmd_samplers(args) -> int:
    from .sampler_report import write_samplers_report

    paths = write_samplers_report(args.out, n=args.n, n_max=args.n_max, rng=args.seed,
                                  progress=not args.quiet)
    for key, path in paths.items():
        print(f"{key}: {path}")
    return 0


def _cmd_render(args) -> int:
    from .images import write_image
    from .integrators import render
    from .integrators.registry import get_method, pop_method_name
    from .scene import load_scene

    name = pop_method_name({} if args.integrator is None else {"integrator": args.integrator}, args.method,
                           "mcvar render (--method, --integrator)")
    method = get_method(name)
    options = {}
    if args.strategies is not None:
        if method.name != "bdpt":
            raise ValueError("--strategies writes the (s, t) strategy images of bidirectional path tracing: "
                             f"it needs --method bdpt, not {method.name!r}")
        options["strategies"] = True
    scene = load_scene(args.scene)
    _scene_file_defaults(args, scene, method.name)
    out = Path(args.out)
    if out.is_dir():
        raise ValueError(f"--out must name an image file (.npy, .png, .exr, .hdr); {str(out)!r} is a directory")
    # estimator options of the path methods, only when asked for (other methods do not take them)
    tuning = {k: v for k, v in (("visible_lights", args.visible_lights), ("rr_threshold", args.rr_threshold),
                                ("rr_depth", args.rr_depth), ("caustics", args.caustics),
                                ("glass_splits", args.glass_splits), ("reuse", args.reuse)) if v is not None}
    common = dict(method=method.name, spp=args.spp, res=args.res, sampler=args.sampler, rng=args.seed,
                  max_depth=args.max_depth, heuristic=args.heuristic, progress=not args.quiet)
    if _adaptive_default(args, method):
        from .adaptive import adaptive_settings

        # the most efficient unbiased configuration (docs/performance.md)
        result = render(scene, allocation="adaptive", workers=_adaptive_workers(args.workers),
                        **common, **{**adaptive_settings(method), **tuning})
    else:
        result = render(scene, batch_spp=args.batch_spp,
                        workers=1 if args.workers is None else args.workers, **common, **options, **tuning)
    path = write_image(args.out, result.image)
    note = " (interrupted: image holds the spp finished)" if result.interrupted else ""
    print(f"wrote {path}: {result.image.shape[1]}x{result.image.shape[0]}, "
          f"{result.spp} spp in {result.seconds:.2f} s{note}")
    if args.strategies is not None:
        from .integrators.bdpt import strategies_from_extra, write_strategies

        written = write_strategies(args.strategies, strategies_from_extra(result.extra, result.res), result.res)
        print(f"wrote {len(written) - 1} strategy images (s{{s}}_t{{t}}.npy) and {written[-1]}")
    return 0


def _scene_file_defaults(args, scene, method: str) -> None:
    """Fill the options the command line left out (None) from what a scene file says
    (``Scene.render_defaults``: film size, sample count, path depth, roulette depth),
    else the built-in defaults (64 x 64 pixels, 16 spp)."""
    from .integrators import METHODS

    given = dict(scene.render_defaults)
    if args.res is None:
        args.res = given.get("res", 64)
    if args.spp is None:
        args.spp = given.get("spp", 16)
    if args.max_depth is None and method in ("path", "path_bsdf", "light", "bdpt"):
        args.max_depth = given.get("max_depth")
    method = METHODS.get(method)
    if args.rr_depth is None and "rr_depth" in given and method is not None and "rr_depth" in method.options:
        args.rr_depth = given["rr_depth"]


def _usable_cpus() -> int:
    """CPUs this process may run on: its affinity mask (``taskset``, a container's
    cpuset), not the machine's count, where the platform tells."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _adaptive_workers(workers):
    """Processes of an adaptive render: ``workers``, or by default two (the caller and
    one pool process) when this process may run on two CPUs or more, else one.

    The rule, measured (docs/performance.md, 'Both cores under load'): on two
    cores two workers took 0.62-0.89x one worker's time in seven of eight
    conditions (load 3-12, with zero to two busy loops added; the scheduler
    shares by process, and the caller takes batches the pool has not
    started), and 1.30x in one, at a load average the load cannot tell from
    a 0.62x case, so the load average is not consulted. On one usable CPU a
    second process only time-shares it.
    """
    return min(2, _usable_cpus()) if workers is None else workers


def _adaptive_default(args, method) -> bool:
    """``mcvar render`` renders with ``allocation='adaptive'`` unless ``--uniform``,
    a method that is not camera-kind, ``--batch-spp``, a square-only sampler
    or fewer than 16 spp (the pilot would be too small to allocate by) say
    otherwise."""
    return (not args.uniform and method.kind == "camera" and args.batch_spp is None
            and not _square_sampler(args.sampler) and args.spp >= 16)


def _square_sampler(name: str) -> bool:
    from .samplers import SAMPLERS

    return name in SAMPLERS and SAMPLERS[name].square


def _cmd_converge(args) -> int:
    from .report import convergence_report

    if (args.target is None) == (args.target_spec is None):
        raise ValueError("give a target: a name (cornell, checkerboard, ...) or --target module:function, "
                         "not both")
    if args.target_spec is not None:
        from .experiments import load_target

        target = load_target(args.target_spec)
    else:
        target = args.target
    methods, res = args.methods, args.res
    if args.target_spec is None and target.lower().endswith(".xml"):
        # a scene file: its film width and path depth unless --res / --methods say otherwise
        from .scene import load_scene

        given = load_scene(target).render_defaults
        res = given.get("res", (32, 32))[0] if res is None else res
        if methods is None and given.get("max_depth") is not None:
            methods = [f"path:{given['max_depth']}"]
    paths = convergence_report(target, args.out, methods=methods, samplers=args.samplers,
                               spp=args.spp, replicates=args.replicates, res=32 if res is None else res,
                               rng=args.seed, workers=args.workers, progress=not args.quiet,
                               reference=args.reference)
    for key, path in paths.items():
        print(f"{key}: {path}")
    return 0


def _cmd_demo(args) -> int:
    from .demo import demo

    paths = demo(args.out, progress=not args.quiet)
    if not args.no_best:
        from .adaptive import render_adaptive
        from .images import write_image
        from .scene import load_scene

        # the Cornell box once more, with the most efficient unbiased configuration
        r = render_adaptive(load_scene("cornell"), spp=256, res=64, sampler="sobol", rng=1,
                            workers=_adaptive_workers(None), progress=not args.quiet)
        Path(args.out).mkdir(parents=True, exist_ok=True)
        paths["best"] = write_image(Path(args.out) / "cornell-best.png", r.image)
        print(f"cornell-best.png: 64x64, adaptive Sobol, {r.spp} spp on average in {r.seconds:.2f} s")
    for key, path in paths.items():
        print(f"{key}: {path}")
    return 0


def _cmd_chart(args) -> int:
    from .chart_report import chart_report

    paths = chart_report(args.out, quick=args.quick, methods=args.methods, rng=args.seed,
                         workers=args.workers, progress=not args.quiet,
                         command="mcvar " + " ".join(sys.argv[1:]))
    for key, path in paths.items():
        print(f"{key}: {path}")
    return 0


def _cmd_compare(args) -> int:
    from .compare_report import compare_report

    paths = compare_report(args.out, scenes=args.scenes, methods=args.methods, seconds=args.seconds, res=args.res,
                           seeds=args.seeds, seed=args.seed, progress=not args.quiet, pairs=args.pairs,
                           command="mcvar " + " ".join(sys.argv[1:]))
    for key, path in paths.items():
        print(f"{key}: {path}")
    return 0


class _RegistryHelp(str):
    """A help text naming the registered methods, filled in only when help is shown
    (argparse formats help with ``%``): building the parser imports no integrator."""

    def __new__(cls, template: str, what: str):
        obj = super().__new__(cls, template)
        obj.what = what
        return obj

    def __mod__(self, params):
        if self.what == "samplers":
            from .samplers import SAMPLERS

            names = ", ".join(SAMPLERS)
        elif self.what == "rows":
            from .experiments.chart import chart_methods

            names = ", ".join(chart_methods())
        elif self.what == "scenes":
            from .scene import SCENES

            names = ", ".join(SCENES)
        else:
            from .integrators import METHODS

            names = ", ".join(METHODS)
        return str.__mod__(str(self).replace("{" + self.what + "}", names.replace("%", "%%")), params)


def _add_compare_parser(sub, quiet) -> None:
    """The ``mcvar compare`` subcommand (issue 21)."""
    p = sub.add_parser("compare", parents=[quiet], help="every method on every scene at equal wall time",
                       description="Render every method on every scene for the same wall time (rounds of "
                                   "spp until --seconds are spent), compare each image with one shared "
                                   "high-spp reference per scene (cached in OUT/.cache), and write "
                                   "compare.csv (median spp, seconds, MSE, efficiency 1 / (MSE x time) over "
                                   "the seeds), compare.png (methods x scenes, the winner of each column "
                                   "framed) and compare.html. Ctrl-C writes the cells finished so far.")
    p.add_argument("--scenes", type=_name_list, default=None,
                   help=_RegistryHelp("comma-separated scenes: {scenes} (default the scenes of issue 21: "
                                      "cornell,cornell-point,cornell-door,cornell-caustic,veach-mis, "
                                      "mcvar.experiments.compare.DEFAULT_SCENES)", "scenes"))
    p.add_argument("--methods", type=_name_list, default=None,
                   help=_RegistryHelp("comma-separated registered methods: {methods} (default every "
                                      "registered light-transport method, the AOVs and rasterization left "
                                      "out: mcvar.experiments.compare.default_methods())", "methods"))
    p.add_argument("--seconds", type=float, default=2.0, help="wall time per method, scene and seed (default 2)")
    p.add_argument("--res", type=int, default=32, help="image width and height in pixels (default 32)")
    p.add_argument("--seeds", type=int, default=3, help="independent runs per cell; medians reported (default 3)")
    p.add_argument("--seed", type=int, default=0, help="root seed (default 0)")
    p.add_argument("--pairs", action="store_true",
                   help="also the lecture's pairs at equal time (path / path_bsdf / light at the point light and "
                        "forward tracing without the camera connection, path / bdpt on cornell-caustic's caustic "
                        "and at the point light, path / the Metropolis methods on cornell-door, path / sppm on "
                        "the caustic), BDPT's (s, t) strategy grid on cornell-caustic and radiosity's second "
                        "view from one solve: pairs.csv, strategies.csv, strategies.png, point_light.csv, "
                        "radiosity_views.csv")
    p.add_argument("--out", type=Path, default=Path("out/compare"), help="output folder (default out/compare)")
    p.set_defaults(func=_cmd_compare)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mcvar", description="Monte Carlo estimation and its variance, measured.")
    parser.add_argument("--version", action="version", version=f"mcvar {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    quiet = argparse.ArgumentParser(add_help=False)
    quiet.add_argument("--quiet", action="store_true", help="no progress bars")

    p = sub.add_parser("samplers", parents=[quiet],
                       help="plot every sampler, its spectrum and discrepancy vs n",
                       description="Write a figure of every sampler's points side by side, their "
                                   "power spectra, and discrepancy versus n with fitted slopes "
                                   "(PNG), plus a CSV of the numbers.")
    p.add_argument("--n", type=int, default=256, help="points per sampler in the scatter plots (default 256)")
    p.add_argument("--n-max", type=int, default=4096, help="largest n of the discrepancy sweep (default 4096)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--out", type=Path, default=Path("out/samplers"), help="output folder")
    p.set_defaults(func=_cmd_samplers)

    p = sub.add_parser("render", parents=[quiet], help="render one image of a scene",
                       description="Render a scene with one method and sampler. .npy holds "
                                   "linear radiance (H, W, 3), row 0 at the top; .png is tonemapped "
                                   "to sRGB; .exr is linear. Ctrl-C keeps the spp finished so far.")
    p.add_argument("scene", help="scene name (cornell, cornell-spheres, checkerboard, furnace, quad-environment, "
                                 "...) or a Mitsuba 3 scene file FILE.xml (docs/scene-files.md)")
    p.add_argument("--res", type=int, default=None, help="image width and height in pixels (default 64, or a "
                                                         "scene file's film)")
    p.add_argument("--spp", type=int, default=None, help="samples per pixel (default 16, or a scene file's "
                                                         "sample_count)")
    p.add_argument("--method", default=None,
                   help=_RegistryHelp("rendering method, any of mcvar.integrators.METHODS: {methods} "
                                      "(default path: NEE + MIS)", "methods"))
    p.add_argument("--integrator", default=None, help="alias of --method")
    p.add_argument("--sampler", default="sobol",
                   help=_RegistryHelp("pixel sampler, any of mcvar.samplers.SAMPLERS: {samplers} (default sobol; "
                                      "the previous default was random)", "samplers"))
    p.add_argument("--seed", type=int, default=1, help="random seed: the same seed gives the same image")
    p.add_argument("--max-depth", type=int, default=None,
                   help="maximum path depth (1 = emitters seen directly); default: Russian roulette")
    p.add_argument("--heuristic", default="power", help="MIS heuristic: power or balance")
    p.add_argument("--batch-spp", type=int, default=None, help="spp per batch (bounds memory)")
    p.add_argument("--workers", type=int, default=None,
                   help="processes to spread batches over (default: 2 for adaptive renders, the "
                        "caller and one more; 1 with --uniform, the previous behaviour)")
    p.add_argument("--strategies", type=Path, default=None, metavar="DIR",
                   help="with --method bdpt: write every (s, t) strategy's weighted image of depth <= 4 "
                        "to DIR (s{s}_t{t}.npy, linear) and their grid (strategies.png)")
    p.add_argument("--uniform", action="store_true",
                   help="the same spp in every pixel (the previous behaviour); default for camera-kind "
                        "methods (path, direct, ...) at >= 16 spp: unbiased adaptive sampling (a pilot "
                        "decides where the samples go, docs/performance.md)")
    p.add_argument("--visible-lights", choices=("exact", "sampled"), default=None,
                   help="lights seen directly by the camera: their exact pixel integral plus sampled "
                        "differences (a control variate; default for adaptive renders) or plain sampling "
                        "(default with --uniform)")
    p.add_argument("--caustics", choices=("light", "path"), default=None,
                   help="caustic paths (a diffuse first vertex, the light reached through a specular one): left "
                        "to light tracing where the scene allows it (default for adaptive renders) or found by "
                        "path tracing (default with --uniform)")
    p.add_argument("--glass-splits", type=int, default=None,
                   help="camera rays follow both lobes of glass at their first N glass vertices (default: 1 for "
                        "adaptive renders, 0 with --uniform)")
    p.add_argument("--reuse", type=int, default=None,
                   help="path reuse: camera samples of N neighbouring pixels share their paths from the second "
                        "vertex on, balance-heuristic weighted (unbiased; Lambertian scenes; noise correlated "
                        "within a tile; default: 4 for adaptive renders, 1 (off) with --uniform)")
    p.add_argument("--rr-threshold", type=float, default=None,
                   help="Russian roulette survival max(beta) / THRESHOLD, in (0, 1] (default: 0.2 for "
                        "adaptive renders, a weight window; 1, pbrt's rule, with --uniform)")
    p.add_argument("--rr-depth", type=int, default=None,
                   help="segments before Russian roulette starts (default 3)")
    p.add_argument("--out", type=Path, default=Path("out/render.png"), help=".npy, .png or .exr")
    p.set_defaults(func=_cmd_render)

    p = sub.add_parser("converge", parents=[quiet], help="variance / bias / MSE / efficiency vs spp report",
                       description="Sweep methods x samplers x spp levels x replicates on a scene "
                                   "(cornell, ...) or an integrand (checkerboard, hemisphere, ...) "
                                   "and write plots, a CSV of every number and a summary page.")
    p.add_argument("target", nargs="?", default=None,
                   help="scene (cornell, cornell-spheres, or a Mitsuba 3 FILE.xml) or integrand "
                        "(checkerboard, hemisphere, ...)")
    p.add_argument("--target", dest="target_spec", metavar="MODULE:FUNCTION", default=None,
                   help="your own renderer instead: FUNCTION(method, sampler, spp, rng) -> image in "
                        "MODULE (importable from the current folder); methods from --methods or the "
                        "module's METHODS; reference from --reference, EXACT or reference(rng)")
    p.add_argument("--methods", "--integrators", "--estimators", dest="methods", type=_name_list,
                   default=None, help="comma-separated rendering methods (scenes; 'path:3' stops paths at "
                                      "depth 3, 'path' uses Russian roulette) or the problem's "
                                      "estimators (integrands); default: path,path:2,direct or "
                                      "every estimator (--integrators and --estimators are aliases)")
    p.add_argument("--samplers", type=_name_list, default=None,
                   help=_RegistryHelp("comma-separated sampler names ({samplers}; default "
                                      "random,jittered,sobol)", "samplers"))
    p.add_argument("--spp", type=_int_list, default=None,
                   help="comma-separated spp (or N) levels (default 1,4,16,64 for scenes, "
                        "1,4,...,4096 for integrands)")
    p.add_argument("--replicates", type=int, default=8, help="independent replicates per level (default 8)")
    p.add_argument("--res", type=int, default=None, help="image resolution for scenes (default 32, or a scene "
                                                         "file's film width)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--workers", type=int, default=None, help="processes (default: all cores)")
    p.add_argument("--reference", type=Path, default=None,
                   help="reference to compare with instead of rendering one: .npy image (variance 0) "
                        "or .npz with 'value' and optionally 'variance'")
    p.add_argument("--out", type=Path, default=Path("out/converge"), help="output folder")
    p.set_defaults(func=_cmd_converge)

    p = sub.add_parser("demo", parents=[quiet], help="the default Cornell-box convergence report",
                       description="Render the Cornell box (64 x 64) with path tracing (Russian "
                                   "roulette), path tracing stopped at depth 3 and direct lighting, "
                                   "each with the random, jittered and Sobol samplers at 1, 4, 16 "
                                   "and 64 spp, 6 replicates, and write the convergence report "
                                   "(report.html, CSVs, PNGs). Re-running reuses finished runs.")
    p.add_argument("--out", type=Path, default=Path("demo-report"), help="output folder (default demo-report)")
    p.add_argument("--no-best", action="store_true",
                   help="skip cornell-best.png (64x64, 256 spp, adaptive Sobol: the most efficient unbiased "
                        "configuration, docs/performance.md); the previous behaviour")
    p.set_defaults(func=_cmd_demo)

    p = sub.add_parser("chart", parents=[quiet], help="the lecture's rendering-methods chart, measured",
                       description="Measure the lecture's Rendering Algorithm Chart (consistent? "
                                   "unbiased?) for every registered method on the Cornell box: "
                                   "replicates at increasing levels of each method's accuracy knob, "
                                   "the bias and consistency tests of 'mcvar converge', MSE x time at "
                                   "the largest level. Writes chart.csv, chart.png and chart.html. "
                                   "Re-running reuses finished runs.")
    p.add_argument("--out", type=Path, default=Path("out/chart"), help="output folder (default out/chart)")
    p.add_argument("--quick", action="store_true", help="16 x 16 pixels, 10 replicates (under 2 minutes "
                                                        "for spp methods on 2 cores)")
    p.add_argument("--methods", type=_name_list, default=None,
                   help=_RegistryHelp("comma-separated chart methods ({rows}; 'path_depth3' is an alias of "
                                      "'path:3'); default: every registered one", "rows"))
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--workers", type=int, default=None, help="processes (default: all cores)")
    p.set_defaults(func=_cmd_chart)

    _add_compare_parser(sub, quiet)
    return parser


#: What ``main`` reports as a user's error (one line on stderr, exit status 2):
#: bad values and types (the library's ``ValueError``/``TypeError`` name the
#: argument), files that cannot be read or written (``OSError``: a missing
#: file, ``--out`` naming a directory, no permission, a full disk) and a
#: ``--target`` module that cannot be imported. Anything else (``KeyError``,
#: ``IndexError``, ``MemoryError`` ...) is a bug and keeps its traceback.
USER_ERRORS = (ValueError, TypeError, OSError, ImportError)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except USER_ERRORS as exc:
        print(f"mcvar {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"mcvar {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
