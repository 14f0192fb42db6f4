"""Static web player export of a bundle: ``neuras-distill export BUNDLE --format web --out DIR``.

Owns: :func:`export_web`, :func:`web_files` and the layout of the folder it writes. The folder plays the bundle in
a browser with plain WebGL2 (``neuras_distill/web/player.js``: no library, no CDN, nothing fetched from outside
the folder) by the same passes as ``playback/renderer.py``; ``python -m http.server`` inside it is enough to view
it, and so is opening ``index.html`` from ``file://`` (where ``fetch`` cannot read files, the player loads
``data.js``: the same data, base64).

Layout of DIR (every binary file raw little-endian, no header; the sizes are in scene.json)::

    index.html, player.js       the player (package data, copied unchanged)
    scene.json                  what the player needs: textures, mesh draw calls, passes, bounds, background,
                                the texture limit the folder was exported for (``max_texture_size``)
    cameras.json                the run's {"train": Cameras.to_json(), "test": ...} copied byte for byte from
                                the bundle's parent folder; without one a default orbit camera (the framing of
                                ``viewer.world_orbit_cameras``, 640 x 480, world frame) as "test" camera 0 and
                                "default_orbit": true. ``index.html?camera=N`` plays held-out (test) camera N.
    mesh.bin                    float32 (V, 8) interleaved: position (bundle frame, relative to the origin),
                                uv, ``MeshData.vertex_normals`` (the VBO layout of ``rasterize.mesh_vertex_array``)
    faces.bin                   uint32 (F, 3) triangle indices; ``scene.json`` "layers" = ``mesh_layers``
    tex_<uniform>.bin           one per bundle texture: uint16 (H, W[, C]) -> R16UI..RGBA16UI, float32 ->
                                R32F..RGBA32F, row 0 = v = 0, NEAREST (as ``BundleRenderer`` binds them); every
                                side at most ``max_texture_size`` (scene.json; default 4096,
                                ``export/texture_limit.py``): a taller codebook is wrapped again with more codes
                                per row and the shaders reading it say so
    data.js                     every file above (not the player, not the marker) base64 in one script:
                                ``window.NEURAS_WEB_DATA = {"files": {path: base64}}``; the player loads it only
                                from a ``file://`` page (over HTTP it fetches the files)
    shaders/*.vert|frag         GLSL ES 3.00 from ``glsl.to_glsl_es`` of the very sources the desktop compiles:
                                the bundle's shader.frag (one file per mesh layer, ``shaders.shader_variant``),
                                ``shaders.VERTEX_SHADER``, the bundle's sky.frag with ``SKY_VERTEX_SHADER``, the
                                silhouette pass
    .neuras-distill-web         marker: this folder is ours, so a later export may replace it

Decisions: the 16-bit index PNG is written out as raw uint16 because a browser decodes PNGs to 8 bits per channel;
the float32 data (codebooks, vertices) is raw so the GPU gets the same bits as the desktop player. data.js makes
the folder about 2.3 times the size of its data (raw + 4/3 base64): the raw files stay because HTTP fetches them
(no page downloads both), and the data is small (the default demo: a 0.89 MB bundle, a 3.2 MB folder of which
data.js is 1.8 MB; the run folder's views/ PNGs are 9.4 MB). The folder is built beside DIR under a temporary name
and renamed into place: on any error nothing is left, and an existing DIR is replaced only when it carries the
marker.
"""

from __future__ import annotations

import base64
import json
from importlib import resources
from pathlib import Path

from .. import __version__
from ..errors import BadInputError
from .folder_output import check_replaceable, write_folder
from .playable import playable_bundle
from .texture_limit import DEFAULT_MAX_TEXTURE_SIZE, checked_limit

MARKER = ".neuras-distill-web"
PLAYER_FILES = ("index.html", "player.js")
DATA_SCRIPT = "data.js"
DEFAULT_CAMERA_SIZE = (640, 480)


def cameras_json(bundle, src: Path) -> bytes:
    """cameras.json bytes: the run's (beside the bundle), validated, or a default orbit camera."""
    from ..render.cameras import Cameras

    path = src.parent / "cameras.json"
    if path.is_file():
        try:
            data = json.loads(path.read_text("utf-8"))
            Cameras.from_json(data["test"])
        except (ValueError, KeyError, TypeError, UnicodeDecodeError) as exc:
            raise BadInputError(f"{path} is not a cameras.json of a run ({exc.__class__.__name__}: {exc}); "
                                "fix or remove it") from None
        return path.read_bytes()
    from ..playback.viewer import world_orbit_cameras

    world = world_orbit_cameras(bundle, 1, *DEFAULT_CAMERA_SIZE)
    return json.dumps({"test": world.to_json(), "default_orbit": True}).encode("utf-8")


def web_files(bundle, cameras_json: bytes, max_texture_size: int = DEFAULT_MAX_TEXTURE_SIZE) -> dict[str, bytes]:
    """{relative path: bytes} of the web folder for a loaded ``bundle`` (see the module docstring), the marker
    included, every texture at most ``max_texture_size`` texels a side (``texture_limit.fit_bundle_textures``;
    BadInputError naming a texture that cannot fit)."""
    limit = checked_limit(max_texture_size)
    parts = playable_bundle(bundle, limit)
    files: dict[str, bytes] = {}
    files["mesh.bin"] = parts.vertices.astype("<f4", copy=False).tobytes()
    files["faces.bin"] = parts.faces.astype("<u4", copy=False).tobytes()
    textures = []
    for tex in parts.textures:
        file = f"tex_{tex.name}.bin"
        files[file] = tex.data.astype(tex.data.dtype.newbyteorder("<"), copy=False).tobytes()
        textures.append({"name": tex.name, "file": file, "width": int(tex.data.shape[1]),
                         "height": int(tex.data.shape[0]), "components": tex.components, "type": tex.kind,
                         **({"layers": tex.layers} if tex.layers > 1 else {})})
    programs = {}
    for layer, source in parts.programs.items():
        programs[layer] = f"shaders/mesh{layer}.frag"
        files[programs[layer]] = source.encode("utf-8")
    files["shaders/mesh.vert"] = parts.vertex_shader.encode("utf-8")
    sky = None
    if parts.sky is not None:
        files["shaders/sky.vert"], files["shaders/sky.frag"] = (s.encode("utf-8") for s in parts.sky[:2])
        sky = {"vertex": "shaders/sky.vert", "fragment": "shaders/sky.frag",
               "center": [float(x) for x in parts.sky[2]]}
    silhouette = None
    if parts.silhouette is not None:
        files["shaders/silhouette.vert"], files["shaders/silhouette.frag"] = (s.encode("utf-8")
                                                                              for s in parts.silhouette)
        silhouette = {"vertex": "shaders/silhouette.vert", "fragment": "shaders/silhouette.frag"}
    scene = {
        "generator": f"neuras-distill {__version__}",
        "background": [float(c) for c in parts.background],
        "origin": [float(x) for x in parts.origin],
        "bounds": parts.bounds.tolist(),
        "cull_back_faces": parts.cull_back_faces,
        "mesh": {"vertices": int(len(parts.vertices)), "faces": int(len(parts.faces)), "vbo": "mesh.bin",
                 "ibo": "faces.bin", "layers": parts.layers},
        "vertex_shader": "shaders/mesh.vert", "programs": programs, "textures": textures,
        "max_texture_size": limit,
        "sky": sky, "silhouette": silhouette,
    }
    files["scene.json"] = json.dumps(scene, indent=1).encode("utf-8")
    files["cameras.json"] = cameras_json
    files[DATA_SCRIPT] = data_script(files)
    web = resources.files("neuras_distill") / "web"
    for name in PLAYER_FILES:
        files[name] = (web / name).read_bytes()
    files[MARKER] = json.dumps({"generator": "neuras-distill", "version": __version__}).encode("utf-8")
    return files


def data_script(files: dict[str, bytes]) -> bytes:
    """data.js: ``window.NEURAS_WEB_DATA = {"files": {path: base64 of its bytes}}`` for every data file in
    ``files`` (what the player reads when opened from ``file://``, where it cannot fetch)."""
    embedded = {name: base64.b64encode(data).decode("ascii") for name, data in sorted(files.items())}
    return ("// neuras-distill web player data: the folder's data files, base64, for file:// pages (player.js)\n"
            "window.NEURAS_WEB_DATA = " + json.dumps({"files": embedded}, separators=(",", ":")) + ";\n"
            ).encode("ascii")


def export_web(bundle_path, out, max_texture_size: int = DEFAULT_MAX_TEXTURE_SIZE) -> Path:
    """Write the bundle at ``bundle_path`` (a folder, or a GLB of ours) as the static web folder ``out``, every
    texture at most ``max_texture_size`` texels a side.

    Validates everything first (the bundle with its checksums, cameras.json beside it, the output: absent or a
    folder with our marker, the textures' sizes), builds the folder under a temporary sibling name and renames it
    into place: on any error nothing is left behind. Returns ``out``.
    """
    from ..bake.bundle import load_bundle

    src, out = Path(bundle_path), Path(out)
    limit = checked_limit(max_texture_size)
    check_replaceable(out, MARKER, "web folder")
    if not src.exists():
        raise BadInputError(f"bundle {src} does not exist")
    bundle = load_bundle(src)
    return write_folder(out, web_files(bundle, cameras_json(bundle, src.resolve()), limit))


__all__ = ["DATA_SCRIPT", "MARKER", "cameras_json", "data_script", "export_web", "web_files"]
