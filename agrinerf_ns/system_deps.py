"""The system pieces that Nerfstudio's commands need beyond pip: the libraries open3d and pymeshlab load
(``ns-export``) and an ``ffmpeg`` (``ns-render`` videos). Each check returns None when the piece works, else a message
that says how to install it.

``python -m agrinerf_ns.system_deps`` prints every problem and exits 1 if there is one (``scripts/install.sh`` runs
it after installing).
"""

from __future__ import annotations

import ctypes
import importlib.util
import shutil
import sys
from typing import List, Optional

SYSTEM_LIBRARIES = {
    "libusb-1.0.so.0": ("libusb-1.0-0", "libusb1", "open3d"),
    "libEGL.so.1": ("libegl1", "libglvnd-egl", "open3d"),
    "libGL.so.1": ("libgl1", "libglvnd-glx", "open3d"),
    "libOpenGL.so.0": ("libopengl0", "libglvnd-opengl", "pymeshlab"),
}
"""The system libraries that a minimal Debian lacks: soname -> (Debian/Ubuntu package, Fedora package, the module
that loads it). open3d's module links the first three; pymeshlab, which ns-export's meshes are saved with, loads its
PLY writer through the fourth. scripts/install_system.sh installs the same (tests/test_install_system.py checks)."""
OPEN3D_LIBRARY_HINT = (
    "open3d (used by ns-export and agrinerf-export) cannot load: {err}. It needs the system library {soname}: "
    "on Debian/Ubuntu run 'sudo apt-get install {debian}' (Fedora: 'sudo dnf install {fedora}'); "
    "'bash scripts/install_system.sh' installs every one it needs."
)
MESHLAB_OPENGL_HINT = (
    "pymeshlab (ns-export's meshes) cannot load its PLY writer without the system library {soname} ({err}): "
    "on Debian/Ubuntu run 'sudo apt-get install {debian}' (Fedora: 'sudo dnf install {fedora}')."
)
FFMPEG_HINT = (
    "No 'ffmpeg' on PATH, which ns-render needs for videos, and imageio-ffmpeg (a dependency) provides none for this "
    "platform: install one, e.g. 'sudo apt-get install ffmpeg'."
)


class SystemDependencyError(RuntimeError):
    """A system library or program that a command needs is missing (the message says how to install it)."""


def open3d_problem() -> Optional[str]:
    """None if ``import open3d`` works; else what is missing and how to install it."""
    try:
        import open3d  # noqa: F401
    except ImportError as err:
        for soname, (debian, fedora, user) in SYSTEM_LIBRARIES.items():
            if user == "open3d" and soname in str(err):
                return OPEN3D_LIBRARY_HINT.format(err=err, soname=soname, debian=debian, fedora=fedora)
        return f"open3d cannot be imported: {err} (reinstall with 'bash scripts/install.sh')."
    return None


def import_open3d():
    """``import open3d``, or :class:`SystemDependencyError` naming the missing system library."""
    problem = open3d_problem()
    if problem is not None:
        raise SystemDependencyError(problem)
    import open3d

    return open3d


def meshlab_opengl_problem() -> Optional[str]:
    """None if pymeshlab is absent or its plugins' libOpenGL.so.0 loads (without it pymeshlab imports, then saves no
    PLY: "Unknown format for save: ply", as seen on a fresh Debian); else how to install it. Linux only."""
    if not sys.platform.startswith("linux") or importlib.util.find_spec("pymeshlab") is None:
        return None
    soname = "libOpenGL.so.0"
    debian, fedora, _ = SYSTEM_LIBRARIES[soname]
    try:
        ctypes.CDLL(soname)
    except OSError as err:
        return MESHLAB_OPENGL_HINT.format(err=err, soname=soname, debian=debian, fedora=fedora)
    return None


def ffmpeg_problem() -> Optional[str]:
    """None if an ``ffmpeg`` is on PATH (as Nerfstudio's ``check_ffmpeg_installed`` and mediapy look it up)."""
    return None if shutil.which("ffmpeg") else FFMPEG_HINT


def problems() -> List[str]:
    """Every missing system piece, as messages."""
    return [p for p in (open3d_problem(), meshlab_opengl_problem(), ffmpeg_problem()) if p is not None]


def main() -> int:
    """Print each problem on stderr; 1 if there is any (after the compat shims, as every ns-* command runs them)."""
    from agrinerf_ns import compat

    compat.activate()
    found = problems()
    for problem in found:
        print(f"agrinerf-ns: {problem}", file=sys.stderr)
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
