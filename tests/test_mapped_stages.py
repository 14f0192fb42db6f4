"""Large per-pixel stages (G-buffers, teacher renders, the shader's view inputs) are written to the work area view by
view and used memory-mapped, not held whole in memory."""

from __future__ import annotations

import numpy as np
import pytest

from neuras_distill.geometry.mesh import MeshData
from neuras_distill.pipeline.cache import StageCache
from neuras_distill.pipeline.stage_results import load_gbuffer
from neuras_distill.render.cameras import Cameras


def _plane_and_cameras():
    verts = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    uvs = np.array([[0.1, 0.1], [0.9, 0.1], [0.9, 0.9], [0.1, 0.9]])
    mesh = MeshData(verts, [[0, 1, 2], [0, 2, 3]], uvs)
    cameras = Cameras.orbit([0.0, 0.0, 0.0], 3.0, 3, width=48, height=32, elevation_deg=50.0)
    return mesh, cameras


@pytest.mark.gl
def test_gbuffer_written_to_files_equals_the_one_in_memory(tmp_path):
    from neuras_distill.playback.rasterize import rasterize_gbuffer

    mesh, cameras = _plane_and_cameras()
    in_memory = rasterize_gbuffer(mesh, cameras)
    written = rasterize_gbuffer(mesh, cameras, out=tmp_path)
    loaded = load_gbuffer(tmp_path, mmap=True)
    assert 0.05 < in_memory.coverage.mean() < 0.95           # the plane covers part of every view
    for name in ("uv", "face_id", "coverage", "depth", "normal"):
        a, b, c = getattr(in_memory, name), getattr(written, name), getattr(loaded, name)
        assert isinstance(c, np.memmap) and c.dtype == a.dtype and c.shape == a.shape
        assert np.array_equal(a, b) and np.array_equal(a, c), name
    assert np.isinf(loaded.depth[~loaded.coverage]).all() and (loaded.face_id[~loaded.coverage] == -1).all()


def test_cached_files_writes_once_and_returns_the_mapped_files(tmp_path):
    writes = []

    def write(folder):
        writes.append(folder)
        out = np.lib.format.open_memmap(folder / "x.npy", mode="w+", dtype=np.float32, shape=(4, 5))
        for i in range(4):                                    # filled row by row, as the stages fill views
            out[i] = np.arange(5) + 10 * i
        out.flush()

    def load(folder):
        return np.load(folder / "x.npy", mmap_mode="c")

    cache = StageCache(tmp_path / "work", log=lambda line: None)
    first = cache.cached_files("gbuffer", "k", write, load)
    second = cache.cached_files("gbuffer", "k", write, load)
    expected = np.arange(5)[None] + 10 * np.arange(4)[:, None]
    assert len(writes) == 1 and cache.reused == ["gbuffer"]
    assert isinstance(first, np.memmap) and np.array_equal(first, expected) and np.array_equal(second, expected)
    second[0, 0] = -1.0                                       # copy-on-write: the stored file is unchanged
    assert np.load(tmp_path / "work" / "gbuffer" / "k" / "x.npy")[0, 0] == 0.0
