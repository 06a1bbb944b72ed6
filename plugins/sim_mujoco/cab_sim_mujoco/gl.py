"""The OpenGL context MuJoCo renders through, chosen at launch, and what it turned out to be.

MuJoCo renders with OpenGL; without a display that means EGL (a GPU driver, or Mesa's llvmpipe on
the CPU) or OSMesa (Mesa's off-screen software renderer). The choice:

1. ``MUJOCO_GL`` when the operator set it (``egl``, ``osmesa`` or ``glfw``): that backend or a
   ``RendererUnavailable`` saying why it cannot start; never a silent switch to another one.
2. Otherwise EGL when ``libEGL`` loads, else OSMesa when ``libOSMesa`` loads.

PyOpenGL binds its platform (``PYOPENGL_PLATFORM``) once per process, so one backend serves the
whole process: the first context decides, later ones reuse it. The renderer string
(``GL_RENDERER``) is read from the started context; ``llvmpipe`` / ``softpipe`` there means the
frames are drawn on the CPU, and :func:`describe` records it.
"""
from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import logging
import os
import threading
from dataclasses import dataclass

from cab_core.errors import RendererUnavailable

VALID = ("egl", "osmesa", "glfw")
_OFF = ("disable", "disabled", "off", "false", "0")  # MuJoCo's own words for "no rendering"
_LIBS = {"egl": ("EGL", "libEGL.so.1"), "osmesa": ("OSMesa", "libOSMesa.so.8")}
_PACKAGES = {"egl": "libegl1 libegl-mesa0 libgl1-mesa-dri", "osmesa": "libosmesa6",
             "glfw": "libglfw3 and a display"}
_SOFTWARE = ("llvmpipe", "softpipe", "swrast", "lavapipe")


@dataclass
class GLInfo:
    backend: str  # egl | osmesa | glfw
    chosen_by: str  # "MUJOCO_GL" or "auto"
    renderer: str  # GL_RENDERER
    version: str  # GL_VERSION
    vendor: str  # GL_VENDOR


_STARTED: dict[str, object] = {}  # "context", "info": the process's context, once started
_LOCK = threading.RLock()  # one thread draws at a time: the context is the process's, not a simulator's


@contextlib.contextmanager
def current(ctx):
    """Make the process's context current on this thread for the block, then release it; threads
    (and the simulators they drive) take turns."""
    with _LOCK, ctx.as_current():
        yield


def _loads(backend: str) -> bool:
    if backend == "glfw":
        return True
    name, soname = _LIBS[backend]
    for candidate in (soname, ctypes.util.find_library(name)):
        if not candidate:
            continue
        try:
            ctypes.CDLL(candidate)
            return True
        except OSError:
            continue
    return False


def forced_backend(environ=os.environ) -> str | None:
    """The backend the operator set in ``MUJOCO_GL`` (None when unset), checked to load.

    MuJoCo's own ``import mujoco`` starts that backend's OpenGL bindings and fails with a bare
    AttributeError when its library is missing; the simulator module calls this before importing
    MuJoCo, so the operator reads why instead."""
    forced = (environ.get("MUJOCO_GL") or "").strip().lower()
    if not forced:
        return None
    if forced in _OFF:
        return "off"
    if forced not in VALID:
        raise RendererUnavailable(f"MUJOCO_GL={forced!r} is not a backend MuJoCo can render with "
                                  f"headless here; use one of {', '.join(VALID)} (or unset it)")
    if not _loads(forced):
        raise RendererUnavailable(f"MUJOCO_GL={forced} was set, but its library does not load (MuJoCo "
                                  f"cannot even be imported so); install {_PACKAGES[forced]}, or unset "
                                  f"MUJOCO_GL to let cab choose")
    return forced


def choose_backend(environ=os.environ) -> tuple[str, str]:
    """(backend, how it was chosen). Raises RendererUnavailable when none can load."""
    forced = forced_backend(environ)
    if forced == "off":
        raise RendererUnavailable("MUJOCO_GL turns MuJoCo's rendering off; unset it, or build the "
                                  "simulator with render: false for physics-only use")
    if forced is not None:
        return forced, "MUJOCO_GL"
    for backend in ("egl", "osmesa"):
        if _loads(backend):
            return backend, "auto"
    raise RendererUnavailable("MuJoCo found neither libEGL nor libOSMesa; install "
                              f"{_PACKAGES['egl']} (EGL) or {_PACKAGES['osmesa']} (OSMesa), "
                              "or build the simulator with render: false for physics-only use")


# the libraries a backend's context loads when it starts (beyond the one _loads tries): Mesa's EGL
# vendor library, which links Mesa's drivers and LLVM (glvnd's libEGL loads it on first use)
_DRIVER_LIBS = {"egl": ("libEGL_mesa.so.0",), "osmesa": (), "glfw": ()}


def preload() -> list[str]:
    """Load, without starting anything, what the context of the backend :func:`choose_backend`
    picks will load: its library and driver libraries, and PyOpenGL's bindings of that platform.
    Called in a sweep's fork server (``cab_sim_mujoco.cab_preload``), so that its workers share
    these pages instead of each relocating its own copy of Mesa and LLVM (about 50 MiB). No thread,
    display or context is made; returns the libraries loaded. A backend that cannot start here
    loads nothing (the worker says why when it renders)."""
    try:
        backend, _ = choose_backend()
        _context_class(backend)  # PyOpenGL's platform module, bound to this backend
    except RendererUnavailable:
        return []
    from OpenGL import GL  # noqa: F401  (the GL bindings and the library behind them)

    loaded = []
    for soname in _DRIVER_LIBS[backend]:
        try:
            ctypes.CDLL(soname)
        except OSError:  # not Mesa (a GPU vendor's driver): nothing of it is loaded here
            continue
        loaded.append(soname)
    return loaded


def _context_class(backend: str):
    """The GLContext class of ``backend``; setting PYOPENGL_PLATFORM first is what binds it.
    PyOpenGL's note that its optional C accelerator is not installed (an INFO record on first
    import, printed by any application that logs INFO, as cab's command line does) is kept out."""
    logging.getLogger("OpenGL.acceleratesupport").setLevel(logging.WARNING)
    platform = os.environ.get("PYOPENGL_PLATFORM")
    if backend in ("egl", "osmesa") and platform and platform.lower() != backend:
        raise RendererUnavailable(f"PYOPENGL_PLATFORM={platform} conflicts with the {backend} backend; "
                                  f"unset it or set MUJOCO_GL={platform.lower()}")
    if backend == "egl":
        from mujoco.egl import GLContext
    elif backend == "osmesa":
        from mujoco.osmesa import GLContext
    else:
        from mujoco.glfw import GLContext
    return GLContext


def context(width: int, height: int):
    """The process's GL context (started on first use) and its :class:`GLInfo`.

    The context is current on no thread: users wrap their GL work in :func:`current`, which
    releases it afterwards, so that any thread may render next (an EGL context current on one
    thread cannot be made current on another). ``width``/``height`` bound only GLFW's window;
    EGL and OSMesa render into MuJoCo's own off-screen framebuffer."""
    with _LOCK:
        if "context" not in _STARTED:
            _start(width, height)
        return _STARTED["context"], _STARTED["info"]


def _start(width: int, height: int) -> None:
    """Start the chosen backend's context and read what it is (under ``_LOCK``)."""
    backend, how = choose_backend()
    try:
        cls = _context_class(backend)
        ctx = cls(max(1, int(width)), max(1, int(height)))
        from OpenGL import GL

        def read(name):
            v = GL.glGetString(name)
            return v.decode(errors="replace") if isinstance(v, bytes) else str(v or "")

        with ctx.as_current():
            info = GLInfo(backend, how, read(GL.GL_RENDERER), read(GL.GL_VERSION), read(GL.GL_VENDOR))
    except RendererUnavailable:
        raise
    except Exception as e:  # noqa: BLE001 (any start-up failure becomes one diagnosis)
        other = "osmesa" if backend == "egl" else "egl"
        chosen = "by MUJOCO_GL" if how != "auto" else "automatically"
        raise RendererUnavailable(
            f"MuJoCo could not start an OpenGL context with {backend} (chosen {chosen}): "
            f"{type(e).__name__}: {e}. Check that {_PACKAGES[backend]} is installed; or set "
            f"MUJOCO_GL={other} (needs {_PACKAGES[other]}); or build the simulator with render: false") from e
    _STARTED.update(context=ctx, info=info)


def is_software(renderer: str) -> bool:
    """Whether a GL_RENDERER string names a CPU rasteriser (Mesa llvmpipe and friends)."""
    r = renderer.lower()
    return any(s in r for s in _SOFTWARE)


def describe(info: GLInfo) -> dict[str, str]:
    """Provenance fields for ``versions()``."""
    out = {"gl_backend": info.backend, "gl_backend_chosen_by": info.chosen_by,
           "render_device": info.renderer, "gl_version": info.version, "gl_vendor": info.vendor}
    if is_software(info.renderer):
        out["render_driver"] = "llvmpipe (Mesa, CPU)" if "llvmpipe" in info.renderer.lower() else "software (CPU)"
        out["llvmpipe"] = "yes" if "llvmpipe" in info.renderer.lower() else "no"
    else:
        out["render_driver"] = "gpu"
        out["llvmpipe"] = "no"
    return out
