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
