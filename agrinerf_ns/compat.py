"""Compatibility shims that let Nerfstudio 1.1.5 run offline and on current PyTorch.

Nerfstudio imports every installed plugin's entry points in every ``ns-*`` command, so the plugin activates these
shims for all methods (``nerfacto`` and ``tensorf`` included). Each shim is narrow, checks whether it is needed, and
lives here alone: when Nerfstudio ships a fix, delete the shim and its line in :func:`activate`.

Shims:

- :func:`patch_lpips_offline`: torchmetrics' LPIPS downloads AlexNet weights when a model is constructed. Where the
  weights are not in the torch hub cache, nothing is downloaded (unless ``AGRINERF_DOWNLOAD_WEIGHTS=1`` asks for it):
  LPIPS becomes *unavailable* (it returns NaN) with one warning that says how to provide the weights, instead of a
  download attempt and, offline, a crash of model construction. With the weights present nothing changes.
- :func:`allow_checkpoint_globals`: since torch 2.6 ``torch.load`` defaults to ``weights_only=True``; Nerfstudio's
  checkpoints hold numpy scalars. Exactly those numpy globals are allow-listed (no blanket ``weights_only=False``).
- :func:`expose_ffmpeg`: Nerfstudio (``check_ffmpeg_installed``, its ffmpeg command lines) and mediapy look
  ``ffmpeg`` up on PATH. When PATH has none, the folder of the running interpreter is appended if it holds one (a
  conda env, a venv run without activation), else a folder whose ``ffmpeg`` links to the binary of imageio-ffmpeg
  (a dependency of the plugin), kept in the user's cache (:func:`imageio_ffmpeg_folder`).
- :func:`patch_single_camera_interpolation`: ``ns-render interpolate`` interpolates between the cameras of a split;
  with one camera (a dataset with one held-out frame) Nerfstudio's path has no poses and numpy fails to stack them.
  There the path holds still at that camera for ``--interpolation-steps`` frames, and one line names
  ``--pose-source train``. Applied where ``ns-render`` has imported Nerfstudio's camera paths.
- :func:`patch_eval_json`: ``ns-eval`` writes its metrics with ``json.dumps``, so an unavailable metric (LPIPS
  without its weights) becomes a bare ``NaN`` that strict JSON readers refuse. In ``ns-eval`` the module's ``json``
  is given :func:`agrinerf_ns.metrics_json.strict_dumps`: ``null`` and the reason beside it.

The dataparser package installs :func:`agrinerf_ns.dataparsers.user_errors.install` beside these (it checks
datasets, so it lives with them): a user's error stops a command with one message.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
import tempfile
import urllib.error
import warnings
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, List, Optional, Tuple

import torch

ALEXNET_WEIGHTS = "alexnet-owt-7be5be79.pth"
"""File name torchvision gives the AlexNet weights that LPIPS(net_type='alex') loads."""

DOWNLOAD_ENV = "AGRINERF_DOWNLOAD_WEIGHTS"
"""Set to 1 to let LPIPS download its AlexNet weights when they are not cached (no command downloads otherwise)."""

LPIPS_UNAVAILABLE_MESSAGE = (
    "LPIPS is unavailable: the AlexNet weights it needs are not in the torch hub cache ({path}), and nothing is "
    "downloaded unless " + DOWNLOAD_ENV + "=1. LPIPS metrics will be reported as NaN (null in metrics files). To "
    "enable LPIPS offline, copy '{name}' into "
    '$TORCH_HOME/hub/checkpoints on this machine (on a machine with internet, run once: python -c "import torchvision; '
    "torchvision.models.alexnet(weights='DEFAULT')\" and copy ~/.cache/torch/hub/checkpoints/{name})."
)


@dataclass
class _ShimState:
    """What the shims changed, so that they can be undone (tests) and warn only once."""

    lpips_originals: Optional[Tuple[Callable[..., Any], Callable[..., Any], Callable[..., Any]]] = None
    lpips_warned: bool = False


_STATE = _ShimState()


def alexnet_weights_path() -> Path:
    """Where torchvision looks for the AlexNet weights (honours ``TORCH_HOME``)."""
    return Path(torch.hub.get_dir()) / "checkpoints" / ALEXNET_WEIGHTS


def lpips_shim_needed() -> bool:
    """True when LPIPS construction would have to download its backbone weights."""
    return not alexnet_weights_path().is_file()


def _is_download_failure(err: BaseException) -> bool:
    """Whether an exception (or one in its chain) is a failed fetch of remote weights."""
    seen = set()
    current: Optional[BaseException] = err
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        if isinstance(current, (urllib.error.URLError, ConnectionError, TimeoutError)):
            return True
        current = current.__cause__ or current.__context__
    return False


def _unavailable_value() -> torch.Tensor:
    return torch.tensor(float("nan"))


def patch_lpips_offline() -> bool:
    """Make LPIPS construction survive missing weights without fetching them. Returns True if the patch is installed.

    The real construction is always run, so a filled cache (or ``AGRINERF_DOWNLOAD_WEIGHTS=1`` and a network) gets
    the real metric; without cached weights torchvision's download is refused inside it.
    """
    from torchmetrics.image.lpip import LearnedPerceptualImagePatchSimilarity as LPIPS

    if _STATE.lpips_originals is not None:
        return True
    _STATE.lpips_originals = (LPIPS.__init__, LPIPS.forward, LPIPS.compute)
    original_init, original_forward, original_compute = _STATE.lpips_originals

    def init(self: Any, *args: Any, **kwargs: Any) -> None:
        try:
            with _no_weight_downloads() if lpips_shim_needed() and not downloads_allowed() else nullcontext():
                original_init(self, *args, **kwargs)
            self._lpips_unavailable = False
        except Exception as err:  # only a failed download is absorbed; every other error propagates
            if not _is_download_failure(err):
                raise
            _warn_lpips_unavailable()
            self._lpips_unavailable = True

    def forward(self: Any, *args: Any, **kwargs: Any) -> Any:
        if getattr(self, "_lpips_unavailable", False):
            return _unavailable_value()
        return original_forward(self, *args, **kwargs)

    def compute(self: Any) -> Any:
        if getattr(self, "_lpips_unavailable", False):
            return _unavailable_value()
        return original_compute(self)

    LPIPS.__init__ = init
    LPIPS.forward = forward
    LPIPS.compute = compute
    return True


def unpatch_lpips() -> None:
    """Restore torchmetrics' LPIPS as it was (used by tests)."""
    from torchmetrics.image.lpip import LearnedPerceptualImagePatchSimilarity as LPIPS

    if _STATE.lpips_originals is None:
        return
    LPIPS.__init__, LPIPS.forward, LPIPS.compute = _STATE.lpips_originals
    _STATE.lpips_originals = None


def downloads_allowed() -> bool:
    """Whether the user asked for weight downloads (``AGRINERF_DOWNLOAD_WEIGHTS=1``)."""
    return os.environ.get(DOWNLOAD_ENV, "") not in ("", "0")


@contextmanager
def _no_weight_downloads() -> Iterator[None]:
    """Within: torchvision's weight loader raises a :class:`urllib.error.URLError` instead of fetching a file that
    is not in the hub cache (so no connection is tried and no "Downloading" line is printed)."""
    import torchvision.models._api as weights_api

    original = weights_api.load_state_dict_from_url

    def refuse(url: str, *args: Any, **kwargs: Any) -> Any:
        raise urllib.error.URLError(f"not downloaded: {url} ({DOWNLOAD_ENV}=1 allows it)")

    weights_api.load_state_dict_from_url = refuse
    try:
        yield
    finally:
        weights_api.load_state_dict_from_url = original


def lpips_patched() -> bool:
    """Whether the LPIPS shim is installed."""
    return _STATE.lpips_originals is not None


def _warn_lpips_unavailable() -> None:
    if _STATE.lpips_warned:
        return
    _STATE.lpips_warned = True
    warnings.warn(
        LPIPS_UNAVAILABLE_MESSAGE.format(path=alexnet_weights_path(), name=ALEXNET_WEIGHTS),
        RuntimeWarning,
        stacklevel=3,
    )


def checkpoint_shim_needed(torch_version: Optional[str] = None) -> bool:
    """True on torch >= 2.6, where ``torch.load`` defaults to ``weights_only=True``."""
    version = torch_version if torch_version is not None else torch.__version__
    major, minor = (int(part) for part in version.split("+")[0].split(".")[:2])
    return (major, minor) >= (2, 6)


def checkpoint_globals() -> List[Any]:
    """The numpy globals a Nerfstudio checkpoint pickles: float64 numpy scalars in the schedulers' state.

    Found by reading the pickle of ``nerfacto``, ``tensorf`` and ``agrinerf`` checkpoints (numpy scalar, its dtype and
    the dtype's class). Nothing else is allowed: a checkpoint holding, say, a numpy array still fails to load.
    """
    import numpy as np

    try:
        from numpy.core.multiarray import scalar  # type: ignore[attr-defined]
    except ImportError:  # numpy >= 2 keeps it under numpy._core
        from numpy._core.multiarray import scalar  # type: ignore[attr-defined, no-redef]
    return [scalar, np.dtype, type(np.dtype("float64"))]


def allow_checkpoint_globals() -> bool:
    """Allow-list the numpy globals in Nerfstudio checkpoints for ``weights_only`` loading. Returns True if applied."""
    if not checkpoint_shim_needed():
        return False
    torch.serialization.add_safe_globals(checkpoint_globals())
    return True


def activate() -> None:
    """Apply every shim that this environment needs. Safe to call more than once; never raises."""
    if os.environ.get("AGRINERF_NO_COMPAT") == "1":
        return
    shims = (_activate_lpips, allow_checkpoint_globals, expose_ffmpeg, _activate_single_camera_interpolation,
             patch_eval_json)  # fmt: skip
    for shim in shims:
        try:
            shim()
        except Exception as err:  # a plugin must never break `ns-*` commands
            warnings.warn(
                f"agrinerf-ns compatibility shim {shim.__name__} failed: {err!r}", RuntimeWarning, stacklevel=2
            )


def expose_ffmpeg() -> bool:
    """Append a folder holding an ``ffmpeg`` to PATH when PATH has none: the running interpreter's bin folder if it
    has one, else :func:`imageio_ffmpeg_folder`. Returns True if PATH was changed.

    Appended, not prepended: nothing else on PATH changes meaning.
    """
    if shutil.which("ffmpeg") is not None:
        return False
    bin_dir = Path(sys.executable).parent
    folder = bin_dir if shutil.which("ffmpeg", path=str(bin_dir)) is not None else imageio_ffmpeg_folder()
    if folder is None:
        return False
    os.environ["PATH"] = os.pathsep.join(p for p in (os.environ.get("PATH", ""), str(folder)) if p)
    return True


def imageio_ffmpeg_folder() -> Optional[Path]:
    """A folder whose ``ffmpeg`` is the binary imageio-ffmpeg provides, or None where it provides none.

    imageio-ffmpeg names its binary by platform and version (``ffmpeg-linux-x86_64-v7.0.2``), which a lookup of
    ``ffmpeg`` on PATH does not find; so a link named ``ffmpeg`` to it is kept in the user's cache
    (``$XDG_CACHE_HOME/agrinerf-ns/ffmpeg/<digest of the binary's path>``; the temporary folder where the cache is not
    writable), made once, atomically.
    """
    try:
        import imageio_ffmpeg

        exe = Path(imageio_ffmpeg.get_ffmpeg_exe())
    except (ImportError, RuntimeError):
        return None
    if exe.name == "ffmpeg":  # IMAGEIO_FFMPEG_EXE or a conda ffmpeg: already the name PATH lookups want
        return exe.parent
    digest = hashlib.sha256(str(exe).encode()).hexdigest()[:16]
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "agrinerf-ns"
    for root in (cache, Path(tempfile.gettempdir()) / f"agrinerf-ns-{os.getuid()}"):
        folder = root / "ffmpeg" / digest
        try:
            _link(folder / "ffmpeg", exe)
        except OSError:
            continue
        return folder
    return None


def _link(link: Path, target: Path) -> None:
    """Make ``link`` a symbolic link to ``target`` unless it is one already (atomically: a rename into place)."""
    if link.is_symlink() and Path(os.readlink(link)) == target:
        return
    link.parent.mkdir(parents=True, exist_ok=True)
    tmp = link.with_name(f".{link.name}.{os.getpid()}")
    tmp.unlink(missing_ok=True)
    tmp.symlink_to(target)
    os.replace(tmp, link)


SINGLE_CAMERA_MESSAGE = (
    "ns-render interpolate: the chosen split has one camera, so the video holds still at it; "
    "--pose-source train interpolates between the training cameras."
)


def patch_single_camera_interpolation() -> bool:
    """Let Nerfstudio's interpolated camera path take a single camera: the path then stays at it for ``steps``
    frames (the path from the camera to itself) and :data:`SINGLE_CAMERA_MESSAGE` is printed. Returns True if the
    patch is installed (also in ``nerfstudio.scripts.render``, which imports the function by name)."""
    from nerfstudio.cameras import camera_paths

    original = camera_paths.get_interpolated_camera_path
    if getattr(original, "_agrinerf_single_camera", False):
        return True

    def get_interpolated_camera_path(cameras: Any, steps: int, order_poses: bool) -> Any:
        if len(cameras) != 1:
            return original(cameras=cameras, steps=steps, order_poses=order_poses)
        from nerfstudio.utils.rich_utils import CONSOLE

        CONSOLE.print(f"[yellow]{SINGLE_CAMERA_MESSAGE}")
        return original(cameras=cameras[torch.zeros(2, dtype=torch.long)], steps=steps, order_poses=False)

    get_interpolated_camera_path._agrinerf_single_camera = True  # type: ignore[attr-defined]
    get_interpolated_camera_path.__doc__ = original.__doc__
    camera_paths.get_interpolated_camera_path = get_interpolated_camera_path
    render = sys.modules.get("nerfstudio.scripts.render")
    if render is not None and getattr(render, "get_interpolated_camera_path", None) is original:
        render.get_interpolated_camera_path = get_interpolated_camera_path  # type: ignore[attr-defined]
    return True


def _activate_single_camera_interpolation() -> bool:
    # only where Nerfstudio's camera paths are loaded already (ns-render imports them before the plugins): other
    # commands do not pay for the import
    if "nerfstudio.cameras.camera_paths" not in sys.modules:
        return False
    return patch_single_camera_interpolation()


def _activate_lpips() -> bool:
    if not lpips_shim_needed():
        return False
    return patch_lpips_offline()


def patch_eval_json() -> bool:
    """Where ``ns-eval`` is running (its module is imported: it loads the plugins while it imports), make the
    ``json.dumps`` it writes the metrics file with strict (:func:`agrinerf_ns.metrics_json.strict_dumps`). Returns
    True if applied."""
    import functools
    import json
    import types

    from agrinerf_ns.metrics_json import strict_dumps

    module = sys.modules.get("nerfstudio.scripts.eval")
    if module is None or getattr(module, "json", None) is not json:
        return False
    strict_json = types.ModuleType("json", "The json module, with dumps writing strict JSON (metrics_json).")
    strict_json.__dict__.update({k: v for k, v in vars(json).items() if not k.startswith("__")})
    strict_json.dumps = functools.partial(strict_dumps, reason=metric_null_reason)  # type: ignore[attr-defined]
    module.json = strict_json  # type: ignore[attr-defined]
    return True


def metric_null_reason(key: str) -> str:
    """Why the metric ``key`` has no value (written beside its null in a metrics file)."""
    from agrinerf_ns.metrics_json import not_finite

    if key.startswith("lpips") and lpips_shim_needed():
        return (
            f"LPIPS unavailable: its AlexNet weights ({ALEXNET_WEIGHTS}) are not in {alexnet_weights_path().parent}, "
            f"and nothing is downloaded unless {DOWNLOAD_ENV}=1"
        )
    return not_finite(key)
