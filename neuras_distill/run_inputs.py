"""What a run command distills: the (field, cameras or None, config) that ``demo``, ``from-synthetic``,
``from-ngp``, ``from-sdf`` and ``from-nerfstudio`` build from their parsed arguments (:func:`run_inputs`). The
command line and the bench (which rebuilds a run's field from the command its report recorded) both resolve a
source here.
"""

from __future__ import annotations

from pathlib import Path


def _config_from_args(args):
    from .config import load_config

    overrides: dict = {}
    if args.face_budget is not None:
        overrides.setdefault("geometry", {})["face_budget"] = args.face_budget
    if args.steps is not None:
        overrides.setdefault("train", {})["steps"] = args.steps
    if getattr(args, "time_budget", None) is not None:
        overrides.setdefault("train", {})["run_budget_s"] = args.time_budget
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


def _scene_inputs(args, name: str | None) -> tuple:
    """A synthetic scene (``name`` None: the demo's, ``scenes.synthetic.DEFAULT_SCENE``)."""
    from .scenes.synthetic import DEFAULT_SCENE, make_scene

    field = make_scene(name or DEFAULT_SCENE, kind=args.kind)
    if args.preset is None:       # a scene may name the preset that fits it (street); --config FILE goes on top
        args.preset = getattr(field, "preset", None)
    return field, None, _config_from_args(args)


def parse_box(text: str):
    from .errors import BadInputError

    try:
        v = [float(t) for t in text.replace(" ", "").split(",")]
    except ValueError:
        v = []
    if len(v) != 6:
        raise BadInputError(f"--foreground-box must be six numbers X0,Y0,Z0,X1,Y1,Z1, got {text!r}")
    return [v[:3], v[3:]]


def cameras_option(cam_path: str | None):
    """The ``Cameras`` of a ``--cameras`` transforms.json; None without the option, or for another kind of file
    (a NeuS cameras_sphere.npz, which its adapter reads). A missing file is refused."""
    from .errors import require
    from .render.cameras import Cameras

    if cam_path is None:
        return None
    cam_file = Path(cam_path)
    require(cam_file.is_file(), f"--cameras {cam_path}: no such file")
    return Cameras.from_transforms(cam_file) if cam_file.suffix.lower() == ".json" else None


def _checkpoint_inputs(args, path: str, adapter: str, options: dict) -> tuple:
    from .errors import require
    from .registry import load_field

    cfg = _config_from_args(args)
    src = Path(path)
    cam_path = getattr(args, "cameras", None)
    cameras = cameras_option(cam_path)
    field = load_field(src, adapter=adapter, **options)
    if cameras is None and getattr(field, "cameras", None) is None and cam_path is None:
        require(callable(getattr(field, "default_cameras", None)),
                f"{src} stores no cameras; pass --cameras transforms.json")
    return field, cameras, cfg


def _ngp_inputs(args) -> tuple:
    options = {"latent_view": args.latent_view if args.latent_view == "mean" else parse_int(args.latent_view,
                                                                                        "--latent-view")}
    if args.foreground_box is not None:
        options["foreground_box"] = parse_box(args.foreground_box)
    return _checkpoint_inputs(args, args.snapshot, "instant_ngp", options)


def _sdf_inputs(args) -> tuple:
    from pathlib import Path

    options: dict = {"density": args.density}
    if args.cameras is not None and Path(args.cameras).suffix.lower() != ".json":
        options["cameras"] = args.cameras
    if args.image_size is not None:
        w, _, h = args.image_size.lower().partition("x")
        options["width"], options["height"] = parse_int(w, "--image-size"), parse_int(h, "--image-size")
    if args.model_config is not None:
        options["config"] = args.model_config
    return _checkpoint_inputs(args, args.checkpoint, "neus", options)


def nerfstudio_run(args) -> str:
    """The run ``from-nerfstudio`` reads: RUN or ``--load-config`` (nerfstudio's name for it); one of them."""
    from .errors import BadInputError

    given = [v for v in (args.run, getattr(args, "load_config", None)) if v is not None]
    if not given:
        raise BadInputError("from-nerfstudio needs the run: its config.yml as RUN or --load-config CONFIG")
    if len(given) == 2 and Path(given[0]).resolve() != Path(given[1]).resolve():
        raise BadInputError(f"RUN {given[0]} and --load-config {given[1]} name different runs: give one")
    return given[0]


def _nerfstudio_inputs(args) -> tuple:
    from pathlib import Path

    run = Path(nerfstudio_run(args))
    options: dict = {"appearance": args.appearance if args.appearance in ("mean", "zeros")
                     else parse_int(args.appearance, "--appearance")}
    if args.foreground_box is not None:
        options["foreground_box"] = parse_box(args.foreground_box)
    exported = args.cameras if args.cameras is not None and _is_json_list(args.cameras) else None
    if exported is not None:            # ns-export poses (nerfstudio's frame): the loaded field moves them
        args.cameras = None
    field, cameras, cfg = _checkpoint_inputs(args, str(run / "config.yml" if run.is_dir() else run), "nerfstudio",
                                             options)
    if args.cameras is None and exported is None:    # nerfstudio's habit: the dataset config.yml names
        found, where = field.dataset_transforms()
        if found is not None:
            args.cameras = str(found)
            cameras = cameras_option(args.cameras)
            args.cameras_said = f"cameras: {found} ({where})"
        else:
            args.cameras_said = (f"cameras: {where}: an orbit around the foreground box instead; give the "
                                 "dataset's transforms.json with --cameras")
        field.notes.append(args.cameras_said)
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
            width, height = parse_int(w, "--image-size"), parse_int(h, "--image-size")
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
RUN_COMMANDS = {"demo": lambda a: _scene_inputs(a, None), "from-synthetic": lambda a: _scene_inputs(a, a.name),
                "from-ngp": _ngp_inputs, "from-sdf": _sdf_inputs, "from-nerfstudio": _nerfstudio_inputs}


def run_inputs(args) -> tuple:
    """(field, cameras or None, DistillConfig) of a parsed run command (``RUN_COMMANDS``): what it distills.
    The bench rebuilds a run's field from the command its report recorded (``report["source"]``)."""
    return RUN_COMMANDS[args.command](args)


def parse_int(text: str, flag: str) -> int:
    from .errors import BadInputError

    try:
        return int(text)
    except ValueError:
        raise BadInputError(f"{flag} must be an integer, got {text!r}") from None
