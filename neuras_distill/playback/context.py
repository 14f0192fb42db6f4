"""Headless OpenGL context for the playback stage (G-buffer rasterization, bundle playback, viewer).

This module owns context creation: it is the only place that decides *how* a context is made (EGL first,
then moderngl's default standalone backend) and it caches one context per process. It is also the only
module that imports moderngl: the other playback modules get the module (its flags such as ``NEAREST`` and
``TRIANGLES``, its ``Error``) from :func:`moderngl_module`, and the viewer window wraps its own GL context
with :func:`adopt_current_context`. moderngl is imported lazily inside functions, so ``import neuras_distill``
(and this module) stays cheap and works on machines without any GL libraries; the failure only surfaces, as
:class:`GLUnavailable` with the reason, when a context is actually needed.

Public API:
    get_context() -> moderngl.Context      cached, GL >= 3.3 core
    adopt_current_context() -> Context     wraps the GL context current on this thread (a window's)
    moderngl_module() -> module            moderngl itself, imported on first call
    gl_available() -> (bool, reason)       for tests / CLI to skip or explain
    gl_info(ctx=None) -> dict              renderer, vendor, version strings
    software_gl(renderer) -> bool          whether that renderer rasterizes in software
    GLUnavailable(RuntimeError)            raised when no context can be made
"""

from __future__ import annotations

import os
import threading

MIN_GL_VERSION = 330

_lock = threading.Lock()
_cache: dict = {"pid": None, "ctx": None, "error": None}

_INSTALL_HINT = ("install the EGL/Mesa runtime (Debian/Ubuntu: apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri "
                 "libgbm1) or run where a GPU driver provides EGL")


class GLUnavailable(RuntimeError):
    """No usable OpenGL (>= 3.3 core) context can be created here; the message says why and what to install."""


def moderngl_module():
    """The moderngl module (imported here on first call: the one moderngl import of the package).

    Callers use it for moderngl's flags and types (``NEAREST``, ``TRIANGLES``, ``CULL_FACE``, ``Error``, ...);
    contexts come from :func:`get_context` or :func:`adopt_current_context`.

    Raises :class:`GLUnavailable` when moderngl cannot be imported (not installed, or a broken binary wheel).
    """
    try:
        import moderngl  # noqa: PLC0415 (lazy on purpose)
    except Exception as exc:  # ImportError, or a broken binary wheel
        raise GLUnavailable(f"moderngl cannot be imported ({exc}); pip install moderngl glcontext") from None
    return moderngl


def adopt_current_context():
    """A moderngl context wrapping the OpenGL (>= 3.3 core) context current on this thread, e.g. a glfw
    window's after ``make_context_current``. Not cached: it belongs to the window that made it."""
    return moderngl_module().create_context(require=MIN_GL_VERSION)


def _create_context():
    moderngl = moderngl_module()
    attempts = []
    for label, kwargs in (("EGL", {"standalone": True, "backend": "egl"}), ("default", {"standalone": True})):
        try:
            ctx = moderngl.create_context(require=MIN_GL_VERSION, **kwargs)
        except Exception as exc:  # glcontext raises plain Exceptions with the loader's message
            attempts.append(f"{label} backend: {str(exc).strip() or type(exc).__name__}")
            continue
        return ctx
    raise GLUnavailable("no headless OpenGL 3.3 context could be created (" + "; ".join(attempts) + "); "
                        + _INSTALL_HINT)


def get_context():
    """The process-wide headless moderngl context (created on first call, re-created after a fork).

    Raises :class:`GLUnavailable` with the reason when none can be made (the failure is cached too, so
    repeated calls are cheap). The context is current on the thread that created it; use it from that thread.
    """
    with _lock:
        pid = os.getpid()
        if _cache["pid"] != pid:  # GL contexts do not survive fork: start afresh in a child process
            _cache.update(pid=pid, ctx=None, error=None)
        if _cache["ctx"] is not None:
            return _cache["ctx"]
        if _cache["error"] is not None:
            raise GLUnavailable(_cache["error"])
        try:
            ctx = _create_context()
        except GLUnavailable as exc:
            _cache["error"] = str(exc)
            raise
        _cache["ctx"] = ctx
        return ctx


def gl_available() -> tuple[bool, str]:
    """(True, "") when :func:`get_context` works here, else (False, reason) -- for ``pytest.skip(reason)``."""
    try:
        get_context()
    except GLUnavailable as exc:
        return False, str(exc)
    return True, ""


def gl_info(ctx=None) -> dict:
    """Renderer, vendor and version strings of ``ctx`` (default: :func:`get_context`), plus limits we rely on."""
    ctx = ctx if ctx is not None else get_context()
    info = ctx.info
    return {
        "renderer": str(info.get("GL_RENDERER", "")),
        "vendor": str(info.get("GL_VENDOR", "")),
        "version": str(info.get("GL_VERSION", "")),
        "version_code": int(ctx.version_code),
        "max_texture_size": int(info.get("GL_MAX_TEXTURE_SIZE", 0) or 0),
    }


def software_gl(renderer: str) -> bool:
    """Whether an OpenGL renderer string names a software rasterizer (Mesa llvmpipe / softpipe, SwiftShader)."""
    return any(word in renderer.lower() for word in ("llvmpipe", "softpipe", "swiftshader", "software"))
