"""Which way is up in a glTF export: the rotation that stands a capture upright in glTF's +Y-up frame.

Owns: :data:`UP_CHOICES` (``export --up``), :func:`parse_up`, :func:`capture_up` (what ``auto`` means for a bundle)
and :func:`rotation_onto_y` / :func:`quaternion_xyzw` (the root node's rotation, ``export/gltf.py``).

Frames: the bundle's frame is the field's (z up for the embedded scenes, for nerfstudio's oriented datasets and
for most Instant-NGP captures). glTF's is +Y up. The export puts the bundle's node under a root node whose rotation
``R`` (3, 3) maps the capture's up ``u`` onto +Y: a point ``p`` of the field is at ``R @ p`` in the glTF scene.

Decisions (docs/decisions.md "An upright glTF"):

* ``R`` is the shortest-arc rotation from ``u`` to +Y, so nothing turns about the up axis: +z up gives
  (x, y, z) -> (x, z, -y), the inverse of what Blender's importer does (Blender shows the field's own
  coordinates). An up of -Y (antiparallel) turns half a turn about +x.
* ``auto`` is the mean up (camera +y) of the run's cameras (``cameras.json`` beside the bundle, train and held-out
  views), as the window's orbit uses (``playback/camera_control.mean_up``). A mean within
  :data:`SNAP_DEGREES` of an axis is that axis: captures are shot level to within a few degrees, and an axis keeps
  the scene's horizontal planes exactly horizontal and its numbers round. Without cameras ``auto`` is +z, the
  frame of the orbit cameras the players fall back to.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import BadInputError

#: ``export --up`` values: ``auto`` (:func:`capture_up`) or an axis of the bundle's frame.
UP_CHOICES = ("auto", "+x", "-x", "+y", "-y", "+z", "-z")
#: A cameras' mean up within this many degrees of an axis is taken as that axis.
SNAP_DEGREES = 15.0

_AXES = {f"{sign}{name}": (1.0 if sign == "+" else -1.0) * np.eye(3)[i]
         for i, name in enumerate("xyz") for sign in "+-"}


def parse_up(text: str) -> str:
    """``text`` if it is one of :data:`UP_CHOICES`, else BadInputError naming them."""
    value = str(text).strip().lower()
    if value not in UP_CHOICES:
        raise BadInputError(f"--up {text!r} is not an axis: use one of {', '.join(UP_CHOICES)}")
    return value


def axis_vector(name: str) -> np.ndarray:
    """(3,) float64 unit vector of an axis name (``+x`` ... ``-z``)."""
    return _AXES[name].copy()


def snapped_up(mean: np.ndarray) -> tuple[np.ndarray, str]:
    """(up (3,) unit, its name): the axis nearest ``mean`` (3,) when within :data:`SNAP_DEGREES`, else ``mean``
    normalised (named by its components)."""
    mean = np.asarray(mean, np.float64).reshape(3)
    mean = mean / max(float(np.linalg.norm(mean)), 1e-30)
    name = max(_AXES, key=lambda k: float(_AXES[k] @ mean))
    if float(_AXES[name] @ mean) >= np.cos(np.radians(SNAP_DEGREES)):
        return axis_vector(name), name
    return mean, "(" + ", ".join(f"{x:.3f}" for x in mean) + ")"


def capture_up(bundle_path: Path) -> tuple[np.ndarray, str]:
    """(up (3,) unit in the bundle's frame, where it comes from) for ``--up auto``: the snapped mean up of the
    cameras in ``cameras.json`` beside the bundle (a folder or a .glb), else +z. BadInputError when that file is
    not a run's."""
    from ..playback.camera_control import mean_up
    from ..render.cameras import Cameras

    path = Path(bundle_path).resolve().parent / "cameras.json"
    if not path.is_file():
        return axis_vector("+z"), "+z (no cameras.json beside the bundle)"
    try:
        data = json.loads(path.read_text("utf-8"))
        c2w = np.concatenate([Cameras.from_json(data[k]).c2w.double().numpy() for k in ("train", "test")
                              if k in data])
    except (ValueError, KeyError, TypeError, UnicodeDecodeError) as exc:
        raise BadInputError(f"{path} is not a cameras.json of a run ({exc.__class__.__name__}: {exc}); "
                            "fix or remove it, or give --up an axis") from None
    up, name = snapped_up(mean_up(c2w))
    return up, f"{name} (the mean up of {len(c2w)} cameras in {path.name})"


def resolve_up(choice: str, bundle_path: Path) -> tuple[np.ndarray, str]:
    """(up (3,) unit, a description) of an ``--up`` value for the bundle at ``bundle_path``."""
    choice = parse_up(choice)
    if choice == "auto":
        return capture_up(bundle_path)
    return axis_vector(choice), choice


def rotation_onto_y(up: np.ndarray) -> np.ndarray:
    """(3, 3) float64 rotation taking the unit vector ``up`` (3,) onto +Y by the shortest arc (half a turn about
    +x when ``up`` is -Y)."""
    u = np.asarray(up, np.float64).reshape(3)
    u = u / max(float(np.linalg.norm(u)), 1e-30)
    y = np.array([0.0, 1.0, 0.0])
    c = float(u @ y)
    if c < -1.0 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    v = np.cross(u, y)
    k = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    r = np.eye(3) + k + k @ k / (1.0 + c)
    r[np.abs(r) < 1e-15] = 0.0
    return r


def quaternion_xyzw(r: np.ndarray) -> list[float]:
    """glTF's unit quaternion [x, y, z, w] of the rotation matrix ``r`` (3, 3)."""
    r = np.asarray(r, np.float64)
    w = np.sqrt(max(0.0, 1.0 + r[0, 0] + r[1, 1] + r[2, 2])) / 2.0
    x = np.sqrt(max(0.0, 1.0 + r[0, 0] - r[1, 1] - r[2, 2])) / 2.0
    y = np.sqrt(max(0.0, 1.0 - r[0, 0] + r[1, 1] - r[2, 2])) / 2.0
    z = np.sqrt(max(0.0, 1.0 - r[0, 0] - r[1, 1] + r[2, 2])) / 2.0
    x = np.copysign(x, r[2, 1] - r[1, 2])
    y = np.copysign(y, r[0, 2] - r[2, 0])
    z = np.copysign(z, r[1, 0] - r[0, 1])
    q = np.array([x, y, z, w])
    q /= np.linalg.norm(q)
    return [float(c) for c in q]


__all__ = ["SNAP_DEGREES", "UP_CHOICES", "axis_vector", "capture_up", "parse_up", "quaternion_xyzw",
           "resolve_up", "rotation_onto_y", "snapped_up"]
