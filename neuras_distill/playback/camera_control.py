"""Interactive camera of the window player (``playback/window.py``): orbit, pan, zoom, fly and reset, as pure
numpy on a camera-to-world matrix, so every motion is testable without a display.

Frames: ``c2w`` is a (4, 4) float64 camera-to-world matrix in the OpenGL convention of ``render/cameras.py``
(camera x right, y up, looking down -z), in world coordinates. ``pivot`` is the distance along the view axis to
the point the camera orbits and zooms about (the target). ``world_up`` is the unit vector orbits turn about
(the mean up vector of the run's cameras, so a scene shot with +y or +z up both orbit level).

Motions keep the camera's roll: an orbit rotates the whole frame about the target (yaw about ``world_up``, then
pitch about the camera's right axis, refused where it would pass over the pole), so the first frame is exactly
the start camera and ``reset`` returns to it bit for bit.
"""

from __future__ import annotations

import math

import numpy as np

#: Radians of turn per pixel of mouse drag (orbit and look).
TURN_PER_PIXEL = 0.005
#: Zoom factor per scroll step (pivot distance multiplied by it, or divided).
ZOOM_PER_STEP = 0.9
#: Orbits stop this close (cosine of the angle) to looking straight along ``world_up``.
MAX_POLE_COSINE = 0.995


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about the unit vector ``axis`` (right-handed, Rodrigues)."""
    x, y, z = np.asarray(axis, np.float64) / max(float(np.linalg.norm(axis)), 1e-12)
    c, s = math.cos(angle), math.sin(angle)
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


class CameraController:
    """The window's camera. ``c2w`` (4, 4) float64 world; every method moves it in place.

    Args:
        c2w: start pose, (4, 4) or (3, 4), OpenGL convention, world frame.
        pivot: distance from the camera to its orbit target along the view axis (> 0).
        world_up: (3,) vector orbits turn about (normalised here).
        speed: fly speed in world units per second (WASD).
    """

    def __init__(self, c2w, pivot: float, world_up=(0.0, 0.0, 1.0), speed: float = 1.0):
        pose = np.eye(4)
        pose[:3] = np.asarray(c2w, np.float64).reshape(-1, 4)[:3]
        self.start = pose.copy()
        self.start_pivot = max(float(pivot), 1e-6)
        self.world_up = np.asarray(world_up, np.float64) / max(float(np.linalg.norm(world_up)), 1e-12)
        self.speed = float(speed)
        self.c2w = pose
        self.pivot = self.start_pivot

    # --------------------------------------------------------------- the camera's frame
    @property
    def eye(self) -> np.ndarray:
        """(3,) camera centre, world."""
        return self.c2w[:3, 3].copy()

    @property
    def forward(self) -> np.ndarray:
        """(3,) unit view direction (camera -z), world."""
        return -self.c2w[:3, 2]

    @property
    def target(self) -> np.ndarray:
        """(3,) the point orbits turn about: ``pivot`` in front of the eye."""
        return self.eye + self.pivot * self.forward

    # --------------------------------------------------------------- motions
    def _rotate(self, rot: np.ndarray, about: np.ndarray) -> None:
        self.c2w[:3, :3] = rot @ self.c2w[:3, :3]
        self.c2w[:3, 3] = about + rot @ (self.c2w[:3, 3] - about)

    def _turn(self, dx: float, dy: float, about: np.ndarray) -> None:
        """Yaw by ``-dx`` pixels about ``world_up`` and pitch by ``-dy`` about the camera's right axis, both
        through the point ``about``; the pitch is dropped when it would tip the view past the pole."""
        self._rotate(rotation_about(self.world_up, -dx * TURN_PER_PIXEL), about)
        pitch = rotation_about(self.c2w[:3, 0], -dy * TURN_PER_PIXEL)
        if abs(float(np.dot(pitch @ self.forward, self.world_up))) < MAX_POLE_COSINE:
            self._rotate(pitch, about)

    def orbit(self, dx: float, dy: float) -> None:
        """Drag by (dx, dy) pixels (x right, y down): turn around the target, keeping the distance to it."""
        self._turn(dx, dy, self.target)

    def look(self, dx: float, dy: float) -> None:
        """Drag by (dx, dy) pixels in fly mode: turn the view around the eye (the target moves)."""
        self._turn(-dx, -dy, self.eye)

    def pan(self, dx: float, dy: float, fy: float) -> None:
        """Drag by (dx, dy) pixels: slide the camera in its image plane so the target follows the cursor (``fy``
        the focal length in pixels: one pixel at the target's depth is ``pivot / fy`` world units)."""
        scale = self.pivot / max(float(fy), 1e-6)
        self.c2w[:3, 3] += -dx * scale * self.c2w[:3, 0] + dy * scale * self.c2w[:3, 1]

    def zoom(self, steps: float) -> None:
        """Scroll by ``steps`` (positive: closer): the pivot distance shrinks by ``ZOOM_PER_STEP`` per step and
        the eye moves along the view axis so the target stays put."""
        target = self.target
        self.pivot = max(self.pivot * ZOOM_PER_STEP ** float(steps), 1e-6)
        self.c2w[:3, 3] = target - self.pivot * self.forward

    def fly(self, forward: float, right: float, up: float, seconds: float) -> None:
        """Move the eye (and the target with it) by ``speed * seconds`` along the view axis, the camera's right
        axis and ``world_up``, each weighted by its argument in [-1, 1] (W/S, D/A, E/Q)."""
        step = self.speed * float(seconds)
        self.c2w[:3, 3] += step * (forward * self.forward + right * self.c2w[:3, 0] + up * self.world_up)

    def reset(self) -> None:
        """Back to the start pose and pivot."""
        self.c2w = self.start.copy()
        self.pivot = self.start_pivot


def mean_up(c2w: np.ndarray) -> np.ndarray:
    """(3,) unit mean of the cameras' up axes (camera +y) of (N, 4, 4) poses: the world up a set of cameras
    was shot with."""
    up = np.asarray(c2w, np.float64)[:, :3, 1].sum(axis=0)
    n = float(np.linalg.norm(up))
    return up / n if n > 1e-9 else np.array([0.0, 0.0, 1.0])


def pivot_distance(c2w: np.ndarray, centre: np.ndarray, radius: float) -> float:
    """Distance along the view axis of the pose ``c2w`` (4, 4) to the point nearest ``centre`` (3,): the
    orbit target of a start camera looking at the scene; at least ``0.1 * radius`` (a camera inside the
    scene's bounds still orbits something nearby)."""
    c2w = np.asarray(c2w, np.float64)
    along = float(np.dot(np.asarray(centre, np.float64) - c2w[:3, 3], -c2w[:3, 2]))
    return max(along, 0.1 * max(float(radius), 1e-6))


__all__ = ["CameraController", "rotation_about", "mean_up", "pivot_distance", "TURN_PER_PIXEL",
           "ZOOM_PER_STEP"]
