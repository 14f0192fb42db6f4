"""The real-time window player: ``neuras-distill view BUNDLE`` (this module is the only one that imports glfw).

Why glfw: one small wheel that carries its own libglfw, gives a GL 3.3 core context that moderngl adopts as is,
and raw mouse/keyboard callbacks; moderngl-window would add a framework (its own event loop, resource loaders,
several more dependencies) around the three calls we need. The frame is drawn by the same ``BundleRenderer`` as
every headless player (same programs, passes and framebuffers) and blitted 1:1 to the window, so what the window
shows is bit for bit what ``render`` returns for the same camera.

Controls (also printed by ``H``):
    left drag: orbit the target     right drag: look around (fly)     middle drag / shift + left drag: pan
    scroll: zoom to the target      W A S D: fly, Q E: down / up (shift: 4x faster)
    R: reset to the start camera    N / P: next / previous held-out camera
    1 2 3 4: neural shader / plain RGB texture / UV charts / codebook index      K: skybox pass on / off
    H: print this help              Esc: quit

The window has the start camera's size (scaled down to fit the screen, aspect kept, intrinsics scaled with it)
and does not resize: a different aspect would need other intrinsics than the run's cameras. The title shows the
mode, the draw time (median of the last 30 frames, GPU finished) and the frames per second.
"""

from __future__ import annotations

import os
import time
from collections import deque
from pathlib import Path

import numpy as np

from ..errors import BadInputError
from .camera_control import CameraController, mean_up, pivot_distance
from .context import adopt_current_context
from .projection import mesh_bounds
from .view_modes import VIEW_MODES, mode_bundle

#: Frames drawn at the start camera before ``--screenshot`` reads the window back (the first swaps of some
#: drivers show an undefined buffer).
SCREENSHOT_FRAMES = 3
#: The window may take at most this fraction of the screen per side.
SCREEN_FRACTION = 0.9

HELP = __doc__.split("Controls (also printed by ``H``):\n", 1)[1].split("\n\n", 1)[0]

_MODE_KEYS = dict(zip("1234", VIEW_MODES))


def no_display_reason() -> str | None:
    """Why no window can open here (no X11 or Wayland display named in the environment), or None."""
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return None
    return "no display to open a window on (DISPLAY is not set)"


def _display_hint() -> str:
    return ("render PNG frames headless with `neuras-distill view BUNDLE --orbit`, or run the window in a virtual "
            "display: `xvfb-run -a neuras-distill view BUNDLE`")


def _import_glfw():
    try:
        import glfw  # noqa: PLC0415 (lazy: the headless parts never need it)
    except Exception as exc:  # ImportError, or the bundled libglfw failing to load
        raise BadInputError(f"the window player needs glfw ({exc}): pip install glfw; or "
                            f"{_display_hint()}") from None
    glfw.ERROR_REPORTING = "ignore"      # errors are read with glfw.get_error() and reported as one line
    return glfw


def _glfw_error(glfw) -> str:
    code, text = glfw.get_error()
    return text.decode("utf-8", "replace") if code and text else "no reason given"


def fit_to_screen(width: int, height: int, screen: tuple[int, int]) -> float:
    """Scale (<= 1) that fits a ``width`` x ``height`` window into ``SCREEN_FRACTION`` of ``screen`` (w, h)."""
    limit = min(SCREEN_FRACTION * screen[0] / width, SCREEN_FRACTION * screen[1] / height)
    return min(1.0, limit) if limit > 0 else 1.0


def camera_at(c2w: np.ndarray, intrinsics: tuple[float, float, float, float], width: int, height: int):
    """One world ``Cameras`` with pose ``c2w`` (4, 4), ``intrinsics`` (fx, fy, cx, cy) in pixels, size w x h."""
    from ..render.cameras import Cameras  # noqa: PLC0415 (torch; lazy)

    fx, fy, cx, cy = intrinsics
    return Cameras(np.asarray(c2w, np.float32)[None], fx, fy, cx, cy, int(width), int(height))


class WindowPlayer:
    """A glfw window that plays ``bundle`` from held-out camera ``index`` of ``cameras`` (world frame).

    Args:
        bundle: a loaded ``Bundle``.
        cameras: ``Cameras`` to start from (:func:`viewer.start_cameras`); N / P step through them.
        index: the start camera.
        mode: a ``VIEW_MODES`` key to start in; skybox: whether the skybox pass runs.
        title: the window title's prefix.
    """

    def __init__(self, bundle, cameras, index: int = 0, *, mode: str = "neural", skybox: bool = True,
                 title: str = "neuras-distill"):
        if not 0 <= index < len(cameras):
            raise BadInputError(f"--camera {index} is out of range: there are {len(cameras)} held-out cameras")
        mode_bundle(bundle, mode)           # an unknown mode or a missing plain texture fails before any window
        reason = no_display_reason()
        if reason:
            raise BadInputError(f"{reason}: {_display_hint()}")
        self.glfw = _import_glfw()
        self.bundle, self.cameras, self.index = bundle, cameras, int(index)
        self.mode, self.skybox, self.title = mode, bool(skybox), title
        lo, hi = mesh_bounds(bundle.mesh.vertices)
        self.centre = 0.5 * (lo + hi) + bundle.origin
        self.radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-6)
        self.window = None
        self.renderers: dict = {}
        self.draw_ms: deque = deque(maxlen=30)
        self.message = ""
        self._open()
        self._start_at(self.index)

    # ------------------------------------------------------------------ window and context
    def _open(self) -> None:
        glfw = self.glfw
        if not glfw.init():
            raise BadInputError(f"cannot open a window on display {os.environ.get('DISPLAY', '?')!r} "
                                f"({_glfw_error(glfw)}): {_display_hint()}")
        w0, h0 = int(self.cameras.width), int(self.cameras.height)
        monitor = glfw.get_primary_monitor()
        mode = glfw.get_video_mode(monitor) if monitor else None
        scale = fit_to_screen(w0, h0, (mode.size.width, mode.size.height)) if mode else 1.0
        width, height = max(1, round(w0 * scale)), max(1, round(h0 * scale))
        for hint, value in ((glfw.CONTEXT_VERSION_MAJOR, 3), (glfw.CONTEXT_VERSION_MINOR, 3),
                            (glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE), (glfw.OPENGL_FORWARD_COMPAT, True),
                            (glfw.RESIZABLE, False)):
            glfw.window_hint(hint, value)
        self.window = glfw.create_window(width, height, self.title, None, None)
        if not self.window:
            reason = _glfw_error(glfw)
            glfw.terminate()
            raise BadInputError(f"cannot open an OpenGL 3.3 core window ({reason}); install a GL driver (Mesa: "
                                f"apt-get install libgl1-mesa-dri libglx-mesa0) or {_display_hint()}")
        glfw.make_context_current(self.window)
        glfw.swap_interval(0)          # draw as fast as the bundle plays: the title shows the real frame time
        self.ctx = adopt_current_context()
        self.size = glfw.get_framebuffer_size(self.window)       # pixels (HiDPI screens: more than the window)
        self.scale = self.size[1] / h0
        glfw.set_cursor_pos_callback(self.window, self._on_cursor)
        glfw.set_mouse_button_callback(self.window, self._on_button)
        glfw.set_scroll_callback(self.window, self._on_scroll)
        glfw.set_key_callback(self.window, self._on_key)
        self._cursor = None

    def _renderer(self):
        """The (cached) ``BundleRenderer`` of the current mode, on the window's context."""
        from .renderer import BundleRenderer  # noqa: PLC0415

        if self.mode not in self.renderers:
            self.renderers[self.mode] = BundleRenderer(mode_bundle(self.bundle, self.mode), ctx=self.ctx)
        return self.renderers[self.mode]

    def _start_at(self, index: int) -> None:
        cams = self.cameras
        c2w = cams.c2w[index].double().numpy()
        s = self.scale
        self.intrinsics = (float(cams.fx[index]) * s, float(cams.fy[index]) * s, float(cams.cx[index]) * s,
                           float(cams.cy[index]) * s)
        self.control = CameraController(c2w, pivot_distance(c2w, self.centre, self.radius),
                                        mean_up(cams.c2w.double().numpy()), speed=0.5 * self.radius)
        self.index = index

    # ------------------------------------------------------------------ input
    def _on_cursor(self, _win, x: float, y: float) -> None:
        glfw = self.glfw
        if self._cursor is None:
            self._cursor = (x, y)
            return
        dx, dy = x - self._cursor[0], y - self._cursor[1]
        self._cursor = (x, y)
        left = glfw.get_mouse_button(self.window, glfw.MOUSE_BUTTON_LEFT) == glfw.PRESS
        shift = glfw.get_key(self.window, glfw.KEY_LEFT_SHIFT) == glfw.PRESS
        if glfw.get_mouse_button(self.window, glfw.MOUSE_BUTTON_MIDDLE) == glfw.PRESS or (left and shift):
            self.control.pan(dx, dy, self.intrinsics[1])
        elif left:
            self.control.orbit(dx, dy)
        elif glfw.get_mouse_button(self.window, glfw.MOUSE_BUTTON_RIGHT) == glfw.PRESS:
            self.control.look(dx, dy)

    def _on_button(self, *_args) -> None:
        self._cursor = None            # a new drag starts where the button went down

    def _on_scroll(self, _win, _dx: float, dy: float) -> None:
        self.control.zoom(dy)

    def _on_key(self, _win, key: int, _scancode: int, action: int, _mods: int) -> None:
        glfw = self.glfw
        if action != glfw.PRESS:
            return
        name = glfw.get_key_name(key, 0) or ""
        if key == glfw.KEY_ESCAPE:
            glfw.set_window_should_close(self.window, True)
        elif name in _MODE_KEYS:
            self.set_mode(_MODE_KEYS[name])
        elif name == "k":
            self.skybox = not self.skybox
            self.message = "skybox " + ("on" if self.skybox else "off")
        elif name == "r":
            self.control.reset()
        elif name in ("n", "p"):
            self._start_at((self.index + (1 if name == "n" else -1)) % len(self.cameras))
            self.message = f"held-out camera {self.index}"
        elif name == "h":
            from ..logs import say

            say(HELP)

    def set_mode(self, mode: str) -> None:
        """Switch the output to a ``VIEW_MODES`` key; a mode this bundle cannot show leaves the mode as is and
        says why in the title."""
        try:
            self.mode, previous = mode, self.mode
            self._renderer()
            self.message = VIEW_MODES[mode]
        except BadInputError as exc:
            self.mode = previous
            self.message = str(exc).split(":")[0]

    def _fly(self, seconds: float) -> None:
        glfw, win = self.glfw, self.window
        held = {k: glfw.get_key(win, getattr(glfw, f"KEY_{k}")) == glfw.PRESS for k in "WASDQE"}
        fast = 4.0 if glfw.get_key(win, glfw.KEY_LEFT_SHIFT) == glfw.PRESS else 1.0
        forward, right, up = held["W"] - held["S"], held["D"] - held["A"], held["E"] - held["Q"]
        if forward or right or up:
            self.control.fly(forward, right, up, fast * seconds)

    # ------------------------------------------------------------------ frames
    def draw_frame(self) -> None:
        """Draw the current camera with the current mode into the window's back buffer."""
        cams = camera_at(self.control.c2w, self.intrinsics, *self.size)
        renderer = self._renderer()
        t0 = time.perf_counter()
        frame = renderer.draw(cams, 0, skybox=self.skybox)
        self.ctx.finish()
        self.draw_ms.append(1000.0 * (time.perf_counter() - t0))
        self.ctx.copy_framebuffer(self.ctx.screen, frame)

    def read_screen(self) -> np.ndarray:
        """(H, W, 3) uint8 of the window's back buffer, top row first."""
        w, h = self.size
        data = self.ctx.screen.read(viewport=(0, 0, w, h), components=3, alignment=1)
        return np.frombuffer(data, np.uint8).reshape(h, w, 3)[::-1].copy()

    def _title(self, fps: float) -> str:
        ms = float(np.median(self.draw_ms)) if self.draw_ms else float("nan")
        sky = "" if not self.bundle.has_skybox else (" | sky on" if self.skybox else " | sky off")
        extra = f" | {self.message}" if self.message else ""
        return f"{self.title} | {self.mode} | {ms:.1f} ms/frame, {fps:.0f} fps{sky}{extra} | H: help"

    def run(self, screenshot: str | os.PathLike | None = None) -> Path | None:
        """Play until the window closes (Esc); with ``screenshot``, draw ``SCREENSHOT_FRAMES`` frames at the
        start camera, save the window's framebuffer there as PNG (written beside and renamed: never half a
        file), close and return the path."""
        glfw = self.glfw
        frames, last, fps_clock, fps_frames, fps = 0, time.perf_counter(), time.perf_counter(), 0, 0.0
        try:
            while not glfw.window_should_close(self.window):
                glfw.poll_events()
                now = time.perf_counter()
                if screenshot is None:
                    self._fly(now - last)
                last = now
                self.draw_frame()
                frames += 1
                if screenshot is not None and frames >= SCREENSHOT_FRAMES:
                    return _save_png(self.read_screen(), Path(screenshot))
                glfw.swap_buffers(self.window)
                fps_frames += 1
                if now - fps_clock >= 0.5:
                    fps, fps_clock, fps_frames = fps_frames / (now - fps_clock), now, 0
                    glfw.set_window_title(self.window, self._title(fps))
            return None
        finally:
            self.close()

    def close(self) -> None:
        for renderer in self.renderers.values():
            renderer.release()
        self.renderers.clear()
        if self.window is not None:
            self.glfw.destroy_window(self.window)
            self.window = None
            self.glfw.terminate()


def _save_png(image: np.ndarray, path: Path) -> Path:
    from PIL import Image  # noqa: PLC0415

    if path.suffix.lower() != ".png":
        raise BadInputError(f"--screenshot {path}: give a .png path")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    Image.fromarray(image, mode="RGB").save(tmp, format="PNG")
    os.replace(tmp, path)
    return path


def play_in_window(bundle, cameras, index: int = 0, *, mode: str = "neural", skybox: bool = True,
                   screenshot=None, title: str = "neuras-distill") -> Path | None:
    """Open the window player (:class:`WindowPlayer`) and run it; returns the screenshot path when one was asked."""
    if screenshot is not None and Path(screenshot).suffix.lower() != ".png":
        raise BadInputError(f"--screenshot {screenshot}: give a .png path")
    return WindowPlayer(bundle, cameras, index, mode=mode, skybox=skybox, title=title).run(screenshot)


__all__ = ["WindowPlayer", "play_in_window", "no_display_reason", "fit_to_screen", "camera_at", "HELP",
           "SCREENSHOT_FRAMES"]
