"""The ``neuras-distill`` command. Argument parsing only; the work lives in the library.

Exit codes: 0 success, 2 bad input (one line on stderr saying what and how to fix), 1 internal error.
Heavy modules are imported inside the commands so ``--help`` stays fast.
"""

from __future__ import annotations

import argparse
import sys

DEFAULT_SCENE = "bunny"


def _add_run_options(p: argparse.ArgumentParser, default_out: str | None = None) -> None:
    p.add_argument("--out", default=default_out, help="run folder (default: runs/<scene>)")
    p.add_argument("--preset", default=None, help="settings preset: object (default), fast, quality")
    p.add_argument("--config", default=None, help="TOML file overriding settings (see configs/)")
    p.add_argument("--face-budget", type=int, default=None, help="maximum faces after decimation")
    p.add_argument("--steps", type=int, default=None, help="distillation steps")
    p.add_argument("--texture-resolution", type=int, default=None, help="side of the feature atlas in texels")
    p.add_argument("--view-dependence", choices=["auto", "on", "off"], default=None,
                   help="view-direction input of the shader (auto: decided from the field)")
    p.add_argument("--quiet", action="store_true", help="no progress output")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="neuras-distill",
        description="Turn a trained radiance field into a mesh + neural texture bundle that OpenGL plays in "
                    "real time, and prove it (FPS before/after, error against the field).")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("demo", help="the embedded default scene through the whole pipeline")
    p.add_argument("--kind", choices=["sdf", "density"], default="sdf", help="field type of the scene")
    _add_run_options(p)

    p = sub.add_parser("from-synthetic", help="an embedded synthetic scene through the whole pipeline")
    p.add_argument("name", help="scene name (bunny, sphere, torus)")
    p.add_argument("--kind", choices=["sdf", "density"], default="sdf", help="field type of the scene")
    _add_run_options(p)

    p = sub.add_parser("view", help="play a bundle: render an orbit to PNG frames (headless)")
    p.add_argument("bundle", help="bundle folder (runs/<scene>/bundle)")
    p.add_argument("--orbit", action="store_true", help="render an orbit around the bundle to PNG frames")
    p.add_argument("--frames", type=int, default=36, help="frames in the orbit")
    p.add_argument("--width", type=int, default=512)
    p.add_argument("--height", type=int, default=512)
    p.add_argument("--out", default=None, help="folder for the frames (default: <bundle>/../orbit)")
    return parser


def _config_from_args(args):
    from .config import load_config

    overrides: dict = {}
    if args.face_budget is not None:
        overrides.setdefault("geometry", {})["face_budget"] = args.face_budget
    if args.steps is not None:
        overrides.setdefault("train", {})["steps"] = args.steps
    if args.texture_resolution is not None:
        overrides.setdefault("texture", {})["resolution"] = args.texture_resolution
    if args.view_dependence is not None:
        overrides.setdefault("texture", {})["view_dependence"] = args.view_dependence
    return load_config(preset=args.preset, path=args.config, overrides=overrides)


def _run_scene(args, name: str) -> int:
    from .fields.synthetic import make_scene
    from .pipeline.run import distill
    from .pipeline.rundir import check_output_folder
    from pathlib import Path

    cfg = _config_from_args(args)
    out = Path(args.out or f"runs/{name}" + ("" if args.kind == "sdf" else f"-{args.kind}"))
    check_output_folder(out.resolve())  # fail before any work
    field = make_scene(name, kind=args.kind)
    distill(field, None, cfg, out, progress=not args.quiet,
            log=(lambda m: None) if args.quiet else None)
    return 0


def _view(args) -> int:
    from pathlib import Path

    from .errors import require
    from .bake.bundle import load_bundle
    from .playback.viewer import render_orbit_frames

    bundle = load_bundle(args.bundle)
    require(args.frames >= 1, "--frames must be at least 1")
    out = Path(args.out) if args.out else Path(args.bundle).resolve().parent / "orbit"
    paths = render_orbit_frames(bundle, out, frames=args.frames, width=args.width, height=args.height)
    print(f"wrote {len(paths)} frames to {out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from .errors import BadInputError

    try:
        if args.command == "demo":
            return _run_scene(args, DEFAULT_SCENE)
        if args.command == "from-synthetic":
            return _run_scene(args, args.name)
        if args.command == "view":
            return _view(args)
    except BadInputError as exc:
        print(f"neuras-distill: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("neuras-distill: interrupted; nothing was written", file=sys.stderr)
        return 130
    except Exception as exc:  # an internal error: show the traceback for the bug report
        from .playback.context import GLUnavailable

        if isinstance(exc, GLUnavailable):
            print(f"neuras-distill: error: {exc}", file=sys.stderr)
            return 2
        import traceback

        traceback.print_exc()
        print(f"neuras-distill: internal error: {exc} (please report it with the traceback above)",
              file=sys.stderr)
        return 1
    return 1


if __name__ == "__main__":
    sys.exit(main())
