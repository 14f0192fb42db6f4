"""Adapter for Instant-NGP NeRF snapshots (``.ingp`` gzip(msgpack), ``.msgpack``), recognised by content.

``sniff`` decompresses at most the first 64 KiB and looks for the root map's ``snapshot`` key (3DGRUT's
Gaussian-particle ``.ingp`` files have ``nre_data`` instead and are not claimed). ``load`` returns an
:class:`~neuras_distill.fields.ngp.NgpField` in the frame of the user's transforms.json.
"""

from __future__ import annotations

import zlib
from pathlib import Path

HEAD_BYTES = 1 << 16


class InstantNGPAdapter:
    name = "instant_ngp"

    def sniff(self, path) -> bool:
        from neuras_distill.fields.ngp_snapshot import sniff_snapshot_kind

        try:
            with open(path, "rb") as f:
                raw = f.read(HEAD_BYTES)
        except OSError:
            return False
        kind = sniff_snapshot_kind(raw[:4])
        if kind is None:
            return False
        if kind != "msgpack":
            try:
                raw = zlib.decompressobj(16 + 15 if kind == "gzip" else 15).decompress(raw, HEAD_BYTES)
            except zlib.error:
                return False
            if not raw or not (0x80 <= raw[0] <= 0x8F or raw[0] in (0xDE, 0xDF)):
                return False
        return b"snapshot" in raw and b"nre_data" not in raw

    def load(self, path, *, foreground_box=None, latent_view=0, **options):
        """Options: ``foreground_box`` (2, 3) world box overriding the automatic one; ``latent_view`` the
        training image whose latent code is rendered (default 0, as instant-ngp) or ``"mean"``."""
        from neuras_distill.errors import require
        from neuras_distill.fields.ngp import NgpField
        from neuras_distill.fields.ngp_snapshot import read_snapshot

        require(not options, f"unknown Instant-NGP options: {', '.join(sorted(options))}")
        return NgpField(read_snapshot(Path(path)), foreground_box=foreground_box, latent_view=latent_view)
