"""The NeuS-family adapter: Totoro97/NeuS ``ckpt_*.pth`` and instant-nsr-pl ``*.ckpt`` SDF checkpoints.

Recognised by content, not extension: a zip-format torch checkpoint whose pickle (``data.pkl``, read without
loading any tensor, by :func:`neuras_distill.fields.checkpoint.inspect_torch_zip`) mentions
``sdf_network_fine`` (NeuS) or ``geometry.encoding.encoding.params`` / ``variance.variance`` (instant-nsr-pl).
Loading is :func:`.loader.load_neus_checkpoint`.
"""

from __future__ import annotations

from neuras_distill.errors import BadInputError

MARKERS = (b"sdf_network_fine", b"geometry.encoding.encoding.params", b"variance.variance")
EXTRA_OPTIONS = ("beta", "scale_mat", "background_color", "bound", "sdf_scale", "chunk")


class NeuSAdapter:
    name = "neus"

    def sniff(self, path) -> bool:
        from neuras_distill.fields.checkpoint import inspect_torch_zip

        try:
            _, pickle_bytes = inspect_torch_zip(path)
        except (BadInputError, OSError):
            return False
        return any(m in pickle_bytes for m in MARKERS)

    def load(self, path, cameras=None, config=None, density: str = "neus", width: int | None = None,
             height: int | None = None, **options):
        """Options: ``cameras`` (cameras_sphere.npz or transforms.json path), ``config`` (instant-nsr-pl
        parsed.yaml/JSON path or dict), ``density`` ("neus" | "laplace"), ``width``/``height`` (image size
        for cameras_sphere.npz), and ``beta``, ``scale_mat``, ``background_color``, ``bound``, ``sdf_scale``,
        ``chunk`` (see :func:`~.loader.load_neus_checkpoint`)."""
        from .loader import load_neus_checkpoint

        unknown = sorted(set(options) - set(EXTRA_OPTIONS))
        if unknown:
            raise BadInputError(f"unknown option(s) {', '.join(unknown)} for the neus adapter; it takes cameras, "
                                f"config, density, width, height, {', '.join(EXTRA_OPTIONS)}")
        return load_neus_checkpoint(path, cameras=cameras, config=config, density=density, width=width,
                                    height=height, **options)
