"""The Instant-NGP adapter: NeRF snapshots (``.ingp`` gzip(msgpack), ``.msgpack``), recognised by content.

``sniff`` is :func:`.snapshot.sniff_snapshot` (docs/formats.md §1.1: magic bytes, then the root map's
``snapshot`` key in at most the first 64 KiB inflated; 3DGRUT's Gaussian-particle ``.ingp`` files have
``nre_data`` instead and are not claimed). ``load`` returns an :class:`~.field.NgpField` in the frame of the
user's transforms.json.
"""

from __future__ import annotations

from pathlib import Path


class InstantNGPAdapter:
    name = "instant_ngp"

    def sniff(self, path) -> bool:
        from .snapshot import sniff_snapshot

        return sniff_snapshot(path)

    def load(self, path, *, foreground_box=None, latent_view=0, **options):
        """Options: ``foreground_box`` (2, 3) world box overriding the automatic one; ``latent_view`` the
        training image whose latent code is rendered (default 0, as instant-ngp) or ``"mean"``."""
        from neuras_distill.errors import require

        from .field import NgpField
        from .snapshot import read_snapshot

        require(not options, f"unknown Instant-NGP options: {', '.join(sorted(options))}")
        return NgpField(read_snapshot(Path(path)), foreground_box=foreground_box, latent_view=latent_view)
