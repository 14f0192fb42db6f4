"""What a WebGL2 page needs to play a bundle as ``BundleRenderer`` does: the part both browser exports share.

Owns: :class:`PlayableTexture`, :class:`PlayableBundle` and :func:`playable_bundle`. The web folder
(``export/web.py``) writes these parts as files beside ``scene.json``; the glTF export (``export/gltf.py``) carries
them in its ``NEURAS_neural_material`` extension for the three.js plugin (``web/neuras-three.js``) and any other
engine. Every shader is GLSL ES 3.00 from ``glsl.to_glsl_es`` of the very source the desktop player compiles, and
every texture fits the export's texture limit (``texture_limit.fit_bundle_textures``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..bake.bundle import PAGED_TEXTURES, atlas_pages
from ..errors import BadInputError
from .texture_limit import fit_bundle_textures


@dataclass(frozen=True)
class PlayableTexture:
    """One texture as the player binds it: ``name`` is its sampler uniform; ``data`` uint16 -> R16UI..RGBA16UI or
    float32 -> R32F..RGBA32F, (H, W) or (H, W, C), row 0 = v = 0, sampled NEAREST with CLAMP_TO_EDGE; ``layers``
    P > 1: a texture array of P layers of H / P rows each (an atlas in pages)."""

    name: str
    data: np.ndarray
    layers: int = 1

    @property
    def components(self) -> int:
        return 1 if self.data.ndim == 2 else int(self.data.shape[2])

    @property
    def kind(self) -> str:
        """"uint16" or "float32"."""
        return "uint16" if self.data.dtype == np.uint16 else "float32"


@dataclass(frozen=True)
class PlayableBundle:
    """A bundle in the form a WebGL2 page plays it.

    ``vertices`` float32 (V, 8): position (bundle frame: world relative to ``origin``), uv, shading normal
    (``MeshData.vertex_normals``); ``faces`` uint32 (F, 3); ``layers`` [(u_layer, first face, face count)] in draw
    order (``rasterize.mesh_layers``); ``programs`` {layer key "0"/"1": fragment source} (``shader_variant``);
    ``sky`` (vertex source, fragment source, float64 world centre (3,)) or None; ``silhouette`` (vertex, fragment)
    or None; ``background`` the clear colour (3,) as displayed; ``bounds`` (2, 3) of the positions.
    """

    vertices: np.ndarray
    faces: np.ndarray
    layers: list
    textures: list[PlayableTexture]
    vertex_shader: str
    programs: dict[str, str]
    sky: tuple[str, str, np.ndarray] | None
    silhouette: tuple[str, str] | None
    background: np.ndarray
    origin: np.ndarray
    bounds: np.ndarray
    cull_back_faces: bool


def playable_bundle(bundle, limit: int) -> PlayableBundle:
    """The parts of the loaded ``bundle`` a WebGL2 player needs, every texture at most ``limit`` texels a side
    (BadInputError naming a texture that cannot fit, or one of a type no WebGL2 texture holds)."""
    from ..bake.glsl import to_glsl_es
    from ..bake.glsl_sky import SKY_VERTEX_SHADER
    from ..playback.projection import mesh_bounds
    from ..playback.rasterize import mesh_layers
    from ..playback.shaders import SILHOUETTE_FRAGMENT_SHADER, SILHOUETTE_VERTEX_SHADER, VERTEX_SHADER, shader_variant

    fitted, fragment_shader, sky_fragment_shader = fit_bundle_textures(bundle, limit)
    mesh = bundle.mesh
    manifest = dict(getattr(bundle, "manifest", None) or {})
    uvs = mesh.uvs if mesh.uvs is not None else np.zeros((mesh.num_vertices, 2), np.float32)
    vertices = np.ascontiguousarray(np.concatenate([mesh.vertices, uvs, mesh.vertex_normals()], axis=1),
                                    dtype=np.float32)
    pages = atlas_pages(manifest)
    textures = []
    for name, arr in sorted(fitted.items()):
        arr = np.ascontiguousarray(arr)
        if arr.dtype not in (np.uint16, np.float32) or arr.ndim not in (2, 3) or \
                (arr.ndim == 3 and not 1 <= arr.shape[2] <= 4):
            raise BadInputError(f"bundle texture {name!r} is {arr.dtype} {arr.shape}; expected uint16 or float32 "
                                "(H, W[, C]) with C in 1..4")
        textures.append(PlayableTexture(name, arr, pages if pages > 1 and name in PAGED_TEXTURES else 1))
    layers = [[float(layer), int(first), int(count)] for layer, first, count in mesh_layers(mesh)]
    programs = {str(layer): shader_variant(to_glsl_es(fragment_shader), layer)
                for layer in sorted({max(0, int(layer)) for layer, _, _ in layers} or {0})}
    sky = None
    if sky_fragment_shader:
        sky = (to_glsl_es(SKY_VERTEX_SHADER), to_glsl_es(sky_fragment_shader),
               np.asarray(manifest["skybox"]["center"], np.float64).reshape(3))
    silhouette = None
    if manifest.get("silhouette_blend", False):
        silhouette = (to_glsl_es(SILHOUETTE_VERTEX_SHADER), to_glsl_es(SILHOUETTE_FRAGMENT_SHADER))
    return PlayableBundle(
        vertices=vertices, faces=np.ascontiguousarray(mesh.faces, dtype=np.uint32), layers=layers,
        textures=textures, vertex_shader=to_glsl_es(VERTEX_SHADER), programs=programs, sky=sky,
        silhouette=silhouette, background=np.asarray(bundle.background_color, np.float64).reshape(3),
        origin=np.asarray(getattr(bundle, "origin", np.zeros(3)), np.float64).reshape(3),
        bounds=mesh_bounds(mesh.vertices), cull_back_faces=bool(manifest.get("cull_back_faces", False)))


__all__ = ["PlayableBundle", "PlayableTexture", "playable_bundle"]
