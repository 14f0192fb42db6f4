"""The nerfstudio adapter: a nerfacto run (``config.yml`` + ``nerfstudio_models/step-*.ckpt``), recognised by
content (docs/formats.md §3).

``sniff`` accepts a ``config.yml`` whose first 8 KiB name a nerfstudio ``TrainerConfig`` (or the older
``Config`` / ``ExperimentConfig`` roots). ``load`` reads the newest checkpoint with ``torch.load(weights_only=True)``
and only the numpy scalar globals nerfstudio's optimizer state holds (``fields.checkpoint.NUMPY_SCALAR_GLOBALS``),
and returns a :class:`~.field.NerfstudioField` in the dataset's frame.
"""

from __future__ import annotations

from pathlib import Path

_ROOTS = ("nerfstudio.engine.trainer.TrainerConfig", "nerfstudio.configs.base_config.Config",
          "nerfstudio.configs.experiment_config.ExperimentConfig")


class NerfstudioAdapter:
    name = "nerfstudio"

    def sniff(self, path) -> bool:
        path = Path(path)
        if path.is_dir():
            path = path / "config.yml"
        try:
            with open(path, "rb") as f:
                head = f.read(8192).decode("utf-8", errors="replace")
        except OSError:
            return False
        return any(root in head for root in _ROOTS) and "method_name" in head or (
            head.startswith("!!python/object:nerfstudio.") and "pipeline" in head)

    def load(self, path, *, foreground_box=None, appearance="mean", **options):
        """Options: ``foreground_box`` (2, 3) data-frame box overriding the automatic one; ``appearance``:
        "mean" (nerfstudio's evaluation), "zeros" or a training image's index."""
        from neuras_distill.errors import require
        from neuras_distill.fields.checkpoint import check_finite, load_torch_checkpoint

        from .field import NerfstudioField
        from .nerfacto import NerfactoNetwork, field_state
        from .run import find_run, nerfacto_settings

        require(not options, f"unknown nerfstudio options: {', '.join(sorted(options))}")
        run = find_run(path)
        settings = nerfacto_settings(run.config, str(run.config_path))
        ckpt = load_torch_checkpoint(run.checkpoint, numpy_scalars=True)
        pipeline = ckpt.get("pipeline")
        require(isinstance(pipeline, dict), f"{run.checkpoint} has no 'pipeline' state dict: not a nerfstudio "
                                            "checkpoint (nerfstudio saves step, pipeline, optimizers, scalers)")
        state = field_state(pipeline, str(run.checkpoint))
        check_finite(state, str(run.checkpoint))
        network = NerfactoNetwork(state, settings, appearance=appearance, source=str(run.checkpoint)).eval()
        field = NerfstudioField(run, network, settings, foreground_box=foreground_box)
        field.pose_adjustment = pose_adjustment(pipeline, settings, field.notes)
        return field


def pose_adjustment(pipeline: dict, settings, notes: list):
    """The camera optimizer's (K, 6) float64 pose corrections of the K training images (SO3xR3), or None when it
    was off or learned another kind (a note says so)."""
    import numpy as np

    key = next((k for k in pipeline if k.endswith("camera_optimizer.pose_adjustment")), None)
    if key is None or settings.camera_optimizer == "off":
        return None
    if settings.camera_optimizer != "SO3xR3":
        notes.append(f"camera optimizer mode {settings.camera_optimizer}: its pose corrections are not applied "
                     "(SO3xR3, nerfacto's default, is)")
        return None
    value = pipeline[key].detach().double().numpy()
    if value.ndim != 2 or value.shape[1] != 6 or not np.isfinite(value).all():
        notes.append(f"camera optimizer corrections of shape {tuple(value.shape)} or not finite: not applied")
        return None
    return value
