"""NeuS / IDR camera files (``cameras_sphere.npz``, docs/formats.md §2.3): projection matrices to
:class:`Cameras`, and the scale matrix.

This module owns:

* :func:`cameras_from_neus_npz`: reads ``world_mat_{i}`` (P = K [R | t], world -> pixels, 3x4 or 4x4) and
  ``scale_mat_{i}`` (normalised unit sphere -> world), decomposes every P with an RQ decomposition (signs fixed
  so K has a positive diagonal and R is a rotation) and returns world-frame cameras in our OpenGL convention
  plus the scale matrix.
* :func:`projection_from_camera`: the inverse (K, c2w -> P), used to write such files (tests, fixtures).
* :func:`check_similarity` / :func:`similarity_parts`: a scale matrix must be a similarity
  ``p_world = s Q p + t`` (NeuS uses ``s = scale_mat[0, 0]`` and ``t = scale_mat[:3, 3]``; Q is normally I).

Conventions: NeuS (like OpenCV) puts pixel centres at integer coordinates and its cameras look down +z with
y down; ours put pixel (u, v)'s centre at (u + 0.5, v + 0.5) and look down -z with y up. So
``cx_ours = K[0, 2] + 0.5``, ``cy_ours = K[1, 2] + 0.5`` and the camera y and z axes are negated. The image
size is not stored in the npz: pass ``width``/``height``, or keep the NeuS layout (``image/*.png`` next to
the npz), whose first image's size is read from its PNG header. A non-zero skew K[0, 1] is ignored.
"""

from __future__ import annotations

import re
import struct
import zipfile
from pathlib import Path

import numpy as np
import scipy.linalg
import torch

from neuras_distill.errors import BadInputError, require
from neuras_distill.render.cameras import Cameras

_WORLD_RE = re.compile(r"^world_mat_(\d+)$")


def _load_npz(path: Path) -> dict[str, np.ndarray]:
    require(path.exists(), f"camera file {path} does not exist; give the cameras_sphere.npz of the NeuS case")
    require(path.is_file(), f"camera file {path} is a directory; give the cameras_sphere.npz inside it")
    try:
        with np.load(path, allow_pickle=False) as data:
            if not hasattr(data, "files"):
                raise BadInputError(f"{path} is a single .npy array, not a NeuS cameras .npz archive")
            return {k: np.asarray(data[k]) for k in data.files}
    except BadInputError:
        raise
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise BadInputError(f"{path} is not a readable NeuS cameras .npz ({type(exc).__name__}: "
                            f"{str(exc).splitlines()[0][:160] if str(exc) else 'damaged'})") from None


def _as_matrix(a: np.ndarray, key: str, path: Path) -> np.ndarray:
    require(np.issubdtype(a.dtype, np.number), f"{path}: {key} is not numeric (dtype {a.dtype})")
    a = a.astype(np.float64)
    require(a.shape in ((3, 4), (4, 4)), f"{path}: {key} has shape {a.shape}; expected (4, 4) or (3, 4)")
    require(bool(np.isfinite(a).all()), f"{path}: {key} contains NaN or Inf")
    return a


def similarity_parts(scale_mat: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, Q (3, 3), t (3,)) with ``scale_mat[:3, :3] = s Q``, Q a rotation, s > 0 (no check)."""
    m = np.asarray(scale_mat, dtype=np.float64)
    a = m[:3, :3]
    s = float(np.cbrt(np.linalg.det(a)))
    return s, a / s, m[:3, 3].copy()


def check_similarity(scale_mat: np.ndarray, source: str = "scale_mat") -> np.ndarray:
    """Validate a (4, 4) (or (3, 4)) scale matrix as a similarity with positive scale; returns it (4, 4)."""
    try:
        m = np.asarray(scale_mat, dtype=np.float64)
    except (TypeError, ValueError):
        raise BadInputError(f"{source} is not a matrix of numbers") from None
    require(m.shape in ((4, 4), (3, 4)), f"{source} has shape {m.shape}; expected (4, 4)")
    require(bool(np.isfinite(m).all()), f"{source} contains NaN or Inf")
    if m.shape == (3, 4):
        m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
    require(np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9),
            f"{source} must have [0, 0, 0, 1] as its last row, got {m[3].tolist()}")
    det = np.linalg.det(m[:3, :3])
    require(det > 0, f"{source} must map the unit sphere to the world with a positive scale (det {det:.3g})")
    s, q, _ = similarity_parts(m)
    err = float(np.abs(q.T @ q - np.eye(3)).max())
    require(err < 1e-4, f"{source} is not a uniform scale + rotation + translation (anisotropy {err:.2g}); "
                        "NeuS needs the same scale on every axis")
    return m


def decompose_projection(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """P (3, 4) = λ K [R | t] -> (K (3, 3) with K[2, 2] = 1 and positive diagonal, R rotation, t (3,))."""
    p = np.asarray(p, dtype=np.float64)[:3, :4]
    m = p[:, :3]
    if np.linalg.det(m) < 0:  # P is defined up to scale; a negative scale flips R's determinant
        p = -p
        m = -m
    k, r = scipy.linalg.rq(m)
    signs = np.sign(np.diag(k))
    signs[signs == 0] = 1.0
    d = np.diag(signs)
    k, r = k @ d, d @ r
    t = np.linalg.solve(k, p[:, 3])
    k = k / k[2, 2]
    return k, r, t


def projection_from_camera(k: np.ndarray, c2w_opencv: np.ndarray) -> np.ndarray:
    """(4, 4) NeuS ``world_mat`` (P = K [R | t] padded with [0, 0, 0, 1]) from K (3, 3) and an OpenCV c2w."""
    w2c = np.linalg.inv(np.asarray(c2w_opencv, dtype=np.float64))
    p = np.eye(4)
    p[:3, :4] = np.asarray(k, dtype=np.float64) @ w2c[:3, :4]
    return p


def _png_size(path: Path) -> tuple[int, int] | None:
    try:
        with open(path, "rb") as fh:
            head = fh.read(24)
    except OSError:
        return None
    if len(head) < 24 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return None
    w, h = struct.unpack(">II", head[16:24])
    return (int(w), int(h)) if w > 0 and h > 0 else None


def _image_size_beside(path: Path) -> tuple[int, int] | None:
    """Size of the first PNG in ``<npz dir>/image/`` (the NeuS data layout), if any."""
    folder = path.parent / "image"
    if not folder.is_dir():
        return None
    pngs = sorted(p for p in folder.iterdir() if p.suffix.lower() == ".png")
    return _png_size(pngs[0]) if pngs else None


def cameras_from_neus_npz(path, width: int | None = None, height: int | None = None
                          ) -> tuple[Cameras, np.ndarray]:
    """Read a NeuS ``cameras_sphere.npz``.

    Returns ``(cameras, scale_mat)``: world-frame :class:`Cameras` (OpenGL convention, pixel centres at
    +0.5) and ``scale_mat_0`` (4, 4) float64, the map from NeuS's normalised unit sphere to the world
    (``p_world = scale_mat @ [p, 1]``). ``width``/``height`` are the training image size in pixels; when
    omitted they are read from ``image/*.png`` beside the npz, else :class:`BadInputError` asks for them.
    """
    path = Path(path)
    data = _load_npz(path)
    ids = sorted(int(m.group(1)) for k in data if (m := _WORLD_RE.match(k)))
    require(ids, f"{path} has no world_mat_<i> arrays; it is not a NeuS cameras file "
                 f"(keys: {', '.join(sorted(data)[:6])})")
    require(ids == list(range(len(ids))), f"{path}: world_mat indices are not 0..{len(ids) - 1} (got {ids[:8]}...)")
    if width is None or height is None:
        size = _image_size_beside(path)
        if size is None:
            k0, _, _ = decompose_projection(_as_matrix(data["world_mat_0"], "world_mat_0", path))
            raise BadInputError(
                f"{path} does not store the image size; give it (CLI: --image-size WxH, Python: width=, "
                f"height=; the training images' size in pixels; the principal point suggests about "
                f"{2 * k0[0, 2] + 1:.0f}x{2 * k0[1, 2] + 1:.0f})")
        width = size[0] if width is None else width
        height = size[1] if height is None else height
    require(int(width) > 0 and int(height) > 0, f"image size must be positive, got {width}x{height}")

    scale_key = "scale_mat_0"
    if scale_key in data:
        scale_mat = check_similarity(_as_matrix(data[scale_key], scale_key, path), f"{path}: {scale_key}")
    else:
        scale_mat = np.eye(4)
    c2ws, fx, fy, cx, cy = [], [], [], [], []
    flip = np.diag([1.0, -1.0, -1.0])  # OpenCV camera axes (x right, y down, z forward) -> OpenGL
    for i in ids:
        p = _as_matrix(data[f"world_mat_{i}"], f"world_mat_{i}", path)
        require(abs(np.linalg.det(p[:3, :3])) > 1e-12, f"{path}: world_mat_{i} is singular (not a camera projection)")
        k, r, t = decompose_projection(p)
        require(k[0, 0] > 0 and k[1, 1] > 0, f"{path}: world_mat_{i} gives a non-positive focal length")
        c2w = np.eye(4)
        c2w[:3, :3] = r.T @ flip
        c2w[:3, 3] = -r.T @ t
        c2ws.append(c2w)
        fx.append(k[0, 0])
        fy.append(k[1, 1])
        cx.append(k[0, 2] + 0.5)
        cy.append(k[1, 2] + 0.5)
    cams = Cameras(torch.as_tensor(np.stack(c2ws), dtype=torch.float32), fx, fy, cx, cy, int(width), int(height))
    return cams, scale_mat


def write_neus_npz(path, cameras: Cameras, scale_mat: np.ndarray) -> None:
    """Write ``cameras`` (world frame, ours) and ``scale_mat`` as a NeuS ``cameras_sphere.npz``
    (``world_mat_i`` = K [R | t] in world units, ``scale_mat_i`` = scale_mat for every i)."""
    scale_mat = check_similarity(scale_mat)
    arrays = {}
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    for i in range(len(cameras)):
        k = np.array([[float(cameras.fx[i]), 0.0, float(cameras.cx[i]) - 0.5],
                      [0.0, float(cameras.fy[i]), float(cameras.cy[i]) - 0.5],
                      [0.0, 0.0, 1.0]])
        c2w_cv = cameras.c2w[i].double().numpy() @ flip
        arrays[f"world_mat_{i}"] = projection_from_camera(k, c2w_cv)
        arrays[f"scale_mat_{i}"] = scale_mat.copy()
    np.savez(path, **arrays)
