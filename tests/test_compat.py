"""The offline-LPIPS and checkpoint-loading shims, each on the path where it is needed and where it is not."""

from __future__ import annotations

import urllib.error
import urllib.request
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
import torchvision
from torchmetrics.image.lpip import LearnedPerceptualImagePatchSimilarity

from agrinerf_ns import compat


@pytest.fixture
def lpips_patched():
    """Install the LPIPS shim for one test, then restore torchmetrics as it was."""
    was_patched = compat.lpips_patched()
    compat.patch_lpips_offline()
    compat._STATE.lpips_warned = False
    yield
    if not was_patched:
        compat.unpatch_lpips()


def _offline(*args, **kwargs):
    raise urllib.error.URLError("network unreachable (test)")


def test_lpips_needed_without_weights_and_network(tmp_path: Path, monkeypatch, lpips_patched) -> None:
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    monkeypatch.setattr(urllib.request, "urlopen", _offline)
    assert compat.lpips_shim_needed()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        metric = LearnedPerceptualImagePatchSimilarity(normalize=True)
        second = LearnedPerceptualImagePatchSimilarity(normalize=True)
    messages = [str(w.message) for w in caught if "LPIPS is unavailable" in str(w.message)]
    assert len(messages) == 1, "one clear warning, not one per model"
    assert "TORCH_HOME" in messages[0] and compat.ALEXNET_WEIGHTS in messages[0]
    images = torch.rand(1, 3, 32, 32)
    assert torch.isnan(metric(images, images))
    assert torch.isnan(second(images, images.flip(-1)))


@pytest.fixture
def network_guard(monkeypatch):
    """Every attempt to resolve a host or open a connection is recorded and refused (the network is blocked)."""
    import socket

    attempts = []

    def refuse(*args, **kwargs):
        attempts.append(args)
        raise OSError("network blocked (test)")

    monkeypatch.setattr(socket, "getaddrinfo", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)
    monkeypatch.setattr(socket.socket, "connect", refuse)
    return attempts


def test_lpips_without_weights_tries_no_download(tmp_path: Path, monkeypatch, lpips_patched, network_guard, capfd):
    """With the network blocked and no cached weights: no connection is tried, no "Downloading" line is printed,
    the absence is said once, and LPIPS is NaN. With AGRINERF_DOWNLOAD_WEIGHTS=1 the download is tried (and here
    refused by the blocked network), so the guard sees the attempt the default does not make."""
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    monkeypatch.delenv(compat.DOWNLOAD_ENV, raising=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        metric = LearnedPerceptualImagePatchSimilarity(normalize=True)
        LearnedPerceptualImagePatchSimilarity(normalize=True)
    images = torch.rand(1, 3, 32, 32)
    assert torch.isnan(metric(images, images))
    assert network_guard == [] and "Downloading" not in capfd.readouterr().err
    said = [str(w.message) for w in caught if "LPIPS is unavailable" in str(w.message)]
    assert len(said) == 1 and compat.DOWNLOAD_ENV in said[0]
    monkeypatch.setenv(compat.DOWNLOAD_ENV, "1")
    LearnedPerceptualImagePatchSimilarity(normalize=True)
    assert network_guard, "asked to download, it tries the network"


def test_lpips_unpatched_crashes_offline(tmp_path: Path, monkeypatch) -> None:
    """Shows the shim is needed: without it, construction dies on the download."""
    was_patched = compat.lpips_patched()
    compat.unpatch_lpips()
    try:
        monkeypatch.setenv("TORCH_HOME", str(tmp_path))
        monkeypatch.setattr(urllib.request, "urlopen", _offline)
        with pytest.raises(urllib.error.URLError):
            LearnedPerceptualImagePatchSimilarity(normalize=True)
    finally:
        if was_patched:
            compat.patch_lpips_offline()


def test_lpips_other_errors_still_raise(lpips_patched) -> None:
    with pytest.raises(ValueError):
        LearnedPerceptualImagePatchSimilarity(net_type="not-a-net")


def test_lpips_with_cached_weights_is_the_real_metric(tmp_path: Path, monkeypatch, lpips_patched) -> None:
    """With backbone weights in the hub cache, the patched class computes exactly what torchmetrics computes."""
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    monkeypatch.setattr(urllib.request, "urlopen", _offline)  # proves nothing is fetched
    torch.manual_seed(0)
    weights = compat.alexnet_weights_path()
    weights.parent.mkdir(parents=True)
    torch.save(torchvision.models.alexnet().state_dict(), weights)
    assert not compat.lpips_shim_needed()

    images_a, images_b = torch.rand(2, 3, 64, 64), torch.rand(2, 3, 64, 64)
    patched = LearnedPerceptualImagePatchSimilarity(normalize=True)
    value = patched(images_a, images_b)
    compat.unpatch_lpips()
    reference = LearnedPerceptualImagePatchSimilarity(normalize=True)(images_a, images_b)
    compat.patch_lpips_offline()
    assert torch.isfinite(value) and value > 0
    assert torch.equal(value, reference)


def test_checkpoint_shim_version_gate() -> None:
    assert compat.checkpoint_shim_needed("2.6.0")
    assert compat.checkpoint_shim_needed("2.14.1+cu130")
    assert not compat.checkpoint_shim_needed("2.5.1")
    assert not compat.checkpoint_shim_needed("1.13.1+cpu")


def test_checkpoint_shim_not_needed_is_a_no_op(monkeypatch) -> None:
    monkeypatch.setattr(torch, "__version__", "2.5.1")
    before = list(torch.serialization.get_safe_globals())
    assert compat.allow_checkpoint_globals() is False
    assert list(torch.serialization.get_safe_globals()) == before


@pytest.mark.skipif(not compat.checkpoint_shim_needed(), reason="torch < 2.6 loads pickles without an allow-list")
def test_checkpoint_shim_needed_allows_exactly_numpy_scalars(tmp_path: Path) -> None:
    before = list(torch.serialization.get_safe_globals())
    scheduler_like = {"step": 3, "schedulers": {"fields": {"_last_lr": [np.float64(0.01)]}}, "w": torch.ones(2)}
    with_array = {"bad": np.arange(3)}
    torch.save(scheduler_like, tmp_path / "scalar.ckpt")
    torch.save(with_array, tmp_path / "array.ckpt")
    try:
        torch.serialization.clear_safe_globals()
        with pytest.raises(Exception, match="numpy"):
            torch.load(tmp_path / "scalar.ckpt")
        assert compat.allow_checkpoint_globals() is True
        loaded = torch.load(tmp_path / "scalar.ckpt")
        assert loaded["schedulers"]["fields"]["_last_lr"][0] == pytest.approx(0.01)
        with pytest.raises(Exception, match="numpy"):
            torch.load(tmp_path / "array.ckpt")  # no blanket weights_only=False
    finally:
        torch.serialization.clear_safe_globals()
        torch.serialization.add_safe_globals(before)


def test_activate_never_raises(monkeypatch) -> None:
    def boom() -> bool:
        raise RuntimeError("broken shim")

    monkeypatch.setattr(compat, "allow_checkpoint_globals", boom)
    with pytest.warns(RuntimeWarning, match="broken shim"):
        compat.activate()


def test_imageio_ffmpeg_is_found_when_path_has_no_ffmpeg(tmp_path: Path, monkeypatch) -> None:
    """A plain `pip install agrinerf-ns`: no ffmpeg on PATH nor beside the interpreter, only imageio-ffmpeg's binary
    (named by platform and version). The shim makes `ffmpeg` on PATH that binary, and runs it."""
    import shutil
    import subprocess
    import sys

    import imageio_ffmpeg

    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setattr(sys, "executable", str(tmp_path / "venv" / "bin" / "python"))  # a bin folder without ffmpeg
    assert shutil.which("ffmpeg") is None
    assert compat.expose_ffmpeg()
    found = shutil.which("ffmpeg")
    assert found is not None and Path(found).parent.is_relative_to(tmp_path / "cache" / "agrinerf-ns")
    assert Path(found).resolve() == Path(imageio_ffmpeg.get_ffmpeg_exe()).resolve()
    assert subprocess.run([found, "-version"], capture_output=True, text=True, check=True).stdout.startswith("ffmpeg")
    assert not compat.expose_ffmpeg()  # found now: PATH is left alone
    assert compat.imageio_ffmpeg_folder() == Path(found).parent  # the link is reused


def test_imageio_ffmpeg_link_falls_back_to_the_temporary_folder(tmp_path: Path, monkeypatch) -> None:
    import tempfile

    (tmp_path / "cache").write_text("a file, so no cache folder can be made under it")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    folder = compat.imageio_ffmpeg_folder()
    assert folder is not None and folder.is_relative_to(tmp_path / "tmp") and (folder / "ffmpeg").is_file()


def test_interpolation_between_one_camera_holds_still_and_names_the_train_cameras(capsys) -> None:
    """`ns-render interpolate` on a split of one camera: Nerfstudio's path fails to stack no poses; with the shim it
    stays at the camera for `steps` frames, and says how to interpolate between the training cameras instead."""
    from nerfstudio.cameras import camera_paths
    from nerfstudio.cameras.camera_utils import get_interpolated_poses_many
    from nerfstudio.cameras.cameras import Cameras

    c2w = torch.tensor([[[1.0, 0.0, 0.0, 0.1], [0.0, 0.0, -1.0, 0.2], [0.0, 1.0, 0.0, 0.3]]])
    one = Cameras(fx=50.0, fy=50.0, cx=32.0, cy=24.0, camera_to_worlds=c2w)
    with pytest.raises(ValueError, match="need at least one array to stack"):  # what the shim is for
        get_interpolated_poses_many(one.camera_to_worlds, one.get_intrinsics_matrices(), steps_per_transition=4)
    compat.patch_single_camera_interpolation()
    path = camera_paths.get_interpolated_camera_path(cameras=one, steps=4, order_poses=False)
    assert path.shape == (4,)
    torch.testing.assert_close(path.camera_to_worlds, c2w.expand(4, 3, 4))
    torch.testing.assert_close(path.fx, one.fx.expand(4, 1))
    assert "--pose-source train" in capsys.readouterr().out
    two = Cameras(fx=50.0, fy=50.0, cx=32.0, cy=24.0, camera_to_worlds=torch.cat([c2w, torch.eye(4)[None, :3]]))
    path = camera_paths.get_interpolated_camera_path(cameras=two, steps=3, order_poses=False)
    assert path.shape == (3,)  # two cameras: Nerfstudio's own path, unchanged
    assert "--pose-source" not in capsys.readouterr().out


def test_metrics_files_are_strict_json() -> None:
    """A NaN metric is written as null with its reason; ns-eval's json is given the strict writer."""
    import json
    import math

    from nerfstudio.scripts import eval as ns_eval_script

    from agrinerf_ns.metrics_json import UNAVAILABLE_KEY, strict_dumps

    def refuse(constant: str) -> None:
        raise ValueError(f"not strict JSON: {constant}")

    info = {"results": {"psnr": 20.5, "lpips": math.nan, "psnr_std": math.inf, "views": [1.0, math.nan]}}
    text = strict_dumps(info, indent=2)
    back = json.loads(text, parse_constant=refuse)["results"]
    assert back["psnr"] == 20.5 and back["lpips"] is None and back["psnr_std"] is None and back["views"] == [1.0, None]
    assert set(back[UNAVAILABLE_KEY]) == {"lpips", "psnr_std"} and "not finite" in back[UNAVAILABLE_KEY]["psnr_std"]
    with pytest.raises(ValueError, match="not strict JSON: NaN"):
        json.loads(json.dumps(info), parse_constant=refuse)  # what ns-eval wrote before
    was = ns_eval_script.json
    try:
        ns_eval_script.json = json
        assert compat.patch_eval_json()
        assert json.loads(ns_eval_script.json.dumps(info), parse_constant=refuse)["results"]["lpips"] is None
    finally:
        ns_eval_script.json = was
