"""The ``neuras-distill`` command line's grammar: :func:`build_parser` (every command and option). Parsing only:
what a run command distills is :mod:`.run_inputs`'s, what each command does is :mod:`.cli`'s.
"""

from __future__ import annotations

import argparse

#: The formats ``neuras-distill export --format`` writes.
EXPORT_FORMAT_NAMES = ("gltf", "web", "threejs", "3dtiles")


def _add_run_options(p: argparse.ArgumentParser, default_out: str | None = None) -> None:
    p.add_argument("--out", default=default_out, help="run folder (default: runs/<scene>)")
    p.add_argument("--preset", default=None, help="settings preset: object (default), fast, quality")
    p.add_argument("--config", default=None, help="TOML file overriding settings (see configs/)")
    p.add_argument("--face-budget", type=int, default=None, help="maximum faces after decimation")
    p.add_argument("--steps", type=int, default=None,
                   help="distillation steps (default 0: planned: enough for the atlas, fewer when held-back pixels "
                        "stop improving, within the time budget)")
    p.add_argument("--time-budget", type=float, default=None, metavar="SECONDS",
                   help="cap on the whole run's wall time: training gets what the stages before it leave, less the "
                        "evaluation's estimated time (default: none; training alone stops at 600 s)")
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
    p.add_argument("--quiet", action="store_true", help="no progress display; only warnings and errors")
    p.add_argument("-v", "--verbose", action="store_true", help="also the detail (each message with its logger)")


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
    p.add_argument("run", nargs="?", default=None,
                   help="the run's config.yml or its folder (outputs/<scene>/nerfacto/<timestamp>)")
    p.add_argument("--load-config", dest="load_config", default=None, metavar="CONFIG",
                   help="the run's config.yml, as nerfstudio's commands take it (instead of RUN)")
    p.add_argument("--cameras", default=None,
                   help="the dataset's transforms.json (default: the dataset config.yml names, or a "
                        "transforms.json beside config.yml; without one, an orbit around the foreground box)")
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

    p = sub.add_parser("render", help="a bundle along a camera path (nerfstudio's camera_path.json) or an orbit, "
                                       "as an .mp4 or PNG frames; --compare puts the field beside it")
    p.add_argument("bundle", help="bundle folder, .glb, or a run folder (its bundle/)")
    p.add_argument("--camera-path", default=None, metavar="JSON",
                   help="nerfstudio's camera_path.json (its viewer's export): one frame a pose, at its size and fps")
    p.add_argument("--orbit", type=int, default=None, metavar="N", help="N frames around the bundle's mesh instead")
    p.add_argument("--out", required=True, metavar="PATH",
                   help="an .mp4 (H.264, yuv420p) or a new folder for frame_NNNN.png")
    p.add_argument("--compare", default=None, metavar="RUN_DIR",
                   help="render the run's field beside the bundle (field | bundle): the before and after")
    p.add_argument("--path-frame", default="auto", metavar="FRAME",
                   help="the frame the path's poses are in: auto (nerfstudio's for a nerfstudio run, else the "
                        "bundle's), nerfstudio, or bundle")
    p.add_argument("--dataparser-transforms", default=None, metavar="JSON",
                   help="the nerfstudio run's dataparser_transforms.json, for a run that does not record it")
    p.add_argument("--width", type=int, default=None, help="frame width (default: the path's; an orbit's 960)")
    p.add_argument("--height", type=int, default=None, help="frame height (default: the path's; an orbit's 540)")
    p.add_argument("--fps", type=float, default=None, help="frames per second (default: the path's, else 24)")

    p = sub.add_parser("bench", help="error against run time for a finished run: the field at several step "
                                        "counts, the plain-texture floor and bundle variants distilled from the "
                                        "run's stored stages, with the Pareto front (writes RUN_DIR/bench/)")
    p.add_argument("run", metavar="RUN_DIR", help="a run folder (the --out of demo / from-synthetic / from-ngp / "
                                                  "from-sdf)")
    p.add_argument("--resolutions", default="640x360,1920x1080", metavar="WxH,...",
                   help="frame sizes to score and time at (the held-out cameras' aspect ratio; default "
                        "640x360,1920x1080)")
    p.add_argument("--variants", default=None, metavar="NAME,...",
                   help="bundle variants to distil (default all: atlas-half, atlas-double, mlp-8, mlp-16, "
                        "mlp-two-hidden, no-view, no-vq, faces-quarter, faces-half)")
    p.add_argument("--target-ms", type=float, default=None,
                   help="frame time the recommendation aims at (default 16.7 ms, 60 Hz)")
    p.add_argument("--quiet", action="store_true", help="no progress display; only warnings and errors")
    p.add_argument("-v", "--verbose", action="store_true", help="also the detail (each message with its logger)")

    p = sub.add_parser("tiles", help="a large scene as tiles: plan them, distill each as its own job, merge them "
                                        "into a 3D Tiles tileset")
    tiles = p.add_subparsers(dest="tiles_command", required=True)
    q = tiles.add_parser("plan", help="split the scene's foreground into tiles on the ground plane: CITY/plan.json")
    q.add_argument("source", help="as for check: a checkpoint path, synthetic:NAME or extreme:NAME")
    q.add_argument("--tile-size", type=float, required=True, metavar="METRES",
                   help="side of a tile on the ground plane, in the field's units")
    q.add_argument("--margin", type=float, default=None, metavar="METRES",
                   help="overlap each tile trains on beyond its side (default: a tenth of the tile size)")
    q.add_argument("--out", required=True, metavar="CITY", help="the folder of the plan and its tiles")
    q.add_argument("--dry-run", action="store_true",
                   help="print the tiles, their cameras and estimated time and memory; write nothing")
    q.add_argument("--kind", choices=["sdf", "density"], default=None, help="synthetic scenes: field type")
    q.add_argument("--cameras", default=None, help="transforms.json (as the run commands)")
    q.add_argument("--preset", default=None, help="settings preset (default: the scene's own, as the run commands)")
    q.add_argument("--config", default=None, help="TOML settings (as the run commands)")
    q.add_argument("--steps", type=int, default=None, help="distillation steps of the whole scene, shared out")
    q.add_argument("--face-budget", type=int, default=None, help="faces of the whole scene, shared out")
    q.add_argument("--levels", type=int, default=1, metavar="N",
                   help="levels of detail per tile (default 1: full detail only); level l has 1/4^l of the faces, "
                        "1/2^l of the atlas side and 1/4^l of the training, its geometricError measured")
    q = tiles.add_parser("run", help="distill tile K of a plan into CITY/tiles/K/ (every unfinished tile without "
                                     "--tile): resumable, a finished tile is skipped")
    q.add_argument("city", metavar="CITY", help="the folder of the plan (tiles plan --out)")
    q.add_argument("--tile", type=int, default=None, metavar="K",
                   help="the tile to distill (a SLURM array: --tile $SLURM_ARRAY_TASK_ID); default: all, in turn")
    q.add_argument("--device", default="auto", metavar="DEVICE", help="as the run commands")
    q.add_argument("--nproc", default=1, metavar="N", help="as the run commands: processes sharing a tile's teacher")
    q.add_argument("--ray", nargs="?", const="", default=None, metavar="ADDRESS",
                   help="every unfinished tile as a Ray task (pip install neuras-distill[ray]): on a local Ray, or "
                        "on the cluster at ADDRESS (`ray start --head`'s host:port, or auto); a task whose worker "
                        "dies is retried")
    q.add_argument("--quiet", action="store_true", help="no progress display; only warnings and errors")
    q.add_argument("-v", "--verbose", action="store_true", help="also the detail (each message with its logger)")
    q = tiles.add_parser("merge", help="the finished tiles as a 3D Tiles 1.1 tileset: tileset.json and a .glb each")
    q.add_argument("city", metavar="CITY", help="the folder of the plan and its finished tiles")
    q.add_argument("--out", required=True, help="the tileset folder (replaced only when neuras-distill wrote it)")
    q.add_argument("--max-texture-size", default=None, metavar="N", help="as export")
    q.add_argument("--crs", default=None, metavar="EPSG:XXXXX",
                   help="the projected CRS the scene's coordinates are in (e.g. a UTM zone): the root transform "
                        "places the city on the globe (ECEF; needs pyproj); without it, a local frame")

    p = sub.add_parser("export", help="write a bundle in a format other tools open (gltf: one .glb file; "
                                         "web: a static folder that plays it in a browser; threejs: a three.js "
                                         "page with the glb and the plugin that plays its neural material)")
    p.add_argument("bundle", help="bundle folder (runs/<scene>/bundle); for 3dtiles the tileset folder of tiles merge")
    p.add_argument("--format", required=True, metavar="FORMAT",
                   help=f"output format: {', '.join(EXPORT_FORMAT_NAMES)} (gltf: glTF 2.0 binary, the mesh with its "
                        "plain RGB texture, unlit, plus the whole neural bundle inside; load_bundle reads it; web: "
                        "index.html + WebGL2 player + data, the same shaders in GLSL ES 3.00; view it with "
                        "`neuras-distill serve DIR`, index.html?camera=N plays held-out camera N; "
                        "threejs: index.html, the glb, the three.js plugin neuras-three.js and three.js copied from "
                        "--three, served the same way; 3dtiles: a page streaming a tileset with 3DTilesRendererJS from "
                        "--tiles-renderer and three.js from --three, the tiles' neural material through the plugin)")
    p.add_argument("--three", default=None, metavar="THREE_DIR",
                   help="threejs, 3dtiles: the three.js package to copy into the page (node_modules/three of a "
                        "local `npm install three`; tested with 0.187)")
    p.add_argument("--tiles-renderer", default=None, metavar="TILES_DIR",
                   help="3dtiles only: the 3DTilesRendererJS package to copy into the page "
                        "(node_modules/3d-tiles-renderer of a local `npm install 3d-tiles-renderer`; tested with 0.5.3)")
    p.add_argument("--cesium", default=None, metavar="CESIUM_DIR",
                   help="3dtiles: also a CesiumJS page (cesium.html) of the tileset on the globe, with CesiumJS "
                        "copied from CESIUM_DIR (node_modules/cesium; tested with 1.145.0)")
    p.add_argument("--out", required=True, help="output file or folder (gltf: a .glb path; web, threejs: a folder); an "
                                                "existing one is replaced only when neuras-distill wrote it")
    p.add_argument("--up", default="auto", metavar="AXIS",
                   help="gltf, threejs: the capture's up axis in the bundle's frame, turned onto glTF's +Y by the "
                        "scene's root node: auto (default: the run's cameras' mean up, snapped to an axis within "
                        "15 degrees; +z without cameras.json), +x, -x, +y, -y, +z or -z")
    p.add_argument("--max-texture-size", default=None, metavar="N",
                   help="largest texture side the export writes, in texels (default 4096, a side WebGL2 browsers "
                        "hold in practice): a codebook is wrapped into more codes per row to fit; an atlas page above "
                        "it exits 2 (bake with a smaller texture.page_size, or raise N for a target that holds it)")

    p = sub.add_parser("serve", help="serve a web or threejs export (or a run folder's report.html) on 127.0.0.1 "
                                        "and open it in the browser, until Ctrl-C")
    p.add_argument("dir", metavar="DIR", help="the --out folder of `export --format web|threejs`, or a run folder")
    p.add_argument("--port", default="8000", metavar="N", help="port on 127.0.0.1 (default 8000; 0 picks a free one)")
    p.add_argument("--no-open", action="store_true", help="do not open the page in a browser")
    return parser
