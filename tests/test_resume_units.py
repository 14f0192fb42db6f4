"""Resumable runs, the parts: training checkpoints continue bit for bit, stored stages are reused only when
they are whole, and the run folder finds what a killed run left."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from test_neural import synthetic_gbuffer

from neuras_distill.config import TrainConfig
from neuras_distill.errors import BadInputError
from neuras_distill.neural.model import NeuralTextureModel
from neuras_distill.neural.train import fit
from neuras_distill.neural.train_batches import TrainingPixels
from neuras_distill.neural.train_checkpoint import TrainCheckpoint
from neuras_distill.pipeline.cache import StageCache, digest, field_fingerprint, load_arrays, save_arrays
from neuras_distill.pipeline.rundir import MARKER, RunFolder

pytestmark = pytest.mark.usefixtures("one_torch_thread")


class _Killed(Exception):
    pass


class _KillAfterSaving(TrainCheckpoint):
    """Saves every step (``every_s`` 0) and raises once the state of step ``at`` is on disk: a kill."""

    def __init__(self, path, identity, at: int):
        super().__init__(path, identity, every_s=0.0)
        self.at = at

    def save(self, state: dict) -> None:
        super().save(state)
        if state["step"] >= self.at:
            raise _Killed(state["step"])


SMALL = TrainConfig(batch_patches=2, patch=8)


def _model():
    torch.manual_seed(0)
    return NeuralTextureModel(16, 16, feature_dim=4, num_codes=16, hidden=8, num_layers=2)


def test_training_resumed_from_a_checkpoint_ends_bit_identical(tmp_path):
    data = synthetic_gbuffer(n=2, res=16)
    kwargs = dict(steps=60, config=TrainConfig(batch_patches=2, patch=8, seed=3), progress=False, num_threads=1)
    whole = _model()
    log_whole = fit(whole, TrainingPixels(*data), **kwargs)

    path = tmp_path / "ckpt.pt"
    killed = _model()
    with pytest.raises(_Killed):
        fit(killed, TrainingPixels(*data), checkpoint=_KillAfterSaving(path, "k", at=25), **kwargs)
    assert path.is_file() and not list(tmp_path.glob(".*tmp*"))       # written atomically

    resumed = _model()                       # a new process: a fresh model, same constructor
    log = fit(resumed, TrainingPixels(*data), checkpoint=TrainCheckpoint(path, "k", every_s=1e9), **kwargs)
    assert log.resumed_from_step == 25 and log.steps == 60 and log_whole.resumed_from_step is None
    assert [e["step"] for e in log.entries] == [e["step"] for e in log_whole.entries]
    for (name, a), b in zip(whole.state_dict().items(), resumed.state_dict().values()):
        assert torch.equal(a, b), name


def test_a_checkpoint_of_other_settings_or_a_corrupt_one_is_not_resumed(tmp_path):
    data = synthetic_gbuffer(n=1, res=16)
    path = tmp_path / "ckpt.pt"
    with pytest.raises(_Killed):
        fit(_model(), TrainingPixels(*data), steps=20, config=SMALL, progress=False, checkpoint=_KillAfterSaving(path, "a", 5))
    lines = []
    log = fit(_model(), TrainingPixels(*data), steps=20, config=SMALL, progress=False,
              checkpoint=TrainCheckpoint(path, "b", every_s=1e9, log=lines.append))
    assert log.resumed_from_step is None and "other inputs or settings" in lines[0]
    path.write_bytes(b"PK\x03\x04 not a checkpoint")
    log = fit(_model(), TrainingPixels(*data), steps=20, config=SMALL, progress=False,
              checkpoint=TrainCheckpoint(path, "b", every_s=1e9, log=lines.append))
    assert log.resumed_from_step is None and "unreadable" in lines[1] and not path.exists()


def test_digest_follows_exactly_the_inputs():
    a = np.arange(6, dtype=np.float32).reshape(2, 3)
    assert digest("x", {"b": 1, "a": a}) == digest("x", {"a": a.copy(), "b": 1})       # key order, copies
    assert digest("x", {"a": a}) != digest("x", {"a": a + 1e-6})
    assert digest("x", {"a": a}) != digest("x", {"a": a.astype(np.float64)})
    assert digest(torch.ones(3)) != digest(torch.ones(4)) and digest(1) != digest(1.0)


def test_field_fingerprint_sees_parameters_and_source_digest():
    from neuras_distill.scenes.analytic import SphereSDF

    assert field_fingerprint(SphereSDF(radius=0.5)) == field_fingerprint(SphereSDF(radius=0.5))
    assert field_fingerprint(SphereSDF(radius=0.5)) != field_fingerprint(SphereSDF(radius=0.51))
    net = torch.nn.Linear(3, 4)
    first = field_fingerprint(net)
    with torch.no_grad():
        net.weight[0, 0] += 1e-4
    assert field_fingerprint(net) != first
    class Loaded:                    # what an adapter returns: the checkpoint's digest stands for its state
        def __init__(self, digest_, weight):
            self.source_digest, self.weight = digest_, weight

    assert field_fingerprint(Loaded("sha256:abc", 1.0)) == field_fingerprint(Loaded("sha256:abc", 2.0))
    assert field_fingerprint(Loaded("sha256:abc", 1.0)) != field_fingerprint(Loaded("sha256:abd", 1.0))


def test_stage_cache_reuses_whole_stages_and_recomputes_damaged_ones(tmp_path):
    lines, calls = [], []

    def compute():
        calls.append(1)
        return np.arange(1000, dtype=np.float32)

    def save(x, folder):
        save_arrays(folder, x=x)

    def load(folder):
        return load_arrays(folder, "x")[0]

    cache = StageCache(tmp_path / "work", log=lines.append)
    assert np.array_equal(cache.cached("teacher", "k1", compute, save, load), np.arange(1000))
    assert np.array_equal(cache.cached("teacher", "k1", compute, save, load), np.arange(1000))
    assert len(calls) == 1 and cache.reused == ["teacher"]

    stored = tmp_path / "work" / "teacher" / "k1" / "x.npy"
    stored.write_bytes(stored.read_bytes()[:-8])                      # truncated
    cache.cached("teacher", "k1", compute, save, load)
    assert len(calls) == 2 and "truncated" in lines[-1]
    raw = bytearray(stored.read_bytes())
    raw[-1] ^= 0xFF                                                    # same size, other bytes
    stored.write_bytes(bytes(raw))
    cache.cached("teacher", "k1", compute, save, load)
    assert len(calls) == 3 and "checksum" in lines[-1]
    done = stored.parent / "done.json"
    info = json.loads(done.read_text())
    done.write_text(json.dumps({**info, "version": "0.0.1"}))          # another version's work area
    cache.cached("teacher", "k1", compute, save, load)
    assert len(calls) == 4 and "version 0.0.1" in lines[-1]
    (tmp_path / "work" / "teacher" / "k2").mkdir()                     # a killed write: no done.json
    cache.cached("teacher", "k2", compute, save, load)
    assert len(calls) == 5
    assert StageCache(tmp_path / "work", fresh=True).lookup("teacher", "k1") is None

    other = StageCache(tmp_path / "next", [tmp_path / "work"], log=lines.append)   # the previous run's area
    assert np.array_equal(other.cached("teacher", "k1", compute, save, load), np.arange(1000))
    assert len(calls) == 5 and (tmp_path / "next" / "teacher" / "k1" / "x.npy").is_file()
    other.prune({"teacher": "k9"})
    assert not (tmp_path / "next" / "teacher").exists()


def test_run_folder_keeps_finished_stages_of_a_failed_run_and_locks(tmp_path):
    out = tmp_path / "run"
    folder = RunFolder(out)
    with pytest.raises(RuntimeError):
        with folder as tmp:
            (tmp / "report.json").write_text("{}")
            StageCache(folder.work).store("teacher", "k", lambda f: (f / "a.npy").write_bytes(b"1"))
            with pytest.raises(BadInputError, match="another neuras-distill run is writing"):
                with RunFolder(out):
                    pass
            raise RuntimeError("killed")
    partial = tmp_path / ".run.partial"
    assert not out.exists() and sorted(p.name for p in partial.iterdir()) == [MARKER, "work"]

    again = RunFolder(out)
    with again as tmp:
        assert again.resumed_folder and StageCache(again.work).lookup("teacher", "k") is not None
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"] and (out / "work" / "teacher" / "k").is_dir()

    old_leftover = tmp_path / ".run.tmp-999999999-1"            # an earlier version's, its process long gone
    old_leftover.mkdir()
    (old_leftover / MARKER).write_text("{}")
    with RunFolder(out, keep_work=False) as tmp:
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"] and not (out / "work").exists()
