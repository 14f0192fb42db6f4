"""Reading a bundle back out of a glTF binary (``.glb``) written by :mod:`.gltf`: the files it carries in its
``NEURAS_bundle`` extension (:func:`read_bundle_files`, which ``load_bundle("scene.glb")`` uses) and whether a
file is one of ours (:func:`written_by_us`). The layout is documented in :mod:`.gltf`."""

from __future__ import annotations

import json
import struct
from pathlib import Path

from ..errors import BadInputError

EXTENSION = "NEURAS_bundle"
EXTENSION_VERSION = 1
GENERATOR = "neuras-distill"
GLB_MAGIC, CHUNK_JSON, CHUNK_BIN = 0x46546C67, 0x4E4F534A, 0x004E4942        # b"glTF", b"JSON", b"BIN\0" (little endian)


def _parse_glb(path: Path, data: bytes) -> tuple[dict, bytes]:
    """(JSON document, binary chunk) of a GLB, or BadInputError."""
    bad = BadInputError(f"{path} is not a glTF binary (.glb) file")
    if len(data) < 20:
        raise bad
    magic, version, length = struct.unpack_from("<III", data, 0)
    if magic != GLB_MAGIC or version != 2 or length > len(data):
        raise bad
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
    checksums are ``load_bundle``'s job). BadInputError when ``path`` is no GLB or carries no bundle."""
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
    return files


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
