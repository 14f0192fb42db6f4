"""MP4 video from rendered frames (this module owns every PyAV call).

Codec: H.264 (libx264, which PyAV's wheels carry with FFmpeg), pixel format yuv420p (what browsers, phones and
editors play), constant quality ``crf`` (:data:`CRF`, visually lossless for rendered frames), in an MP4
container with ``+faststart`` (the index first, so a browser starts playing before the file has loaded).
yuv420p needs an even width and height: an odd one is padded by repeating the last column or row.
The file is written next to its destination and moved into place when complete.
"""

from __future__ import annotations

import os
from fractions import Fraction
from pathlib import Path
from typing import Iterable

import numpy as np

from ..errors import BadInputError

#: libx264's constant-quality factor (0 lossless .. 51; 18 is usually called visually lossless; 12 keeps rendered
#: frames within yuv420p's own loss: its half-resolution colour, not the quantiser, bounds the error).
CRF = 12
#: The codec, the pixel format and the container, as the report and the docs name them.
CODEC, PIXEL_FORMAT, CONTAINER = "h264", "yuv420p", "mp4"


def _av():
    """The PyAV module, imported on first use; one line naming the fix where it is not installed."""
    try:
        import av  # noqa: PLC0415
    except ImportError:
        raise BadInputError("writing .mp4 needs PyAV (pip install av: its wheels carry FFmpeg); or pass --out "
                            "a folder for PNG frames") from None
    return av


def even_frame(frame: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 padded to an even height and width by repeating the last row / column."""
    h, w = frame.shape[:2]
    return np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge") if (h % 2 or w % 2) else frame


def write_mp4(frames: Iterable[np.ndarray], path: str | Path, fps: float) -> dict:
    """Encode ``frames`` into ``path``.

    Args:
        frames: (H, W, 3) uint8 RGB images, top row first, all one size.
        path: the .mp4 to write (replaced atomically; its folder is created).
        fps: frames per second (a rational close to it is used for the time base).
    Returns:
        ``{"frames", "width", "height", "fps", "codec", "pixel_format", "crf"}`` of the written file.
    """
    av = _av()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.partial.mp4")
    rate = Fraction(fps).limit_denominator(1001)
    count, size = 0, None
    try:
        with av.open(str(tmp), mode="w", format=CONTAINER, options={"movflags": "+faststart"}) as container:
            stream = None
            for frame in frames:
                img = even_frame(np.ascontiguousarray(frame, dtype=np.uint8))
                if stream is None:
                    size = img.shape[:2]
                    stream = container.add_stream("libx264", rate=rate)
                    stream.width, stream.height = int(size[1]), int(size[0])
                    stream.pix_fmt = PIXEL_FORMAT
                    stream.options = {"crf": str(CRF), "preset": "medium"}
                elif img.shape[:2] != size:
                    raise BadInputError(f"frame {count} is {img.shape[1]}x{img.shape[0]}, not {size[1]}x{size[0]}: "
                                        "a video's frames share one size")
                for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                    container.mux(packet)
                count += 1
            if stream is None:
                raise BadInputError("no frames to write: the camera path is empty")
            for packet in stream.encode():
                container.mux(packet)
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)
    return {"frames": count, "width": int(size[1]), "height": int(size[0]), "fps": float(rate),
            "codec": CODEC, "pixel_format": PIXEL_FORMAT, "crf": CRF}
