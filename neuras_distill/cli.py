"""The ``neuras-distill`` command. Argument parsing only; the work lives in the library.

Exit codes: 0 success, 2 bad input (one line on stderr saying what and how to fix), 1 internal error.
Heavy modules are imported inside the commands so ``--help`` stays fast.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

DEFAULT_SCENE = "bunny"


def _add_run_options(p: argparse.ArgumentParser, default_out: str | None = None) -> None:
    p.add_argument("--out", default=default_out, help="run folder (default: runs/<scene>)")
    p.add_argument("--preset", default=None, help="settings preset: object (default), fast, quality")
    p.add_argument("--config", default=None, help="TOML file overriding settings (see configs/)")
    p.add_argument("--face-budget", type=int, default=None, help="maximum faces after decimation")
    p.add_argument("--steps", type=int, default=None,
                   help="distillation steps (default 0: planned from the atlas within the time budget)")
    p.add_argument("--texture-resolution", type=int, default=None, help="side of the feature atlas in texels")
    p.add_argument("--view-dependence", choices=["auto", "on", "off"], default=None,
                   help="view-direction input of the shader (auto: decided from the field)")
    p.add_argument("--eval-width", type=int, default=None,
                   help="width of the held-out frames that are timed and compared (0: the cameras' own size)")
    p.add_argument("--skyboxes", choices=["auto", "on", "off"], default=None,
                   help="neural skyboxes for what lies beyond the mesh (auto: decided from the field and cameras)")
    p.add_argument("--fresh", action="store_true",
                   help="ignore the stages stored by an earlier or killed run into the same --out (recompute all)")
    p.add_argument("--no-keep-work", dest="keep_work", action="store_false",
                   help="remove the work area (stored stages, G-buffers) after success instead of keeping it in "
                        "<out>/work for the next run into the same folder")
    p.add_argument("--device", default="auto", metavar="DEVICE",
                   help="where the field, the teacher and training compute: auto (a GPU when torch sees one), "
                        "cpu, cuda or cuda:N (default auto; the bundle is played by OpenGL)")
    p.add_argument("--precision", choices=["fp32", "fp16"], default=None,
                   help="field evaluation precision (default fp32; fp16: half hash-grid tables and MLPs with "
                        "float32 compositing, as Instant-NGP evaluates: for GPUs)")
    p.add_argument("--nproc", default=1, metavar="N",
                   help="processes that share the teacher's volume rendering on the CPU (default 1: this one "
                        "alone; N spawns N-1 workers that each hold a copy of the field)")
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
    p.add_argument("name",
                   help="scene name (bunny, bunny-matte, sphere, torus, street, gradient-ball, city, city-small)")
    p.add_argument("--kind", choices=["sdf", "density"], default=None,
                   help="field type of the scene (default: the scene's own, sdf; density for gradient-ball)")
    _add_run_options(p)

    p = sub.add_parser("from-ngp", help="an Instant-NGP snapshot (.ingp / .msgpack) through the whole pipeline")
    p.add_argument("snapshot", help="the snapshot instant-ngp saved (--save_snapshot)")
    p.add_argument("--cameras", default=None,
                   help="transforms.json to train and evaluate on (default: the cameras stored in the snapshot)")
    p.add_argument("--foreground-box", default=None, metavar="X0,Y0,Z0,X1,Y1,Z1",
                   help="world box (transforms.json frame) holding the foreground (default: the snapshot's "
                        "render box, or its occupied cells)")
    p.add_argument("--latent-view", default="0",
                   help="training image whose appearance latent is rendered (default 0, as instant-ngp), or 'mean'")
    _add_run_options(p)

    p = sub.add_parser("from-nerfstudio", help="a nerfstudio nerfacto run (config.yml) through the whole pipeline")
    p.add_argument("run", help="the run's config.yml or its folder (outputs/<scene>/nerfacto/<timestamp>)")
    p.add_argument("--cameras", default=None,
                   help="the dataset's transforms.json (nerfstudio stores no cameras; default: an orbit around "
                        "the foreground box)")
    p.add_argument("--foreground-box", default=None, metavar="X0,Y0,Z0,X1,Y1,Z1",
                   help="box in the dataset's frame holding the foreground (default: where the density is)")
    p.add_argument("--appearance", default="mean",
                   help="appearance embedding: mean (nerfstudio's evaluation, default), zeros, or a training "
                        "image's index")
    p.add_argument("--image-size", default=None, metavar="WxH",
                   help="image size of an ns-export cameras file given to --cameras (it stores poses only)")
    p.add_argument("--focal", type=float, default=None, metavar="PIXELS",
                   help="focal length in pixels of an ns-export cameras file given to --cameras")
    _add_run_options(p)

    p = sub.add_parser("from-sdf", help="a NeuS / hash-grid NeuS checkpoint (.pth / .ckpt) through the pipeline")
    p.add_argument("checkpoint", help="NeuS ckpt_XXXXXX.pth or instant-nsr-pl .ckpt")
    p.add_argument("--cameras", default=None,
                   help="NeuS cameras_sphere.npz (also sets the world frame) or a transforms.json")
    p.add_argument("--image-size", default=None, metavar="WxH",
                   help="image size of the cameras_sphere.npz views (it does not store one)")
    p.add_argument("--model-config", default=None,
                   help="instant-nsr-pl parsed.yaml of the run (grid and network sizes)")
    p.add_argument("--density", choices=["neus", "laplace"], default="neus",
                   help="SDF to opacity: NeuS logistic (default) or VolSDF Laplace")
    _add_run_options(p)

    p = sub.add_parser("check", help="probe a field for stiff and extreme cases before distilling it")
    p.add_argument("source", help="checkpoint path (.ingp / .msgpack / .pth / .ckpt), synthetic:NAME or extreme:NAME")
    p.add_argument("--kind", choices=["sdf", "density"], default=None, help="synthetic scenes: field type")
    p.add_argument("--cameras", default=None,
                   help="transforms.json or NeuS cameras_sphere.npz (as from-ngp / from-sdf)")
    p.add_argument("--foreground-box", default=None, metavar="X0,Y0,Z0,X1,Y1,Z1", help="as from-ngp")
    p.add_argument("--latent-view", default=None, help="as from-ngp")
    p.add_argument("--image-size", default=None, metavar="WxH", help="as from-sdf")
    p.add_argument("--model-config", default=None, help="as from-sdf (instant-nsr-pl parsed.yaml)")
    p.add_argument("--density", choices=["neus", "laplace"], default=None, help="as from-sdf")
    p.add_argument("--preset", default=None, help="settings preset the adaptations are relative to")
    p.add_argument("--config", default=None, help="TOML settings the adaptations are relative to")
    p.add_argument("--samples", type=int, default=64, help="probe lattice points per axis (default 64)")
    p.add_argument("--rays", type=int, default=512, help="probe rays (default 512)")
    p.add_argument("--json", default=None, metavar="PATH", help="also write the report as JSON")

    p = sub.add_parser("view", help="play a bundle in a window (orbit, pan, zoom, fly; keys switch what is shown), "
                                     "or render an orbit to PNG frames headless (--orbit)")
    p.add_argument("bundle", help="bundle folder (runs/<scene>/bundle) or .glb; the window starts at the first "
                                  "held-out camera of the run's cameras.json beside it")
    p.add_argument("--orbit", action="store_true", help="render an orbit around the bundle to PNG frames "
                                                        "(headless, no window)")
    p.add_argument("--frames", type=int, default=36, help="--orbit: frames in the orbit")
    p.add_argument("--width", type=int, default=512, help="--orbit: frame width")
    p.add_argument("--height", type=int, default=512, help="--orbit: frame height")
    p.add_argument("--out", default=None, help="--orbit: folder for the frames (default: <bundle>/../orbit)")
    p.add_argument("--screenshot", default=None, metavar="PATH",
                   help="window: draw a few frames at the start camera, save the window as PNG and exit")
    p.add_argument("--camera", type=int, default=0, help="window: held-out camera to start at (default 0)")
    p.add_argument("--mode", default="neural", metavar="MODE",
                   help="window: what to show first: neural, plain, uv or index (keys 1-4 switch)")
    p.add_argument("--no-skybox", action="store_true", help="window: start with the skybox pass off (key K)")

    p = sub.add_parser("bench", help="error against run time for a finished run: the field at several step "
                                        "counts, the plain-texture floor and bundle variants distilled from the "
                                        "run's stored stages, with the Pareto front (writes RUN_DIR/bench/)")
    p.add_argument("run", metavar="RUN_DIR", help="a run folder (the --out of demo / from-synthetic / from-ngp / "
                                                  "from-sdf)")
    p.add_argument("--resolutions", default="640x360,1920x1080", metavar="WxH,...",
                   help="frame sizes to score and time at (the held-out cameras' aspect ratio; default "
                        "640x360,1920x1080)")
    p.add_argument("--variants", default=None, metavar="NAME,...",
                   help="bundle variants to distil (default all: atlas-half, atlas-double, mlp-8, mlp-32, "
                        "mlp-two-hidden, no-view, no-vq, faces-quarter, faces-half)")
    p.add_argument("--target-ms", type=float, default=None,
                   help="frame time the recommendation aims at (default 16.7 ms, 60 Hz)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")

    p = sub.add_parser("export", help="write a bundle in a format other tools open (gltf: one .glb file; "
                                         "web: a static folder that plays it in a browser)")
    p.add_argument("bundle", help="bundle folder (runs/<scene>/bundle)")
    p.add_argument("--format", required=True, metavar="FORMAT",
                   help=f"output format: {', '.join(EXPORT_FORMATS)} (gltf: glTF 2.0 binary, the mesh with its "
                        "plain RGB texture, unlit, plus the whole neural bundle inside; load_bundle reads it; web: "
                        "index.html + WebGL2 player + data, the same shaders in GLSL ES 3.00; view it with "
                        "`python -m http.server` inside the folder, index.html?camera=N plays held-out camera N)")
    p.add_argument("--out", required=True, help="output file or folder (gltf: a .glb path; web: a folder); an "
                                                "existing one is replaced only when neuras-distill wrote it")
    p.add_argument("--max-texture-size", default=None, metavar="N",
                   help="largest texture side the export writes, in texels (default 4096, a side WebGL2 browsers "
                        "hold in practice): a codebook is wrapped into more codes per row to fit; an atlas page above "
                        "it exits 2 (bake with a smaller texture.page_size, or raise N for a target that holds it)")
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
    if args.eval_width is not None:
        overrides.setdefault("eval", {})["width"] = args.eval_width
    if args.skyboxes is not None:
        overrides.setdefault("skybox", {})["mode"] = args.skyboxes
    if getattr(args, "precision", None) is not None:
        overrides.setdefault("teacher", {})["precision"] = args.precision
    return load_config(preset=args.preset, path=args.config, overrides=overrides)


def _scene_inputs(args, name: str) -> tuple:
    from .scenes.synthetic import make_scene

    field = make_scene(name, kind=args.kind)
    if args.preset is None:       # a scene may name the preset that fits it (street); --config FILE goes on top
        args.preset = getattr(field, "preset", None)
    return field, None, _config_from_args(args)


def _parse_box(text: str):
    from .errors import BadInputError

    try:
        v = [float(t) for t in text.replace(" ", "").split(",")]
    except ValueError:
        v = []
    if len(v) != 6:
        raise BadInputError(f"--foreground-box must be six numbers X0,Y0,Z0,X1,Y1,Z1, got {text!r}")
    return [v[:3], v[3:]]


def _checkpoint_inputs(args, path: str, adapter: str, options: dict) -> tuple:
    from pathlib import Path

    from .errors import require
    from .registry import load_field
    from .render.cameras import Cameras

    cfg = _config_from_args(args)
    src = Path(path)
    cameras = None
    cam_path = getattr(args, "cameras", None)
    if cam_path is not None:
        cam_file = Path(cam_path)
        require(cam_file.is_file(), f"--cameras {cam_path}: no such file")
        if cam_file.suffix.lower() == ".json":
            cameras = Cameras.from_transforms(cam_file)
    field = load_field(src, adapter=adapter, **options)
    if cameras is None and getattr(field, "cameras", None) is None and cam_path is None:
        require(callable(getattr(field, "default_cameras", None)),
                f"{src} stores no cameras; pass --cameras transforms.json")
    return field, cameras, cfg


def _ngp_inputs(args) -> tuple:
    options = {"latent_view": args.latent_view if args.latent_view == "mean" else _int(args.latent_view,
                                                                                        "--latent-view")}
    if args.foreground_box is not None:
        options["foreground_box"] = _parse_box(args.foreground_box)
    return _checkpoint_inputs(args, args.snapshot, "instant_ngp", options)


def _sdf_inputs(args) -> tuple:
    from pathlib import Path

    options: dict = {"density": args.density}
    if args.cameras is not None and Path(args.cameras).suffix.lower() != ".json":
        options["cameras"] = args.cameras
    if args.image_size is not None:
        w, _, h = args.image_size.lower().partition("x")
        options["width"], options["height"] = _int(w, "--image-size"), _int(h, "--image-size")
    if args.model_config is not None:
        options["config"] = args.model_config
    return _checkpoint_inputs(args, args.checkpoint, "neus", options)


def _nerfstudio_inputs(args) -> tuple:
    from pathlib import Path

    run = Path(args.run)
    options: dict = {"appearance": args.appearance if args.appearance in ("mean", "zeros")
                     else _int(args.appearance, "--appearance")}
    if args.foreground_box is not None:
        options["foreground_box"] = _parse_box(args.foreground_box)
    exported = args.cameras if args.cameras is not None and _is_json_list(args.cameras) else None
    if exported is not None:            # ns-export poses (nerfstudio's frame): the loaded field moves them
        args.cameras = None
    field, cameras, cfg = _checkpoint_inputs(args, str(run / "config.yml" if run.is_dir() else run), "nerfstudio",
                                             options)
    if cameras is not None and exported is None:     # the dataset's transforms.json: the cameras as trained
        import json

        names = [str(f.get("file_path", "")) for f in json.loads(Path(args.cameras).read_text())["frames"]]
        cameras, count = field.corrected_cameras(cameras, names)
        if count:
            field.notes.append(f"the camera optimizer's pose corrections applied to {count} training cameras")
    if exported is not None:
        args.cameras = exported
        width = height = None
        if args.image_size is not None:
            w, _, h = args.image_size.lower().partition("x")
            width, height = _int(w, "--image-size"), _int(h, "--image-size")
        cameras = field.exported_cameras(exported, width, height, args.focal)
    return field, cameras, cfg


def _is_json_list(path) -> bool:
    """Whether ``path`` is a JSON file holding a list (``ns-export cameras`` output, not a transforms.json)."""
    import json

    try:
        return isinstance(json.loads(Path(path).read_text()), list)
    except (OSError, ValueError, UnicodeDecodeError):
        return False


#: The commands that run the pipeline, and how each builds its (field, cameras or None, config).
RUN_COMMANDS = {"demo": lambda a: _scene_inputs(a, DEFAULT_SCENE), "from-synthetic": lambda a: _scene_inputs(a, a.name),
                "from-ngp": _ngp_inputs, "from-sdf": _sdf_inputs, "from-nerfstudio": _nerfstudio_inputs}


def run_inputs(args) -> tuple:
    """(field, cameras or None, DistillConfig) of a parsed run command (``RUN_COMMANDS``): what it distills.
    The bench rebuilds a run's field from the command its report recorded (``report["source"]``)."""
    return RUN_COMMANDS[args.command](args)


def _default_out(args) -> Path:
    if args.command in ("demo", "from-synthetic"):
        name = DEFAULT_SCENE if args.command == "demo" else args.name
        return Path(f"runs/{name}" + ("" if args.kind in (None, "sdf") else f"-{args.kind}"))
    if args.command == "from-nerfstudio":
        run = Path(args.run).resolve()
        folder = run if run.is_dir() else run.parent              # outputs/<scene>/<method>/<timestamp>
        return Path(f"runs/{folder.parent.parent.name or folder.name or 'nerfstudio'}-{folder.parent.name}")
    return Path(f"runs/{Path(args.snapshot if args.command == 'from-ngp' else args.checkpoint).stem or 'field'}")


def _distill_command(args) -> int:
    from pathlib import Path

    from .device import resolve_device
    from .parallel import check_nproc
    from .pipeline.run import distill
    from .pipeline.rundir import check_output_folder

    out = Path(args.out) if args.out else _default_out(args)
    check_output_folder(out.resolve())  # fail before any work
    resolve_device(args.device)
    check_nproc(args.nproc)              # before any work: a bad --nproc is one line, nothing written
    field, cameras, cfg = run_inputs(args)
    distill(field, cameras, cfg, out, progress=not args.quiet, log=(lambda m: None) if args.quiet else None,
            fresh=args.fresh, keep_work=args.keep_work, source=_source(args), device=args.device,
            nproc=args.nproc)
    return 0


def _bench(args) -> int:
    from .bench import bench
    from .bench.run import parse_resolutions

    resolutions = parse_resolutions(args.resolutions)
    variants = None if args.variants is None else [v.strip() for v in args.variants.split(",") if v.strip()]
    bench(args.run, resolutions=resolutions, variants=variants, target_ms=args.target_ms,
          progress=not args.quiet, log=(lambda m: None) if args.quiet else print)
    return 0


def _int(text: str, flag: str) -> int:
    from .errors import BadInputError

    try:
        return int(text)
    except ValueError:
        raise BadInputError(f"{flag} must be an integer, got {text!r}") from None


def _check(args) -> int:
    import json
    from pathlib import Path

    from .config import load_config
    from .stability.probe import probe_field
    from .stability.source import load_source

    options: dict = {}
    if args.latent_view is not None:
        options["latent_view"] = args.latent_view if args.latent_view == "mean" else _int(args.latent_view,
                                                                                          "--latent-view")
    if args.foreground_box is not None:
        options["foreground_box"] = _parse_box(args.foreground_box)
    if args.image_size is not None:
        w, _, h = args.image_size.lower().partition("x")
        options["width"], options["height"] = _int(w, "--image-size"), _int(h, "--image-size")
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


def _max_texture_size(args) -> int:
    """``export --max-texture-size`` as a positive int (``bake/texture_limit.py``'s default when not given)."""
    from .bake.texture_limit import DEFAULT_MAX_TEXTURE_SIZE
    from .errors import require

    if args.max_texture_size is None:
        return DEFAULT_MAX_TEXTURE_SIZE
    n = _int(args.max_texture_size, "--max-texture-size")
    require(n >= 1, f"--max-texture-size must be at least 1 texel, got {n}")
    return n


def _export_gltf(args) -> int:
    from .bake.gltf import export_gltf

    out = export_gltf(args.bundle, args.out, _max_texture_size(args))
    print(f"wrote {out} ({out.stat().st_size} bytes)")
    return 0


def _export_web(args) -> int:
    from .bake.web import export_web

    out = export_web(args.bundle, args.out, _max_texture_size(args))
    print(f"wrote {out} (serve it with `python -m http.server` inside it, open index.html)")
    return 0


#: ``export --format`` values and their writers (each raises BadInputError for bad input, writes atomically).
EXPORT_FORMATS = {"gltf": _export_gltf, "web": _export_web}


def _export(args) -> int:
    from .errors import BadInputError

    writer = EXPORT_FORMATS.get(args.format)
    if writer is None:
        raise BadInputError(f"unknown --format {args.format!r}; known formats: {', '.join(EXPORT_FORMATS)}")
    return writer(args)


def _source(args) -> dict:
    """``report["source"]``: this command line and the folder it ran in (relative paths are relative to it)."""
    import os

    return {"command": ["neuras-distill", *getattr(args, "argv", [])], "cwd": os.getcwd()}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    args.argv = argv
    from .errors import BadInputError

    try:
        if args.command in RUN_COMMANDS:
            return _distill_command(args)
        if args.command == "bench":
            return _bench(args)
        if args.command == "view":
            return _view(args)
        if args.command == "check":
            return _check(args)
        if args.command == "export":
            return _export(args)
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
