"""The ``NEURAS_neural_material`` glTF extension: the neural look of a bundle as glTF buffers and accessors.

Owns: :func:`neural_material_extension` (the name and version are ``bake/glb_reader.py``'s), which
``export/gltf.py`` calls to put a :class:`~neuras_distill.export.playable.PlayableBundle` into the GLB it writes.
The extension sits on the bundle's node (``nodes[0].extensions``); ``docs/formats.md`` ("The glTF neural
material") specifies it for loader writers, ``web/neuras-three.js`` is the three.js loader, and
``bake/glb_reader.py`` checks it when a bundle is loaded from a GLB.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..bake.glb_reader import NEURAL_EXTENSION_VERSION
from .playable import PlayableBundle

_FLOAT, _UNSIGNED_SHORT, _UNSIGNED_INT = 5126, 5123, 5125
_TYPES = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}


def neural_material_extension(parts: PlayableBundle, add_view: Callable[[bytes, str], int],
                              add_accessor: Callable[[dict], int]) -> dict:
    """The extension's JSON object for ``parts``; its data goes into the GLB's binary chunk through ``add_view``
    (bytes, name) -> buffer view index and ``add_accessor`` (accessor dict) -> accessor index. Every array is
    little-endian; shaders are UTF-8 GLSL ES 3.00 text in their own buffer views."""

    def accessor(array: np.ndarray, component: int, kind: str, name: str, bounds: bool = False) -> int:
        flat = np.ascontiguousarray(array)
        view = add_view(flat.astype(flat.dtype.newbyteorder("<"), copy=False).tobytes(), name)
        count = int(flat.shape[0]) if kind != "SCALAR" or flat.ndim == 1 else int(flat.size)
        acc = {"bufferView": view, "componentType": component, "count": count, "type": kind, "name": name}
        if bounds:
            acc["min"], acc["max"] = [float(x) for x in flat.min(0)], [float(x) for x in flat.max(0)]
        return add_accessor(acc)

    def shader(source: str, name: str) -> int:
        return add_view(source.encode("utf-8"), name)

    v = parts.vertices
    geometry = {
        "POSITION": accessor(np.ascontiguousarray(v[:, 0:3]), _FLOAT, "VEC3", "neural POSITION", bounds=True),
        "TEXCOORD_0": accessor(np.ascontiguousarray(v[:, 3:5]), _FLOAT, "VEC2", "neural TEXCOORD_0"),
        "NORMAL": accessor(np.ascontiguousarray(v[:, 5:8]), _FLOAT, "VEC3", "neural NORMAL"),
        "indices": accessor(parts.faces.reshape(-1), _UNSIGNED_INT, "SCALAR", "neural indices"),
    }
    programs = {layer: shader(source, f"neural fragment shader, layer {layer}")
                for layer, source in parts.programs.items()}
    textures = []
    for tex in parts.textures:
        h, w = tex.data.shape[:2]
        component = _UNSIGNED_SHORT if tex.kind == "uint16" else _FLOAT
        textures.append({"uniform": tex.name, "width": int(w), "height": int(h // tex.layers),
                         "layers": int(tex.layers),
                         "accessor": accessor(tex.data.reshape(h * w, tex.components), component,
                                              _TYPES[tex.components], f"texture {tex.name}")})
    ext = {
        "version": NEURAL_EXTENSION_VERSION,
        "geometry": geometry,
        "vertexShader": shader(parts.vertex_shader, "neural vertex shader"),
        "drawCalls": [{"layer": layer, "firstFace": first, "faceCount": count,
                       "fragmentShader": programs[str(max(0, int(layer)))]} for layer, first, count in parts.layers],
        "textures": textures,
        "cullBackFaces": parts.cull_back_faces,
        "background": [float(c) for c in parts.background],
    }
    if parts.sky is not None:
        ext["sky"] = {"vertexShader": shader(parts.sky[0], "sky vertex shader"),
                      "fragmentShader": shader(parts.sky[1], "sky fragment shader"),
                      "center": [float(x) for x in parts.sky[2]]}
    if parts.silhouette is not None:
        ext["silhouette"] = {"vertexShader": shader(parts.silhouette[0], "silhouette vertex shader"),
                             "fragmentShader": shader(parts.silhouette[1], "silhouette fragment shader")}
    return ext


__all__ = ["neural_material_extension"]
