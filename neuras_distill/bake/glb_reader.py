"""Reading a bundle back out of a glTF binary (``.glb``) written by ``export/gltf.py``: the files it carries in its
``NEURAS_bundle`` extension (:func:`read_bundle_files`, which ``load_bundle("scene.glb")`` uses), the check of
its ``NEURAS_neural_material`` extension (:func:`check_neural_extension`) and whether a file is one of ours
(:func:`written_by_us`). The layout is documented in ``export/gltf.py`` and ``export/gltf_neural.py``."""

from __future__ import annotations

import json
import struct
from pathlib import Path

from ..errors import BadInputError

EXTENSION = "NEURAS_bundle"
EXTENSION_VERSION = 1
NEURAL_EXTENSION = "NEURAS_neural_material"      # the neural look for engines (export/gltf_neural.py)
NEURAL_EXTENSION_VERSION = 1
GENERATOR = "neuras-distill"
GLB_MAGIC, CHUNK_JSON, CHUNK_BIN = 0x46546C67, 0x4E4F534A, 0x004E4942        # b"glTF", b"JSON", b"BIN\0" (little endian)


def _parse_glb(path: Path, data: bytes) -> tuple[dict, bytes]:
    """(JSON document, binary chunk) of a GLB, or BadInputError."""
    bad = BadInputError(f"{path} is not a glTF binary (.glb) file")
    if len(data) < 20:
        raise bad
    magic, version, length = struct.unpack_from("<III", data, 0)
    if magic != GLB_MAGIC or version != 2:
        raise bad
    if length > len(data):
        raise BadInputError(f"{path} is truncated: its header declares {length} bytes, the file has {len(data)}; "
                            "copy or export it again")
    json_len, json_type = struct.unpack_from("<II", data, 12)
    if json_type != CHUNK_JSON or 20 + json_len > length:
        raise bad
    try:
        doc = json.loads(data[20:20 + json_len].decode("utf-8"))
    except (ValueError, UnicodeDecodeError):
        raise bad from None
    if not isinstance(doc, dict):
        raise bad
    body = b""
    at = 20 + json_len
    if at + 8 <= length:
        bin_len, bin_type = struct.unpack_from("<II", data, at)
        if bin_type == CHUNK_BIN and at + 8 + bin_len <= length:
            body = data[at + 8:at + 8 + bin_len]
    return doc, body


def read_bundle_files(path) -> dict[str, bytes]:
    """{file name: bytes} of the bundle a GLB carries in its ``NEURAS_bundle`` extension (unchecked: the
    checksums are ``load_bundle``'s job). BadInputError when ``path`` is no GLB, carries no bundle, or carries a
    ``NEURAS_neural_material`` that :func:`check_neural_extension` refuses."""
    path = Path(path)
    doc, body = _parse_glb(path, path.read_bytes())
    ext = (doc.get("extensions") or {}).get(EXTENSION)
    if not isinstance(ext, dict) or not isinstance(ext.get("files"), dict):
        raise BadInputError(f"{path} is a glTF file without a neuras bundle (no {EXTENSION} extension)")
    if ext.get("version") != EXTENSION_VERSION:
        raise BadInputError(f"{path}: {EXTENSION} version {ext.get('version')} is not supported "
                            f"(this version reads {EXTENSION_VERSION})")
    views = doc.get("bufferViews") or []
    files = {}
    for name, i in ext["files"].items():
        if not isinstance(i, int) or not 0 <= i < len(views) or not isinstance(views[i], dict):
            raise BadInputError(f"{path}: {EXTENSION} names a missing buffer view for {name}")
        start, size = views[i].get("byteOffset", 0), views[i].get("byteLength", -1)
        if views[i].get("buffer") != 0 or not isinstance(start, int) or not isinstance(size, int) \
                or start < 0 or size < 0 or start + size > len(body):
            raise BadInputError(f"{path}: the buffer view of {name} lies outside the binary chunk")
        files[name] = body[start:start + size]
    node = (doc.get("nodes") or [None])[0]
    neural = (node.get("extensions") or {}).get(NEURAL_EXTENSION) if isinstance(node, dict) else None
    if neural is not None:
        check_neural_extension(path, doc, len(body), neural)
    return files


_COMPONENT_BYTES = {5123: 2, 5125: 4, 5126: 4}
_TYPE_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def _views_and_accessors(ext) -> tuple[list[int], list[int]]:
    """(buffer view indices, accessor indices) the ``NEURAS_neural_material`` object ``ext`` names."""
    views, accessors = [ext.get("vertexShader")], list((ext.get("geometry") or {}).values())
    views += [call.get("fragmentShader") for call in ext.get("drawCalls") or [] if isinstance(call, dict)]
    accessors += [tex.get("accessor") for tex in ext.get("textures") or [] if isinstance(tex, dict)]
    for part in ("sky", "silhouette"):
        if isinstance(ext.get(part), dict):
            views += [ext[part].get("vertexShader"), ext[part].get("fragmentShader")]
    return views, accessors


def check_neural_extension(path, doc: dict, body_size: int, ext) -> None:
    """BadInputError unless the node's ``NEURAS_neural_material`` object ``ext`` is of a version this package
    reads and every buffer view and accessor it names lies inside the ``body_size``-byte binary chunk (the layout
    is ``export/gltf_neural.py``'s): a truncated or damaged file is refused before anything is loaded."""
    if not isinstance(ext, dict) or not isinstance(ext.get("version"), int):
        raise BadInputError(f"{path}: {NEURAL_EXTENSION} has no version: the file is damaged; export it again")
    if ext["version"] != NEURAL_EXTENSION_VERSION:
        raise BadInputError(f"{path}: {NEURAL_EXTENSION} version {ext['version']} is not supported (this version "
                            f"reads {NEURAL_EXTENSION_VERSION}): update neuras-distill, or export it again with "
                            "this one")
    views, accessors = doc.get("bufferViews") or [], doc.get("accessors") or []

    def view_end(i, what) -> int:
        v = views[i] if isinstance(i, int) and 0 <= i < len(views) and isinstance(views[i], dict) else None
        start, size = (v.get("byteOffset", 0), v.get("byteLength")) if v else (None, None)
        if v is None or v.get("buffer") != 0 or not isinstance(start, int) or not isinstance(size, int) \
                or start < 0 or size < 0 or start + size > body_size:
            raise BadInputError(f"{path}: {NEURAL_EXTENSION}'s {what} lies outside the binary chunk "
                                f"({body_size} bytes): the file is truncated or damaged; export it again")
        return size

    named_views, named_accessors = _views_and_accessors(ext)
    for i in named_views:
        view_end(i, f"buffer view {i}")
    for i in named_accessors:
        a = accessors[i] if isinstance(i, int) and 0 <= i < len(accessors) and isinstance(accessors[i], dict) \
            else None
        if a is None or a.get("componentType") not in _COMPONENT_BYTES or a.get("type") not in _TYPE_COMPONENTS \
                or not isinstance(a.get("count"), int) or a["count"] < 0:
            raise BadInputError(f"{path}: {NEURAL_EXTENSION} names a missing or malformed accessor {i}: the file "
                                "is damaged; export it again")
        need = a.get("byteOffset", 0) + a["count"] * _TYPE_COMPONENTS[a["type"]] * _COMPONENT_BYTES[a["componentType"]]
        if need > view_end(a.get("bufferView"), f"accessor {i}"):
            raise BadInputError(f"{path}: {NEURAL_EXTENSION}'s accessor {i} declares {a['count']} values, more "
                                "than its buffer view holds: the file is damaged; export it again")


def written_by_us(path) -> bool:
    """Whether the file ``path`` is a GLB this module wrote (its asset.generator names neuras-distill)."""
    try:
        with open(path, "rb") as f:
            head = f.read(20)
            if len(head) < 20:
                return False
            magic, version, _ = struct.unpack_from("<III", head, 0)
            json_len, json_type = struct.unpack_from("<II", head, 12)
            if magic != GLB_MAGIC or version != 2 or json_type != CHUNK_JSON or json_len > 1 << 26:
                return False
            doc = json.loads(f.read(json_len).decode("utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return False
    if not isinstance(doc, dict) or not isinstance(doc.get("asset"), dict):
        return False
    return str((doc.get("asset") or {}).get("generator", "")).startswith(GENERATOR + " ")
