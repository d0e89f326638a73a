"""Tri-modal dataset: Nerfstudio's ``InputDataset`` plus per-pixel thermal and event frames and their masks.

Every extra frame is returned as a float32 ``(H, W, 1)`` tensor at the RGB image's resolution, so Nerfstudio's
pixel sampler (which indexes every batch key with the image's ``[camera, y, x]``) returns it at the same pixels
as RGB: a training batch carries ``batch["thermal"]`` of shape ``(num_rays, 1)`` beside ``batch["image"]``.

Keys returned by :meth:`AgriNeRFDataset.get_metadata` (only for modalities the dataparser found):

- ``"thermal"`` in [0, 1] and ``"thermal_mask"`` in {0, 1} (all ones when the dataset has no thermal masks);
- ``"event"`` in [0, 1] (representation in ``metadata["agrinerf"]["events"]``) and ``"event_mask"`` in {0, 1};
- ``"temperature"`` in degrees C and ``"temperature_mask"`` in {0, 1} (the thermal mask, and the image has a value),
  when the dataset has temperature images (``metadata["temperature_filenames"]``);
- ``"fruit"`` and ``"fruit_known"`` in {0, 1} (``dataparsers/fruit_masks.py``), when the frames have fruit masks
  (``metadata["fruit_mask_filenames"]``), and ``"fruit_thermal"`` (1 where the frame's mask is the thermal camera's
  view, ``metadata["fruit_mask_thermal"]``).

Like ``"image"``, these keys stay on the CPU in the cached batch (``exclude_batch_keys_from_device``); a model
moves them with ``batch["thermal"].to(self.device)`` as it does the image.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, List, Tuple

import numpy as np
import torch
from jaxtyping import Float
from nerfstudio.data.datamanagers.base_datamanager import VanillaDataManager, VanillaDataManagerConfig
from nerfstudio.data.datamanagers.parallel_datamanager import ParallelDataManager, ParallelDataManagerConfig
from nerfstudio.data.datasets.base_dataset import InputDataset
from PIL import Image
from torch import Tensor

from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataError, AgriNeRFDataParserConfig
from agrinerf_ns.dataparsers.fruit_masks import load_fruit_mask
from agrinerf_ns.dataparsers.fruit_sampler import FruitPixelSamplerConfig
from agrinerf_ns.dataset_format import EVENT_MASK, EVENT_SUMS, EVENTS, FRUIT_MASK, TEMPERATURE, THERMAL, THERMAL_MASK

# batch key -> (metadata key of its files, metadata key of its masks, batch key of its mask)
MODALITY_KEYS: Dict[str, Tuple[str, str, str]] = {
    "thermal": (THERMAL.metadata, THERMAL_MASK.metadata, "thermal_mask"),
    "event": (EVENTS.metadata, EVENT_MASK.metadata, "event_mask"),
}


def load_aligned_frame(path: Path, height: int, width: int, is_mask: bool = False) -> Float[Tensor, "height width 1"]:
    """Loads a single-channel frame as float32 (H, W, 1), resized to (height, width) like Nerfstudio's images.

    Values are scaled to [0, 1] by the file's bit depth (8 or 16 bit). A mask is binarised (>= 0.5 is valid);
    after a resize a pixel stays valid only if its whole footprint was valid.
    """
    try:
        pil_image = Image.open(path)
        pil_image.load()
    except Exception as error:  # PIL raises several types for unreadable files
        raise AgriNeRFDataError(f"{path}: cannot read image: {error}") from error
    if pil_image.mode not in ("L", "I;16", "I;16B", "I;16L", "I"):
        raise AgriNeRFDataError(f"{path}: expected a single-channel image, got mode {pil_image.mode}.")
    array = np.asarray(pil_image)
    full_scale = 255.0 if array.dtype == np.uint8 else 65535.0
    frame = array.astype(np.float32) / full_scale
    if is_mask:
        frame = (frame >= 0.5).astype(np.float32)
    file_width, file_height = pil_image.size
    if (file_height, file_width) != (height, width):
        _check_same_aspect(path, file_height, file_width, height, width)
        resized = Image.fromarray(frame).resize((width, height), resample=Image.Resampling.BILINEAR)
        frame = np.asarray(resized, dtype=np.float32)
        if is_mask:
            frame = (frame >= 1.0 - 1e-3).astype(np.float32)
    return torch.from_numpy(np.clip(frame, 0.0, 1.0).copy())[..., None]


def load_temperature_frame(
    path: Path, height: int, width: int
) -> Tuple[Float[Tensor, "height width 1"], Float[Tensor, "height width 1"]]:
    """A temperature image (16-bit centikelvin PNG, ``agrinerf_ns.temperature``) as float32 degrees C (H, W, 1) and its
    valid mask (the pixel has a value), resized like the image (bilinear; after a resize a pixel is valid only if its
    whole footprint was)."""
    from agrinerf_ns.temperature import decode_celsius

    try:
        pil_image = Image.open(path)
        pil_image.load()
    except Exception as error:  # PIL raises several types for unreadable files
        raise AgriNeRFDataError(f"{path}: cannot read image: {error}") from error
    array = np.asarray(pil_image)
    if array.ndim != 2 or array.dtype not in (np.uint16, np.int32, np.uint32):
        raise AgriNeRFDataError(
            f"{path}: a temperature image is a 16-bit single-channel PNG, got mode {pil_image.mode}"
        )
    celsius, valid = decode_celsius(array.astype(np.uint16))
    file_width, file_height = pil_image.size
    if (file_height, file_width) != (height, width):
        _check_same_aspect(path, file_height, file_width, height, width)
        weight = valid.astype(np.float32)
        resize = lambda a: np.asarray(Image.fromarray(a).resize((width, height), Image.Resampling.BILINEAR))  # noqa: E731
        w = resize(weight)
        celsius = np.where(w > 0, resize(celsius * weight) / np.maximum(w, 1e-6), 0.0).astype(np.float32)
        valid = w >= 1.0 - 1e-3
    return torch.from_numpy(celsius.copy())[..., None], torch.from_numpy(valid.astype(np.float32))[..., None]


def load_event_counts(
    path: Path, height: int, width: int
) -> Tuple[Float[Tensor, "height width 1"], Float[Tensor, "height width 1"]]:
    """The ON and OFF event counts per RGB pixel of one frame's event window (``event_sums_path``, float32).

    The counts are per pixel of the full-resolution RGB camera; a downscaled image would need them pooled, which the
    event loss does not do yet, so the size must match.
    """
    try:
        with np.load(path) as sums:
            pos, neg = np.asarray(sums["pos"]), np.asarray(sums["neg"])
    except (OSError, KeyError, ValueError) as error:
        raise AgriNeRFDataError(f"{path}: cannot read the ON/OFF counts 'pos' and 'neg': {error}") from error
    if pos.shape != (height, width) or neg.shape != (height, width):
        raise AgriNeRFDataError(
            f"{path}: event counts are {pos.shape[::-1]} but the RGB image is {width}x{height}; the event loss needs "
            "them at the image's resolution (train without downscaling)."
        )
    return (
        torch.from_numpy(pos.astype(np.float32))[..., None],
        torch.from_numpy(neg.astype(np.float32))[..., None],
    )


def _check_same_aspect(path: Path, file_height: int, file_width: int, height: int, width: int) -> None:
    """A frame may differ from the image only by the image's downscale factor (one pixel of rounding allowed)."""
    if abs(file_width * height / file_height - width) > 1.0 or abs(file_height * width / file_width - height) > 1.0:
        raise AgriNeRFDataError(
            f"{path}: frame is {file_width}x{file_height} but its RGB image is {width}x{height} (after downscaling); "
            "thermal and event frames must be warped into the RGB camera at its resolution."
        )


class AgriNeRFDataset(InputDataset):
    """Images plus the aligned thermal and event frames (and valid masks) named by the AgriNeRF dataparser."""

    exclude_batch_keys_from_device: List[str] = InputDataset.exclude_batch_keys_from_device + [
        "thermal",
        "thermal_mask",
        "event",
        "event_mask",
        "event_on",
        "event_off",
        "temperature",
        "temperature_mask",
        "fruit",
        "fruit_known",
        "fruit_thermal",
    ]

    def get_image_float32(self, image_idx: int) -> Float[Tensor, "h w 3"]:
        """The RGB frame in [0, 1], scaled by the dataparser's ``rgb_gain`` (dark frames brightened; clipped at 1)."""
        image = super().get_image_float32(image_idx)
        gain = float(self.metadata.get("rgb_gain", 1.0))
        return image if gain == 1.0 else (image * gain).clamp(0.0, 1.0)

    def get_metadata(self, data: Dict) -> Dict[str, Any]:
        """Returns the thermal/event frames and masks of ``data["image_idx"]`` at the size of ``data["image"]``."""
        image_idx = data["image_idx"]
        height, width = data["image"].shape[:2]
        out: Dict[str, Any] = {}
        for key, (files_key, masks_key, mask_key) in MODALITY_KEYS.items():
            filenames = self.metadata.get(files_key)
            if not filenames:
                continue
            out[key] = load_aligned_frame(filenames[image_idx], height, width)
            mask_files = self.metadata.get(masks_key)
            if mask_files:
                out[mask_key] = load_aligned_frame(mask_files[image_idx], height, width, is_mask=True)
            else:
                out[mask_key] = torch.ones((height, width, 1), dtype=torch.float32)
        temperature_files = self.metadata.get(TEMPERATURE.metadata)
        if temperature_files:
            out["temperature"], valid = load_temperature_frame(temperature_files[image_idx], height, width)
            out["temperature_mask"] = valid * out.get("thermal_mask", torch.ones_like(valid))
        fruit_masks = self.metadata.get(FRUIT_MASK.metadata)
        if fruit_masks:
            out["fruit"], out["fruit_known"] = load_fruit_mask(fruit_masks[image_idx], height, width)
            thermal = bool((self.metadata.get("fruit_mask_thermal") or [False] * len(fruit_masks))[image_idx])
            out["fruit_thermal"] = torch.full((height, width, 1), float(thermal))  # the mask is the thermal camera's
        sums_files = self.metadata.get(EVENT_SUMS.metadata)
        if sums_files:
            out["event_on"], out["event_off"] = load_event_counts(sums_files[image_idx], height, width)
        return out

    @property
    def modalities(self) -> Tuple[str, ...]:
        """Modalities present in this dataset, among ("rgb", "thermal", "events")."""
        return tuple(self.metadata.get("modalities", ("rgb",)))


def agrinerf_datamanager_config(parallel: bool = False, **kwargs: Any) -> VanillaDataManagerConfig:
    """Datamanager config for AgriNeRF methods over :class:`AgriNeRFDataset`.

    Args:
        parallel: use Nerfstudio's ``ParallelDataManager`` (a spawned process samples rays; scripts then need the
            ``if __name__ == "__main__":`` guard) instead of the in-process ``VanillaDataManager`` (the default:
            deterministic given the torch seed, and cheaper on a CPU).
        kwargs: fields of :class:`VanillaDataManagerConfig`, for example ``train_num_rays_per_batch=1024``; the
            dataparser defaults to :class:`AgriNeRFDataParserConfig`, the pixel sampler to
            :class:`FruitPixelSamplerConfig` (uniform; ``--pipeline.datamanager.pixel-sampler.fruit-share``).
    """
    kwargs.setdefault("dataparser", AgriNeRFDataParserConfig())
    kwargs.setdefault("pixel_sampler", FruitPixelSamplerConfig())  # uniform unless its fruit_share is set
    if parallel:
        return ParallelDataManagerConfig(_target=ParallelDataManager[AgriNeRFDataset], **kwargs)
    return VanillaDataManagerConfig(_target=VanillaDataManager[AgriNeRFDataset], **kwargs)
