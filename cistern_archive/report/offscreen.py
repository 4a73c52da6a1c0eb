"""Quiet off-screen rendering with VTK on a machine without a display.

VTK's Linux wheels choose the OpenGL window at run time. Without ``DISPLAY`` the default X window logs
"bad X server connection" before falling back, so the EGL window (Mesa's software rasteriser through
``libEGL``) is requested up front with ``VTK_DEFAULT_OPENGL_WINDOW``. It needs the system's GL vendor
neutral EGL library and a vendor driver (Debian: ``libegl1 libegl-mesa0 libgl1-mesa-dri``);
:func:`probe` checks they are loadable before anything renders, because a render without them can
crash the interpreter instead of raising.
"""

from __future__ import annotations

import ctypes
import functools
import os
from pathlib import Path

EGL_WINDOW = "vtkEGLRenderWindow"
EGL_VENDOR_DIRS = (Path("/usr/share/glvnd/egl_vendor.d"), Path("/etc/glvnd/egl_vendor.d"))


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def configure() -> None:
    """Make pyvista render off screen, through EGL when no display is set (idempotent)."""
    if not has_display():
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", EGL_WINDOW)
    import pyvista  # deferred: VTK loads in a second and picks its OpenGL window at import

    pyvista.OFF_SCREEN = True


@functools.lru_cache(maxsize=1)
def probe() -> str:
    """Whether off-screen rendering can work here.

    Returns
    -------
    str
        Empty when it can; otherwise why not (the report then shows the reason instead of the 3D views
        and still exports the mesh).
    """
    configure()
    window = os.environ.get("VTK_DEFAULT_OPENGL_WINDOW", "")
    if has_display() and window != EGL_WINDOW:
        return ""
    try:
        egl = ctypes.CDLL("libEGL.so.1")
        egl.eglGetProcAddress  # noqa: B018 - resolving the symbol is the check
    except (OSError, AttributeError) as exc:
        return (f"off-screen rendering needs libEGL ({exc}); install Mesa's EGL "
                "(Debian: libegl1 libegl-mesa0 libgl1-mesa-dri)")
    vendors = [p for d in EGL_VENDOR_DIRS if d.is_dir() for p in sorted(d.glob("*.json"))]
    if not vendors and not os.environ.get("__EGL_VENDOR_LIBRARY_FILENAMES"):
        return ("off-screen rendering needs an EGL vendor driver (no file in "
                f"{', '.join(str(d) for d in EGL_VENDOR_DIRS)}); install Debian's libegl-mesa0 libgl1-mesa-dri")
    return ""
