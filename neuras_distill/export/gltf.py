"""glTF 2.0 binary (``.glb``) export of a bundle.

Owns: :func:`export_gltf` (``neuras-distill export BUNDLE --format gltf --out scene.glb``) and :func:`glb_bytes`.
The GLB is written by hand (a JSON chunk and one binary chunk: no glTF library); this module and
:mod:`.glb_reader` (which reads a bundle back out of one) are the only ones that know the layout.

Layout (one buffer, the GLB's binary chunk; every buffer view starts on a 4-byte boundary)::

    scenes[0] -> nodes[1] "neuras up": ``rotation`` (a unit quaternion; absent when the capture is already +Y
        up) that turns the capture's up onto glTF's +Y (``export/gltf_up.py``, ``export --up``), so the scene
        stands upright in every engine; ``extras.neuras_up`` is that up in the bundle's frame
      -> nodes[0] "neuras bundle" -> meshes[0]: one triangle primitive (one per atlas page); the node's
        ``translation`` is ``bundle.origin`` (JSON doubles; absent when it is zero), so the mesh sits at its
        world place while its float32 positions stay small. Everything on this node (the mesh, the neural
        extension, the skyboxes in it) is in the bundle's own frame: a point p of the field is at R @ p in
        the glTF scene, R the root's rotation
        POSITION    float32 (V, 3), world units relative to ``bundle.origin``: the bundle's vertices as stored
                    (a georeferenced scene keeps float32 precision around its centre), in the bundle's axes
        TEXCOORD_0  float32 (V, 2), the bundle's uvs unchanged: glTF's v runs down the image, and the texture's
                    first row is v = 0 (the bundle's convention), so no flip is needed
        indices     uint16 (V < 65535) or uint32
    materials[0]: KHR_materials_unlit, baseColorTexture = the bundle's plain_rgb.png (8-bit RGB, values as
        displayed, i.e. sRGB-encoded base colour as glTF expects), sampler LINEAR / LINEAR_MIPMAP_LINEAR,
        CLAMP_TO_EDGE; doubleSided unless the manifest says ``cull_back_faces``; each image at most
        ``max_texture_size`` texels a side (default 4096, ``export/texture_limit.py``; a larger page is refused)
    an atlas in pages (``manifest.atlas_pages`` P > 1): one primitive, material, texture and image per page
        with faces (primitive p's indices are the faces on page p, its material p's image page p of
        plain_rgb.png as its own PNG); TEXCOORD_0 is then the uv within the vertex's page
        (``v_page = v * P - page``; no chart crosses a page), shared by all primitives
    extensions.NEURAS_bundle = {"version": 1, "files": {file name: buffer view index}}: every file of the bundle
        folder (manifest.json and every file it lists with its sha256), byte for byte; plain_rgb.png's view is
        the image's own (stored once). Listed in ``extensionsUsed``, not ``extensionsRequired``: an engine that
        does not know it ignores it and shows the textured mesh.

Decisions: a two-layer bundle's glTF mesh is its core only (faces[:core_faces], vertices compacted): the shell is
a fringe that the player draws behind any core fragment (``playback/shaders.py``), a rule no generic engine has,
so drawn opaque it would hide the core; it travels in the extension with the rest. Skyboxes likewise travel only
in the extension. A bundle without plain_rgb.png (baked before the runs stored it) is refused with a message
saying to re-run: its MLP exists only as GLSL in the bundle, so a fallback would need a GL pass in UV space with
an invented view input (say, opposite the normal), a texture the report's baseline never measured.

``load_bundle("scene.glb")`` reads the files back through :func:`read_bundle_files` and validates them exactly
as a folder's (checksums from manifest.json), so the GLB plays identically to the folder.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from .. import __version__
from ..bake.glb_reader import (
    CHUNK_BIN,
    CHUNK_JSON,
    EXTENSION,
    EXTENSION_VERSION,
    GENERATOR,
    GLB_MAGIC,
    NEURAL_EXTENSION,
    read_bundle_files,
    written_by_us,
)
from ..errors import BadInputError
from .folder_output import write_file
from .gltf_neural import neural_material_extension
from .gltf_up import parse_up, quaternion_xyzw, resolve_up, rotation_onto_y
from .playable import playable_bundle
from .texture_limit import DEFAULT_MAX_TEXTURE_SIZE, check_side, checked_limit

_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_FLOAT, _UNSIGNED_SHORT, _UNSIGNED_INT = 5126, 5123, 5125
_LINEAR, _LINEAR_MIPMAP_LINEAR, _CLAMP_TO_EDGE = 9729, 9987, 33071


class _Binary:
    """The binary chunk under construction: 4-byte aligned buffer views."""

    def __init__(self):
        self.parts: list[bytes] = []
        self.size = 0
        self.views: list[dict] = []

    def add(self, data: bytes, target: int | None = None, name: str | None = None) -> int:
        view = {"buffer": 0, "byteOffset": self.size, "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        if name is not None:
            view["name"] = name
        pad = (-len(data)) % 4
        self.parts += [data, b"\0" * pad]
        self.size += len(data) + pad
        self.views.append(view)
        return len(self.views) - 1


def _glb_mesh(bundle) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(positions float32 (V', 3) relative to ``bundle.origin``, uvs float32 (V', 2), faces (F', 3) into them) of
    the faces an engine should draw: all of a single-layer mesh, the core of a two-layer one; unused vertices
    dropped."""
    mesh = bundle.mesh
    faces = np.asarray(mesh.faces, np.int64)
    if mesh.core_faces:                                   # None: one layer; 0: no core, draw what there is
        faces = faces[:mesh.core_faces]
    if not len(faces):
        raise BadInputError("the bundle's mesh has no faces to export")
    used, remap = np.unique(faces.reshape(-1), return_inverse=True)
    return np.asarray(mesh.vertices, np.float32)[used], np.asarray(mesh.uvs, np.float32)[used], remap.reshape(-1, 3)


def glb_bytes(bundle, files: dict[str, bytes], max_texture_size: int = DEFAULT_MAX_TEXTURE_SIZE,
              up=(0.0, 1.0, 0.0)) -> bytes:
    """The GLB of ``bundle`` (a loaded :class:`~neuras_distill.bake.bundle.Bundle` with ``plain_rgb``) carrying
    ``files`` ({name: bytes}: the bundle folder's files, ``bundle.read_bundle_file_bytes``) losslessly; its
    images (one per atlas page) at most ``max_texture_size`` texels a side, else BadInputError. ``up`` (3,) is
    the capture's up in the bundle's frame, which the root node turns onto +Y (``gltf_up.resolve_up``)."""
    from ..bake.bundle import PLAIN_FILE

    if PLAIN_FILE not in files:
        raise BadInputError("the bundle has no plain RGB texture (plain_rgb.png; bundles baked by older versions "
                            "lack it): re-run the distillation to export it as glTF")
    from ..bake.bundle import atlas_pages, encode_png_rgb

    pages = atlas_pages(bundle.manifest)
    check_side("plain_rgb", bundle.plain_rgb.shape[1], bundle.plain_rgb.shape[0], checked_limit(max_texture_size),
               pages)
    positions, uvs, faces = _glb_mesh(bundle)
    face_page = np.zeros(len(faces), np.int64)
    if pages > 1:                      # each vertex lies on one page: its uv within that page's own texture
        vertex_page = np.clip(np.floor(uvs[:, 1].astype(np.float64) * pages), 0, pages - 1).astype(np.int64)
        uvs = np.stack([uvs[:, 0], uvs[:, 1].astype(np.float64) * pages - vertex_page], axis=1).astype(np.float32)
        face_page = vertex_page[faces[:, 0]]
    binary = _Binary()
    small = len(positions) < 65535                        # 65535 is uint16's primitive-restart value
    index_type, index_dtype = (_UNSIGNED_SHORT, np.uint16) if small else (_UNSIGNED_INT, np.uint32)
    position = binary.add(positions.tobytes(), _ARRAY_BUFFER, "POSITION")
    texcoord = binary.add(uvs.tobytes(), _ARRAY_BUFFER, "TEXCOORD_0")
    accessors = [
        {"bufferView": position, "componentType": _FLOAT, "count": len(positions), "type": "VEC3",
         "min": [float(x) for x in positions.min(0)], "max": [float(x) for x in positions.max(0)]},
        {"bufferView": texcoord, "componentType": _FLOAT, "count": len(uvs), "type": "VEC2"},
    ]
    primitives = []
    for page in range(pages):                             # one primitive and material per page with faces
        page_faces = faces[face_page == page]
        if not len(page_faces):
            continue
        view = binary.add(page_faces.astype(index_dtype).tobytes(), _ELEMENT_ARRAY_BUFFER,
                          "indices" if pages == 1 else f"indices page {page}")
        accessors.append({"bufferView": view, "componentType": index_type, "count": int(page_faces.size),
                          "type": "SCALAR"})
        primitives.append({"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": len(accessors) - 1,
                           "material": page, "mode": 4})
    file_views = {}
    for name in ("manifest.json", *sorted(n for n in files if n != "manifest.json")):
        file_views[name] = binary.add(files[name], None, name)
    parts = playable_bundle(bundle, max_texture_size)

    def add_accessor(acc: dict) -> int:
        accessors.append(acc)
        return len(accessors) - 1

    neural = neural_material_extension(parts, lambda data, name: binary.add(data, None, name), add_accessor)
    if pages == 1:
        images = [{"name": PLAIN_FILE, "bufferView": file_views[PLAIN_FILE], "mimeType": "image/png"}]
    else:                              # the stacked plain texture cut into its pages, one PNG each
        side = bundle.plain_rgb.shape[1]
        images = [{"name": f"plain_rgb page {page}", "mimeType": "image/png",
                   "bufferView": binary.add(encode_png_rgb(bundle.plain_rgb[page * side:(page + 1) * side]), None,
                                            f"plain_rgb page {page}")} for page in range(pages)]
    materials = [{"name": "plain texture (unlit)" + (f", page {page}" if pages > 1 else ""),
                  "pbrMetallicRoughness": {"baseColorTexture": {"index": page}, "metallicFactor": 0.0,
                                           "roughnessFactor": 1.0},
                  "doubleSided": not bool(bundle.manifest.get("cull_back_faces", False)),
                  "extensions": {"KHR_materials_unlit": {}}} for page in range(pages)]
    rotation = rotation_onto_y(up)
    up_node = {"name": "neuras up", "children": [0],
               "extras": {"neuras_up": [float(x) for x in np.asarray(up, np.float64).reshape(3)]}}
    if not np.allclose(rotation, np.eye(3), atol=1e-12):
        up_node["rotation"] = quaternion_xyzw(rotation)
    doc = {
        "asset": {"version": "2.0", "generator": f"{GENERATOR} {__version__}"},
        "extensionsUsed": ["KHR_materials_unlit", EXTENSION, NEURAL_EXTENSION],
        "extensions": {EXTENSION: {"version": EXTENSION_VERSION, "files": file_views}},
        "scene": 0,
        "scenes": [{"name": "neuras bundle", "nodes": [1]}],
        "nodes": [{"name": "neuras bundle", "mesh": 0,
                   **({"translation": [float(x) for x in bundle.origin]} if bundle.origin.any() else {}),
                   "extensions": {NEURAL_EXTENSION: neural}}, up_node],
        "meshes": [{"name": "bundle mesh" + (" (core)" if bundle.mesh.core_faces else ""),
                    "primitives": primitives}],
        "materials": materials,
        "textures": [{"sampler": 0, "source": page} for page in range(pages)],
        "samplers": [{"magFilter": _LINEAR, "minFilter": _LINEAR_MIPMAP_LINEAR, "wrapS": _CLAMP_TO_EDGE,
                      "wrapT": _CLAMP_TO_EDGE}],
        "images": images,
        "accessors": accessors,
        "bufferViews": binary.views,
        "buffers": [{"byteLength": binary.size}],
    }
    text = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    text += b" " * ((-len(text)) % 4)
    body = b"".join(binary.parts)
    total = 12 + 8 + len(text) + 8 + len(body)
    return b"".join([struct.pack("<III", GLB_MAGIC, 2, total), struct.pack("<II", len(text), CHUNK_JSON), text,
                     struct.pack("<II", len(body), CHUNK_BIN), body])


def export_gltf(bundle_path, out, max_texture_size: int = DEFAULT_MAX_TEXTURE_SIZE, up: str = "auto") -> Path:
    """Write the bundle at ``bundle_path`` (a folder, or a GLB of ours) as the glTF binary ``out`` (.glb), its
    images at most ``max_texture_size`` texels a side (``texture_limit.check_side``), the capture's ``up`` (an
    ``export --up`` value, ``gltf_up.UP_CHOICES``) turned onto +Y.

    Validates everything first (the bundle with its checksums, the output path: absent or a GLB of ours), then
    writes a temporary file beside ``out`` and renames it into place: on any error nothing is left behind.
    Returns ``out``.
    """
    from ..bake.bundle import load_bundle, read_bundle_file_bytes

    src, out = Path(bundle_path), Path(out)
    limit = checked_limit(max_texture_size)
    parse_up(up)
    if out.suffix.lower() != ".glb":
        raise BadInputError(f"--out {out}: a glTF binary must end in .glb")
    if out.exists() or out.is_symlink():
        if out.is_dir():
            raise BadInputError(f"output path {out} is a folder; choose a .glb file path for --out")
        if not written_by_us(out):
            raise BadInputError(f"output file {out} exists and was not written by neuras-distill; "
                                "choose another --out or remove it")
    if not src.exists():
        raise BadInputError(f"bundle {src} does not exist")
    bundle = load_bundle(src)
    if bundle.plain_rgb is None:
        raise BadInputError(f"bundle {src} has no plain RGB texture (plain_rgb.png; bundles baked by older "
                            "versions lack it): re-run the distillation to export it as glTF")
    up_vector, _ = resolve_up(up, src)
    files = read_bundle_files(src) if src.is_file() else read_bundle_file_bytes(src)
    data = glb_bytes(bundle, files, limit, up_vector)
    out.parent.mkdir(parents=True, exist_ok=True)
    return write_file(out, data)


__all__ = ["export_gltf", "glb_bytes"]
