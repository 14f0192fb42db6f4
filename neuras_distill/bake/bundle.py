"""The bundle: what plays (mesh with UVs, feature textures, generated fragment shader, manifest).

Owns: :class:`Bundle`, :func:`bake`, :func:`load_bundle`, :func:`float16_feature_nbytes`. On disk::

    manifest.json        format, sizes, model settings, sha256 of every other file; ``core_faces``: null for a
                         single-layer mesh, else the number of core faces (faces[:core_faces] the core,
                         the rest the shell; see ``MeshData.core_faces``); a missing key reads as null;
                         ``shaders``: 2 when the fragment shader holds one MLP per layer (picked by ``u_layer``);
                         ``normal_smoothing``: rounds of the shading normals' smoothing (absent: 0);
                         ``view_input``: "direction" or "reflection" (the direction the shader feeds its MLP,
                         computed in ``shader.frag``; absent: "direction")
    mesh.npz             float32 vertices (V,3), float32 uvs (V,2), int32 faces (F,3)
    feature_index.png    16-bit grayscale PNG of the (H, W) code indices (row 0 = v = 0, i.e. the image
                         looks upside down in a viewer), lossless; an atlas in ``atlas_pages`` P > 1 pages
                         (format version 4) stacks them: H = P * W, page p is rows p*W .. (p+1)*W - 1,
                         played as a texture array of P layers
    codebook.npy         float32 (K, ceil(D/4), 4), zero padded
    shader.frag          the generated fragment shader
    shader.vert          only when the bundle carries a vertex shader (``playback.shaders.VERTEX_SHADER``: a
                         two-layer mesh is drawn core then shell with its uniform ``u_layer`` = 0 / 1)
    sky_index.png        only with skyboxes: 16-bit PNG of the skybox atlas's code indices
    sky_codebook.npy     only with skyboxes: float32 (K_sky, ceil(D/4), 4)
    sky.frag             only with skyboxes: the skybox pass's fragment shader (``bake/glsl_sky.py``)
    plain_rgb.png        optional (every run writes it): 8-bit RGB PNG, (H, W) of the feature atlas,
                         the plain texture (``bake/plain_texture.py``: the model once per texel, gutters padded),
                         values as displayed (sRGB as stored), row 0 = v = 0 like the index map; what the glTF
                         export (``export/gltf.py``) hands other engines as base colour. Never bound by the player.

A bundle also travels as one glTF binary (``export/gltf.py``): :func:`load_bundle` given a ``.glb`` file reads the
same files, byte for byte, from its ``NEURAS_bundle`` extension and validates them exactly like a folder's.

Textures are named by the sampler they bind to: ``u_index`` (uint16 (H, W)) and ``u_codebook``, and with
skyboxes ``u_sky_index`` and ``u_sky_codebook``.

Precision: mesh vertices are stored relative to ``manifest["origin"]`` (float64 world position of the scene
centre, [0, 0, 0] for bundles baked without one); the renderer subtracts it from camera positions in float64,
so a scene kilometres from its world origin plays with float32 precision around its own centre. The skybox
layers (``manifest["skybox"]``) carry their own float64 centre.

Versions: a single-layer bundle is written as format version 2, a two-layer one (``core_faces`` set) as 3, so a
reader that predates the layers refuses it instead of letting the shell hide the core; both are read here.
A bundle whose shading normals are smoothed (manifest ``normal_smoothing`` k > 0, ``MeshData.normal_smoothing``:
every player computes ``MeshData.vertex_normals`` with k rounds of one-ring averaging) is version 5, whatever
else it has, so an older reader, which would feed its facing input the plain normals, refuses it.
"""

from __future__ import annotations

import hashlib
import io
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from neuras_distill.bake.glb_reader import read_bundle_files
from neuras_distill.bake.glsl import generate_fragment_shader
from neuras_distill.errors import BadInputError
from neuras_distill.geometry.mesh import MeshData

FORMAT = "neuras-bundle"
FORMAT_VERSION = 2
TWO_LAYER_FORMAT_VERSION = 3            # written only for a two-layer mesh (manifest ``core_faces`` not null)
PAGES_FORMAT_VERSION = 4                # written only for an atlas in pages (manifest ``atlas_pages`` > 1)
NORMALS_FORMAT_VERSION = 5              # written only with smoothed shading normals (``normal_smoothing`` > 0)
READABLE_VERSIONS = (1, 2, 3, 4, 5)
#: Textures that hold the atlas's pages stacked along their rows, played as a texture array of
#: ``atlas_pages`` layers when there are several (the index map; a plain bundle's RGB texture).
PAGED_TEXTURES = ("u_index", "u_rgb")
MAX_CODES = 65535
FILES = ("manifest.json", "mesh.npz", "feature_index.png", "codebook.npy", "shader.frag")
SKY_FILES = ("sky_index.png", "sky_codebook.npy", "sky.frag")
PLAIN_FILE = "plain_rgb.png"


def atlas_pages(manifest: dict | None) -> int:
    """The atlas's page count a bundle manifest records (``atlas_pages``; 1 when absent: one texture)."""
    return int((manifest or {}).get("atlas_pages") or 1)


def float16_feature_nbytes(height: int, width: int, dim: int) -> int:
    """Bytes of the same atlas stored unquantized as float16: H * W * D * 2."""
    return int(height) * int(width) * int(dim) * 2


@dataclass
class Bundle:
    """A baked, playable result.

    Attributes:
        mesh: MeshData with uvs; its ``core_faces`` (None: one layer) is what the manifest's ``core_faces`` records.
        textures: {"u_index": uint16 (H, W), "u_codebook": float32 (K, C4, 4)}.
        fragment_shader: GLSL source (``#version 400 core`` from ``bake/glsl.py``; a plain-texture bundle's,
            ``glsl.plain_fragment_shader``, is ``#version 330 core``).
        background_color: (3,) float32 clear colour.
        manifest: dict (format, sizes, model settings, ...; ``save`` adds file hashes).
        vertex_shader: optional GLSL source saved as shader.vert (the playback stage owns it).
        sky_fragment_shader: the skybox pass's GLSL source, or None for a bundle without skyboxes (then
            ``textures`` has no ``u_sky_*`` entries and ``manifest`` no ``skybox``).
        plain_rgb: optional uint8 (H, W, 3) plain RGB texture over the mesh's UVs (row 0 = v = 0), saved as
            plain_rgb.png; not a sampler of the fragment shader (so not in ``textures``). None: not baked
            (older bundles).

    Encoding (the files' bytes, ``_encode``) is done once and kept: :meth:`save`, :meth:`nbytes_on_disk` and
    :meth:`feature_nbytes` share it. The kept bytes carry a fingerprint of everything they are made from (a
    hash of the arrays' bytes, the shaders and the manifest; far cheaper than the PNG and zip compression), so
    any change to the bundle, an attribute set or an array changed in place, encodes it afresh.
    """

    mesh: MeshData
    textures: dict
    fragment_shader: str
    background_color: np.ndarray
    manifest: dict = field(default_factory=dict)
    vertex_shader: str | None = None
    sky_fragment_shader: str | None = None
    plain_rgb: np.ndarray | None = None
    _encoded: tuple[bytes, dict[str, bytes]] | None = field(default=None, init=False, repr=False,
                                                            compare=False)

    @property
    def origin(self) -> np.ndarray:
        """(3,) float64 world position the mesh vertices are relative to."""
        return np.asarray(self.manifest.get("origin", (0.0, 0.0, 0.0)), dtype=np.float64).reshape(3)

    @property
    def has_skybox(self) -> bool:
        return self.sky_fragment_shader is not None

    def __post_init__(self) -> None:
        self.background_color = np.asarray(self.background_color, dtype=np.float32).reshape(3)
        if self.plain_rgb is not None:
            self.plain_rgb = np.ascontiguousarray(self.plain_rgb)
            if self.plain_rgb.dtype != np.uint8 or self.plain_rgb.ndim != 3 or self.plain_rgb.shape[2] != 3:
                raise ValueError(f"plain_rgb must be a uint8 (H, W, 3) array, got {self.plain_rgb.dtype} "
                                 f"{self.plain_rgb.shape}")

    # ------------------------------------------------------------------ encoding
    def _fingerprint(self) -> bytes:
        """A digest of everything :meth:`_encode_files` reads (array bytes with dtype and shape, shaders,
        background colour, manifest): equal digests, equal files."""
        h = hashlib.blake2b(digest_size=32)

        def add(value: Any) -> None:
            if isinstance(value, np.ndarray):
                a = np.ascontiguousarray(value)
                h.update(f"array {a.dtype.str} {a.shape}|".encode())
                h.update(a.reshape(-1).view(np.uint8))
            else:
                h.update(f"{type(value).__name__} {value!r}|".encode())

        m = self.mesh
        for value in (m.vertices, m.uvs, m.faces, m.core_faces, m.normal_smoothing, self.fragment_shader,
                      self.vertex_shader,
                      self.sky_fragment_shader, self.background_color, self.plain_rgb):
            add(value)
        for name in sorted(self.textures):
            add(name)
            add(np.asarray(self.textures[name]))
        add(json.dumps(self.manifest, sort_keys=True, default=repr))
        return h.digest()

    def _encode(self) -> dict[str, bytes]:
        """{file name: bytes} of the saved bundle, encoded once and reused while the bundle is unchanged
        (see the class docstring). A new dict each call; the bytes are shared."""
        key = self._fingerprint()
        if self._encoded is None or self._encoded[0] != key:
            self._encoded = (key, self._encode_files())
        return dict(self._encoded[1])

    def _encode_files(self) -> dict[str, bytes]:
        """Encode every file of the bundle: PNGs, the compressed mesh, the manifest with the files' hashes."""
        files: dict[str, bytes] = {}
        buf = io.BytesIO()
        m = self.mesh
        np.savez_compressed(buf, vertices=m.vertices.astype(np.float32), uvs=m.uvs.astype(np.float32),
                            faces=m.faces.astype(np.int32))
        files["mesh.npz"] = buf.getvalue()
        files["feature_index.png"] = _encode_png16(self.textures["u_index"])
        buf = io.BytesIO()
        np.save(buf, np.ascontiguousarray(self.textures["u_codebook"], dtype=np.float32), allow_pickle=False)
        files["codebook.npy"] = buf.getvalue()
        files["shader.frag"] = self.fragment_shader.encode("utf-8")
        if self.vertex_shader is not None:
            files["shader.vert"] = self.vertex_shader.encode("utf-8")
        if self.has_skybox:
            files["sky_index.png"] = _encode_png16(self.textures["u_sky_index"])
            buf = io.BytesIO()
            np.save(buf, np.ascontiguousarray(self.textures["u_sky_codebook"], dtype=np.float32), allow_pickle=False)
            files["sky_codebook.npy"] = buf.getvalue()
            files["sky.frag"] = self.sky_fragment_shader.encode("utf-8")
        if self.plain_rgb is not None:
            files[PLAIN_FILE] = encode_png_rgb(self.plain_rgb)
        core_faces = _core_faces(m.core_faces, m.num_faces, "the mesh")
        manifest = dict(self.manifest)
        version = (NORMALS_FORMAT_VERSION if m.normal_smoothing > 0 else
                   PAGES_FORMAT_VERSION if atlas_pages(self.manifest) > 1 else
                   FORMAT_VERSION if core_faces is None else TWO_LAYER_FORMAT_VERSION)
        if m.normal_smoothing > 0:
            manifest["normal_smoothing"] = int(m.normal_smoothing)
        else:
            manifest.pop("normal_smoothing", None)
        manifest.update(format=FORMAT, format_version=version, core_faces=core_faces,
                        background_color=[float(x) for x in self.background_color],
                        files={k: {"bytes": len(v), "sha256": hashlib.sha256(v).hexdigest()} for k, v in files.items()})
        files["manifest.json"] = json.dumps(manifest, indent=2, sort_keys=True).encode("utf-8")
        return files

    def save(self, directory) -> Path:
        """Write the bundle files into ``directory`` (created if needed). Returns the directory."""
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        for name, data in self._encode().items():
            (d / name).write_bytes(data)
        return d

    def nbytes_on_disk(self) -> int:
        """Total bytes the saved files take (the same encoding ``save`` writes, encoded once)."""
        return sum(len(v) for v in self._encode().values())

    def feature_nbytes(self) -> int:
        """Bytes of the feature data on disk: index PNGs + codebooks (mesh atlas and, if any, skyboxes)."""
        files = self._encode()
        return sum(len(files[k]) for k in ("feature_index.png", "codebook.npy", "sky_index.png", "sky_codebook.npy")
                   if k in files)

    def float16_nbytes(self) -> int:
        """Bytes the same atlas would take unquantized in float16 (H * W * D * 2), for the compression ratio."""
        h, w = self.textures["u_index"].shape
        c4 = self.textures["u_codebook"].shape[1] // int(self.manifest.get("codes_per_row", 1))
        return float16_feature_nbytes(h, w, int(self.manifest.get("feature_dim", 4 * c4)))


def _core_faces(value, num_faces: int, where: str) -> int | None:
    """``value`` as None or an int in [0, num_faces], or BadInputError naming ``where``."""
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) \
            or not 0 <= int(value) <= num_faces:
        raise BadInputError(f"{where}: core_faces must be null or an integer in [0, {num_faces}], got {value!r}")
    return int(value)


def encode_png_rgb(rgb: np.ndarray) -> bytes:
    """8-bit RGB PNG bytes of a uint8 (H, W, 3) array (the plain texture, and its pages in the glTF export)."""
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb), mode="RGB").save(buf, format="PNG")
    return buf.getvalue()


def _encode_png16(index: np.ndarray) -> bytes:
    a = np.ascontiguousarray(index)
    if a.dtype != np.uint16 or a.ndim != 2:
        raise ValueError(f"an index map must be a uint16 (H, W) array, got {a.dtype} {a.shape}")
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, format="PNG", compress_level=9)
    data = buf.getvalue()
    if not np.array_equal(_decode_png16(data), a):        # lossless round trip, checked once per encode
        raise RuntimeError("16-bit PNG round trip of the index map is not exact")
    return data


def _decode_png16(data: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(data)) as im:
        if im.mode not in ("I;16", "I;16B", "I;16L", "I"):
            raise ValueError(f"feature_index.png is mode {im.mode}, not 16-bit grayscale")
        a = np.array(im)
    if a.dtype != np.uint16:
        if a.min() < 0 or a.max() > 65535:
            raise ValueError("feature_index.png values outside 16 bits")
        a = a.astype(np.uint16)
    return a


#: Rows of the codebook texture at most (the texture height; llvmpipe's and common GPUs' largest side).
CODEBOOK_MAX_ROWS = 16384


def codes_per_row(num_codes: int, max_rows: int = CODEBOOK_MAX_ROWS) -> int:
    """How many codes share one row of the codebook texture so that it has at most ``max_rows`` rows."""
    return max(1, -(-int(num_codes) // int(max_rows)))


def wrap_codebook(codebook: np.ndarray, per_row: int) -> np.ndarray:
    """(K, C4, 4) codebook -> (ceil(K / per_row), per_row * C4, 4) texture: code k at row k // per_row,
    columns (k % per_row) * C4 .. + C4 - 1 (zero padding after the last code). per_row 1: unchanged."""
    if per_row == 1:
        return codebook
    k, c4 = codebook.shape[:2]
    rows = -(-k // per_row)
    padded = np.zeros((rows * per_row, c4, 4), np.float32)
    padded[:k] = codebook
    return padded.reshape(rows, per_row * c4, 4)


def _baked_textures(atlas_model, max_rows: int | None = None) -> tuple[np.ndarray, np.ndarray, int, int]:
    """(uint16 index map (H, W), float32 codebook texture (rows, per_row * C4, 4), K, per_row) of a
    NeuralTextureModel's atlas (:func:`wrap_codebook`)."""
    index, codebook = atlas_model.baked_features()
    k, dim = codebook.shape
    if k > MAX_CODES:
        raise BadInputError(f"bake: {k} codes do not fit a uint16 index texture (at most {MAX_CODES})")
    c4 = (dim + 3) // 4
    cb = np.zeros((k, c4 * 4), np.float32)
    cb[:, :dim] = codebook
    per_row = codes_per_row(k, CODEBOOK_MAX_ROWS if max_rows is None else max_rows)
    return index.astype(np.uint16), wrap_codebook(cb.reshape(k, c4, 4), per_row), k, per_row


def bake(model, mesh: MeshData, background_color, extra_manifest: dict | None = None,
         vertex_shader: str | None = None, skybox=None, origin=None) -> Bundle:
    """Turn a trained ``NeuralTextureModel`` and its mesh into a :class:`Bundle`.

    Codes never referenced by the index map are dropped (``manifest["num_codes"]`` is the kept count,
    ``num_codes_trained`` the codebook size during training); when ``extra_manifest`` carries the run's
    ``left_out`` list, the dropped codes are added to it. ``skybox``: a trained :class:`SkyboxModel` to
    bake alongside (its own codebook, pruned the same way, and the ``sky.frag`` pass). ``origin``: (3,)
    float64 world position the mesh vertices are relative to (default the origin).
    """
    if mesh.uvs is None:
        raise BadInputError("bake: the mesh has no UVs; unwrap it before baking")
    core_faces = _core_faces(mesh.core_faces, mesh.num_faces, "bake")
    if model.mesh_layers == 2 and core_faces is None:
        raise BadInputError("bake: the model has a shader per mesh layer but the mesh has one layer "
                            "(core_faces is None); bake it with the two-layer mesh it was trained on")
    index, cb, k, per_row = _baked_textures(model)
    dim = int(model.feature_dim)
    textures = {"u_index": index, "u_codebook": cb}
    sky_shader = None
    manifest = {
        "texture_width": int(model.tex_width), "texture_height": int(model.tex_height),
        "atlas_pages": int(getattr(model, "pages", 1)),
        "feature_dim": int(dim), "num_codes": int(k),
        "num_codes_trained": int(model.num_codes) if model.quantizing else 0,
        "use_vq": bool(model.quantizing), "use_viewdir": bool(model.use_viewdir),
        "use_facing": bool(model.use_facing),
        "view_input": "reflection" if model.view_reflect else "direction",
        "mlp_hidden": int(model.hidden), "mlp_layers": int(model.num_layers),
        "shell_mlp_hidden": int(model.shaders[-1].hidden) if model.mesh_layers == 2 else None,
        "shaders": int(model.mesh_layers),
        "mesh_vertices": int(mesh.num_vertices), "mesh_faces": int(mesh.num_faces),
        "core_faces": core_faces,
        "float16_feature_bytes": float16_feature_nbytes(model.tex_height, model.tex_width, dim),
        "origin": [float(x) for x in (np.zeros(3) if origin is None else np.asarray(origin, np.float64).reshape(3))],
    }
    if per_row > 1:
        manifest["codes_per_row"] = per_row
    if skybox is not None:
        from neuras_distill.bake.glsl_sky import generate_sky_fragment_shader

        sky_index, sky_cb, _, _ = _baked_textures(skybox.atlas, max_rows=MAX_CODES + 1)  # never wrapped
        textures.update(u_sky_index=sky_index, u_sky_codebook=sky_cb)
        sky_shader = generate_sky_fragment_shader(skybox)
        sky_h, sky_w = skybox.layers.atlas_size
        manifest["skybox"] = dict(skybox.layers.to_json(), num_codes=int(sky_cb.shape[0]),
                                  num_codes_trained=int(skybox.atlas.num_codes), feature_dim=int(skybox.feature_dim),
                                  mlp_hidden=int(skybox.shader.hidden), atlas_size=[sky_h, sky_w],
                                  float16_feature_bytes=float16_feature_nbytes(sky_h, sky_w, skybox.feature_dim))
    manifest.update(extra_manifest or {})
    manifest["core_faces"] = core_faces                 # the mesh's, whatever extra_manifest says
    if "left_out" in manifest and model.quantizing and k < model.num_codes:     # the bake's own leaving out
        manifest["left_out"] = [*manifest["left_out"], {
            "component": "unused codes",
            "reason": f"{model.num_codes - k} of {model.num_codes} codebook entries are used by no texel and "
                      "were dropped"}]
    return Bundle(mesh=MeshData(mesh.vertices, mesh.faces, mesh.uvs, core_faces=core_faces,
                                normal_smoothing=int(mesh.normal_smoothing)),
                  textures=textures,
                  fragment_shader=generate_fragment_shader(model, codes_per_row=per_row),
                  background_color=background_color,
                  manifest=manifest, vertex_shader=vertex_shader, sky_fragment_shader=sky_shader)


def load_bundle(directory) -> Bundle:
    """Read and validate a saved bundle: its folder, or a glTF binary (``.glb``) written by ``export/gltf.py``
    (the same files, carried in the ``NEURAS_bundle`` extension). Raises BadInputError naming the missing or
    corrupt file."""
    d = Path(directory)
    if d.is_file():
        files = read_bundle_files(d)
        return _load_files(d, files.get, lambda name: name in files)
    if not d.is_dir():
        raise BadInputError(f"bundle folder {d} does not exist")
    return _load_files(d, lambda name: (d / name).read_bytes() if (d / name).is_file() else None,
                       lambda name: (d / name).is_file())


def read_bundle_file_bytes(directory) -> dict[str, bytes]:
    """{file name: bytes} of every file of the bundle folder ``directory`` (manifest.json and every file it
    lists), after :func:`load_bundle` validated them (checksums included): what a lossless copy carries."""
    d = Path(directory)
    load_bundle(d)
    manifest = json.loads((d / "manifest.json").read_text("utf-8"))
    return {name: (d / name).read_bytes() for name in ("manifest.json", *sorted(manifest["files"]))}


def _load_files(d: Path, read, exists) -> Bundle:
    """The bundle whose files ``read(name)`` returns (bytes or None when absent); ``d`` names it in errors."""
    missing = [f for f in FILES if not exists(f)]
    if missing:
        raise BadInputError(f"bundle {d} is missing {', '.join(missing)}")
    try:
        manifest = json.loads(read("manifest.json").decode("utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise BadInputError(f"bundle {d}: manifest.json is not valid JSON ({exc})") from exc
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise BadInputError(f"bundle {d}: manifest.json is not a {FORMAT} manifest")
    if manifest.get("format_version") not in READABLE_VERSIONS:
        raise BadInputError(f"bundle {d}: format version {manifest.get('format_version')} is not supported "
                            f"(this version reads {', '.join(map(str, READABLE_VERSIONS))})")
    raw = {}
    for name, info in (manifest.get("files") or {}).items():
        if name == "manifest.json" or "/" in name or "\\" in name or not exists(name):
            raise BadInputError(f"bundle {d} is missing {name}")
        raw[name] = read(name)
        if not isinstance(info, dict) or hashlib.sha256(raw[name]).hexdigest() != info.get("sha256"):
            raise BadInputError(f"bundle {d}: {name} is corrupt (checksum differs from manifest.json)")
    needed = FILES[1:] + (SKY_FILES if "skybox" in manifest else ())
    for name in needed:
        if name not in raw:
            raise BadInputError(f"bundle {d}: manifest.json does not list {name}")

    def corrupt(name, exc):
        return BadInputError(f"bundle {d}: {name} is corrupt ({exc})")

    try:
        with np.load(io.BytesIO(raw["mesh.npz"]), allow_pickle=False) as z:
            mesh = MeshData(z["vertices"], z["faces"], z["uvs"])
    except Exception as exc:  # noqa: BLE001
        raise corrupt("mesh.npz", exc) from exc
    try:
        index = _decode_png16(raw["feature_index.png"])
    except Exception as exc:  # noqa: BLE001
        raise corrupt("feature_index.png", exc) from exc
    try:
        codebook = np.load(io.BytesIO(raw["codebook.npy"]), allow_pickle=False)
    except Exception as exc:  # noqa: BLE001
        raise corrupt("codebook.npy", exc) from exc
    h, w = manifest.get("texture_height"), manifest.get("texture_width")
    if index.shape != (h, w):
        raise BadInputError(f"bundle {d}: feature_index.png is {index.shape}, manifest says {(h, w)}")
    pages = manifest.get("atlas_pages", 1)
    if isinstance(pages, bool) or not isinstance(pages, int) or pages < 1 or (pages > 1 and h != pages * w):
        raise BadInputError(f"bundle {d}: manifest.json says atlas_pages {pages!r}; expected an integer >= 1, "
                            f"with texture_height = atlas_pages x texture_width when above 1")
    num_codes, per_row = manifest.get("num_codes"), manifest.get("codes_per_row", 1)
    rows = -(-int(num_codes) // int(per_row)) if isinstance(num_codes, int) and isinstance(per_row, int) \
        and per_row >= 1 else None
    if codebook.dtype != np.float32 or codebook.ndim != 3 or codebook.shape[2] != 4 or rows is None \
            or codebook.shape[0] != rows or codebook.shape[1] % per_row:
        raise BadInputError(f"bundle {d}: codebook.npy is {codebook.dtype} {codebook.shape}, expected float32 "
                            f"({rows}, {per_row} x C4, 4) for {num_codes} codes, {per_row} per row")
    if index.size and int(index.max()) >= num_codes:
        raise BadInputError(f"bundle {d}: feature_index.png refers to code {int(index.max())} but the codebook "
                            f"has {num_codes}")
    if mesh.faces.size and (mesh.faces.min() < 0 or mesh.faces.max() >= mesh.num_vertices):
        raise BadInputError(f"bundle {d}: mesh.npz faces index missing vertices")
    mesh.core_faces = _core_faces(manifest.get("core_faces"), mesh.num_faces, f"bundle {d}: manifest.json")
    smoothing = manifest.get("normal_smoothing", 0)
    if isinstance(smoothing, bool) or not isinstance(smoothing, int) or not 0 <= smoothing <= 10000:
        raise BadInputError(f"bundle {d}: manifest.json says normal_smoothing {smoothing!r}; expected an integer "
                            "in [0, 10000]")
    mesh.normal_smoothing = smoothing
    try:
        frag = raw["shader.frag"].decode("utf-8")
        vert = raw["shader.vert"].decode("utf-8") if "shader.vert" in raw else None
        sky_frag = raw["sky.frag"].decode("utf-8") if "skybox" in manifest else None
    except UnicodeDecodeError as exc:
        raise corrupt("shader", exc) from exc
    plain = None
    if PLAIN_FILE in raw:
        try:
            with Image.open(io.BytesIO(raw[PLAIN_FILE])) as im:
                if im.mode != "RGB":
                    raise ValueError(f"mode {im.mode}, not 8-bit RGB")
                plain = np.array(im)
        except Exception as exc:  # noqa: BLE001
            raise corrupt(PLAIN_FILE, exc) from exc
        if plain.shape[:2] != (h, w):
            raise BadInputError(f"bundle {d}: {PLAIN_FILE} is {plain.shape[:2]}, manifest says {(h, w)}")
    textures = {"u_index": index, "u_codebook": codebook}
    if "skybox" in manifest:
        try:
            textures["u_sky_index"] = _decode_png16(raw["sky_index.png"])
            textures["u_sky_codebook"] = np.load(io.BytesIO(raw["sky_codebook.npy"]), allow_pickle=False)
        except Exception as exc:  # noqa: BLE001
            raise corrupt("the skybox textures", exc) from exc
        sky = manifest["skybox"]
        if list(textures["u_sky_index"].shape) != list(sky.get("atlas_size", [])) or \
                textures["u_sky_codebook"].shape[0] != sky.get("num_codes") or \
                int(textures["u_sky_index"].max(initial=0)) >= textures["u_sky_codebook"].shape[0]:
            raise BadInputError(f"bundle {d}: the skybox textures do not match manifest.json")
    bg = manifest.get("background_color")
    manifest = {k: v for k, v in manifest.items() if k not in ("format", "format_version", "files", "background_color")}
    return Bundle(mesh=mesh, textures=textures, fragment_shader=frag, background_color=np.asarray(bg, np.float32),
                  manifest=manifest, vertex_shader=vert, sky_fragment_shader=sky_frag, plain_rgb=plain)
