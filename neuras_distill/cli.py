"""The ``neuras-distill`` command. Argument parsing only; the work lives in the library.

Exit codes: 0 success, 2 bad input (one line on stderr saying what and how to fix), 1 internal error.
Heavy modules are imported inside the commands so ``--help`` stays fast.
"""

from __future__ import annotations

import sys
from pathlib import Path

from .cli_parser import EXPORT_FORMAT_NAMES, build_parser
from .logs import install_cli_handler, say
from .run_inputs import RUN_COMMANDS, nerfstudio_run, parse_box, parse_int, run_inputs


def _default_out(args) -> Path:
    if args.command in ("demo", "from-synthetic"):
        from .scenes.synthetic import DEFAULT_SCENE

        name = DEFAULT_SCENE if args.command == "demo" else args.name
        return Path(f"runs/{name}" + ("" if args.kind in (None, "sdf") else f"-{args.kind}"))
    if args.command == "from-nerfstudio":
        run = Path(nerfstudio_run(args)).resolve()
        folder = run if run.is_dir() else run.parent              # outputs/<scene>/<method>/<timestamp>
        return Path(f"runs/{folder.parent.parent.name or folder.name or 'nerfstudio'}-{folder.parent.name}")
    return Path(f"runs/{Path(args.snapshot if args.command == 'from-ngp' else args.checkpoint).stem or 'field'}")


def _distill_command(args) -> int:
    from pathlib import Path

    from .device import resolve_device
    from .errors import BadInputError
    from .pipeline.parallel import check_nproc
    from .pipeline.run import distill
    from .pipeline.rundir import check_output_folder
    from .pipeline.torchrun import agree, join_group, launch_from_env

    out = Path(args.out) if args.out else _default_out(args)
    check_output_folder(out.resolve())  # fail before any work
    resolve_device(args.device)
    check_nproc(args.nproc)              # before any work: a bad --nproc is one line, nothing written
    launch = launch_from_env()
    if launch is None:
        field, cameras, cfg = run_inputs(args)
    else:                                # every rank hears of a rank that cannot load its inputs
        join_group(launch, args.device)
        try:
            field, cameras, cfg = run_inputs(args)
        except BadInputError as exc:
            agree(launch, {}, error=str(exc))
            raise
    if getattr(args, "cameras_said", None):
        say(args.cameras_said)
    distill(field, cameras, cfg, out, progress=not args.quiet,
            fresh=args.fresh, keep_work=args.keep_work, source=_source(args), device=args.device,
            nproc=args.nproc)
    return 0


def _bench(args) -> int:
    from .bench import bench
    from .bench.run import parse_resolutions

    resolutions = parse_resolutions(args.resolutions)
    variants = None if args.variants is None else [v.strip() for v in args.variants.split(",") if v.strip()]
    bench(args.run, resolutions=resolutions, variants=variants, target_ms=args.target_ms,
          progress=not args.quiet, log=say)
    return 0


def _check(args) -> int:
    import json
    from pathlib import Path

    from .config import load_config
    from .stability.probe import probe_field
    from .stability.source import load_source

    options: dict = {}
    if args.latent_view is not None:
        options["latent_view"] = args.latent_view if args.latent_view == "mean" else parse_int(args.latent_view,
                                                                                          "--latent-view")
    if args.foreground_box is not None:
        options["foreground_box"] = parse_box(args.foreground_box)
    if args.image_size is not None:
        w, _, h = args.image_size.lower().partition("x")
        options["width"], options["height"] = parse_int(w, "--image-size"), parse_int(h, "--image-size")
    if args.model_config is not None:
        options["config"] = args.model_config
    if args.density is not None:
        options["density"] = args.density
    field, cameras = load_source(args.source, kind=args.kind, cameras_path=args.cameras, options=options)
    preset = args.preset
    if preset is None:
        preset = getattr(field, "preset", None)          # as from-synthetic: the scene's own preset
    cfg = load_config(preset=preset, path=args.config)
    report = probe_field(field, cameras, samples=args.samples, rays=args.rays, num_steps=cfg.teacher.num_steps,
                         grid_resolution=cfg.geometry.grid_resolution, source=args.source)
    print(report.to_table())
    if args.json:
        out = Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(report.to_json(), indent=2))
    if report.verdict == "refused":
        print(f"neuras-distill: error: {args.source} cannot be distilled: {report.reason()}", file=sys.stderr)
        return 2
    return 0


def _view(args) -> int:
    from pathlib import Path

    from .bake.bundle import load_bundle
    from .errors import require

    bundle = load_bundle(args.bundle)
    if args.orbit:
        from .playback.viewer import render_orbit_frames

        require(args.frames >= 1, "--frames must be at least 1")
        out = Path(args.out) if args.out else Path(args.bundle).resolve().parent / "orbit"
        paths = render_orbit_frames(bundle, out, frames=args.frames, width=args.width, height=args.height)
        print(f"wrote {len(paths)} frames to {out}")
        return 0
    from .playback.viewer import start_cameras
    from .playback.window import play_in_window

    cameras, source = start_cameras(bundle, args.bundle)
    shot = play_in_window(bundle, cameras, args.camera, mode=args.mode, skybox=not args.no_skybox,
                          screenshot=args.screenshot, title=f"neuras-distill {Path(args.bundle).resolve().parent.name}")
    if shot is not None:
        print(f"wrote {shot} ({source} {args.camera}, mode {args.mode})")
    return 0


def _render(args) -> int:
    from .bake.bundle import load_bundle
    from .path_video import bundle_location, compare_field, frames_along, path_cameras, write_frames

    bundle_path, run = bundle_location(args.bundle)
    bundle = load_bundle(bundle_path)
    seen = path_cameras(bundle, bundle_path, run, camera_path=args.camera_path, orbit=args.orbit,
                        path_frame=args.path_frame, dataparser=args.dataparser_transforms, width=args.width,
                        height=args.height, fps=args.fps)
    say(f"cameras: {seen.said}")
    field = compare_field(args.compare) if args.compare else None
    wrote = write_frames(frames_along(bundle, seen.cameras, field), args.out, seen.fps)
    what = "field | bundle" if field is not None else "the bundle"
    print(f"wrote {wrote['path']}: {wrote['frames']} frames of {what}, {wrote['width']}x{wrote['height']} at "
          f"{wrote['fps']:g} fps" + (f", {wrote['codec']} {wrote['pixel_format']}" if "codec" in wrote else ""))
    return 0


def _max_texture_size(args) -> int:
    """``export --max-texture-size`` as a positive int (``export/texture_limit.py``'s default when not given)."""
    from .errors import require
    from .export.texture_limit import DEFAULT_MAX_TEXTURE_SIZE

    if args.max_texture_size is None:
        return DEFAULT_MAX_TEXTURE_SIZE
    n = parse_int(args.max_texture_size, "--max-texture-size")
    require(n >= 1, f"--max-texture-size must be at least 1 texel, got {n}")
    return n


def _up_said(args) -> str:
    """Which up an export turned onto +Y (``export/gltf_up.resolve_up``), for its closing line."""
    from .export.gltf_up import resolve_up

    return resolve_up(args.up, args.bundle)[1]


def _export_gltf(args) -> int:
    from .export.gltf import export_gltf

    out = export_gltf(args.bundle, args.out, _max_texture_size(args), args.up)
    print(f"wrote {out} ({out.stat().st_size} bytes; up {_up_said(args)} turned onto glTF's +Y)")
    return 0


def _export_web(args) -> int:
    from .export.web import export_web

    out = export_web(args.bundle, args.out, _max_texture_size(args))
    print(f"wrote {out} (play it with `neuras-distill serve {out}`)")
    return 0


def _export_threejs(args) -> int:
    from .errors import BadInputError
    from .export.threejs import export_threejs

    if not args.three:
        raise BadInputError("--format threejs needs --three THREE_DIR: the three.js package to copy "
                            "(node_modules/three of a local `npm install three`)")
    out, version = export_threejs(args.bundle, args.out, args.three, _max_texture_size(args), args.up)
    print(f"wrote {out} with three.js {version}, up {_up_said(args)} "
          f"(play it with `neuras-distill serve {out}`)")
    return 0


def _export_3dtiles(args) -> int:
    from .errors import BadInputError
    from .export.tiles_page import export_3dtiles

    if not args.three or not args.tiles_renderer:
        raise BadInputError("--format 3dtiles needs --three THREE_DIR and --tiles-renderer TILES_DIR: the packages "
                            "to copy (node_modules/three and node_modules/3d-tiles-renderer of a local `npm install "
                            "three 3d-tiles-renderer`)")
    out, versions = export_3dtiles(args.bundle, args.out, args.three, args.tiles_renderer, args.cesium)
    cesium = f" and CesiumJS {versions['cesium']} (cesium.html)" if "cesium" in versions else ""
    print(f"wrote {out} with three.js {versions['three']}, 3DTilesRendererJS {versions['3d-tiles-renderer']}{cesium} "
          f"(play it with `neuras-distill serve {out}`)")
    return 0


#: ``export --format`` values and their writers (each raises BadInputError for bad input, writes atomically).
EXPORT_FORMATS = {"gltf": _export_gltf, "web": _export_web, "threejs": _export_threejs, "3dtiles": _export_3dtiles}
assert tuple(EXPORT_FORMATS) == EXPORT_FORMAT_NAMES


def _export(args) -> int:
    from .errors import BadInputError

    writer = EXPORT_FORMATS.get(args.format)
    if writer is None:
        raise BadInputError(f"unknown --format {args.format!r}; known formats: {', '.join(EXPORT_FORMATS)}")
    return writer(args)


def _serve(args) -> int:
    from .export.serve import serve

    try:
        serve(args.dir, port=parse_int(args.port, "--port"), open_browser=not args.no_open,
              ready=lambda url: print(f"serving {args.dir} at {url} (Ctrl-C stops)", flush=True))
    except KeyboardInterrupt:
        print(f"stopped serving {args.dir}")
    return 0


def _source(args) -> dict:
    """``report["source"]``: this command line and the folder it ran in (relative paths are relative to it)."""
    import os

    return {"command": ["neuras-distill", *getattr(args, "argv", [])], "cwd": os.getcwd()}


def main(argv: list[str] | None = None) -> int:
    """The command line; returns the exit code. A rank of a torchrun / srun launch ends its process here
    (``parallel.exit_rank``: gloo's threads can abort the interpreter's shutdown)."""
    code = _main(argv)
    from .errors import BadInputError
    from .pipeline.torchrun import launch_from_env

    try:
        launched = launch_from_env() is not None
    except BadInputError:            # a broken launch environment: _main said so, and no group was formed
        launched = False
    if launched:
        from .pipeline.parallel import exit_rank

        exit_rank(code)
    return code


def _main(argv: list[str] | None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    args.argv = argv
    install_cli_handler("quiet" if getattr(args, "quiet", False) else
                        "verbose" if getattr(args, "verbose", False) else "normal")
    from .errors import BadInputError

    try:
        if args.command in RUN_COMMANDS:
            return _distill_command(args)
        if args.command == "bench":
            return _bench(args)
        if args.command == "view":
            return _view(args)
        if args.command == "render":
            return _render(args)
        if args.command == "check":
            return _check(args)
        if args.command == "export":
            return _export(args)
        if args.command == "serve":
            return _serve(args)
        if args.command == "tiles":
            from .tiles.commands import COMMANDS as TILE_COMMANDS

            return TILE_COMMANDS[args.tiles_command](args)
    except BadInputError as exc:
        print(f"neuras-distill: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("neuras-distill: interrupted; no run folder was written (finished stages, if any, are kept for the "
              "same command to reuse)", file=sys.stderr)
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
