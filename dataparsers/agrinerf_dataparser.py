"""AgriNeRF dataparser: Nerfstudio's ``transforms.json`` plus per-frame thermal and event frames.

The dataset contract is in ``docs/formats.md``. Cameras, poses, scene box, scale and the train/eval split are
Nerfstudio's own (this parser subclasses :class:`Nerfstudio` and calls it), so the split is the one that
``ns-train nerfacto`` makes on the same folder. On top of it this parser finds, for every frame kept in the split,
the thermal and event frames (and their valid masks) and hands their paths to the dataset in
``DataparserOutputs.metadata``:

- ``"thermal_filenames"``, ``"thermal_mask_filenames"``, ``"event_filenames"``, ``"event_mask_filenames"``:
  lists of paths in the order of ``image_filenames``; a key is absent when its files are absent from the dataset
  (or the modality is not requested in ``modalities``).
- ``"modalities"``: the tuple of modalities that are both present and requested, among ("rgb", "thermal", "events").
- ``"agrinerf"``: the dataset's top-level ``agrinerf`` block (a dict; empty when the file has none).
- ``"rgb_level"``: the split's mean RGB value as a fraction of full scale (:func:`rgb_level`): how much light the
  RGB camera got, which decides the model's low-light routing (``low_light_level``); ``"rgb_gain"``: the factor the
  dataset scales every RGB frame by (``dark_rgb_target``; 1: as they are).
- ``"temperature_filenames"``: the frames' linear temperature images (``thermal_temperature_path``: 16-bit PNG in
  centikelvin, ``agrinerf_ns.temperature``) and ``"temperature_stats"`` (dict of floats ``mean_c``, ``std_c``,
  ``min_c``, ``max_c``, degrees C), only when the thermal frames are loaded and the dataset has temperatures (its
  thermal camera had a radiometric calibration).
- ``"times"``: float64 tensor [N], each image's ``timestamp`` (seconds, the capture's clock); ``"exposure"``: float64
  tensor [N, 2], its exposure interval (``exposure_start``, ``exposure_end``), or [t, t] (an instantaneous frame)
  when the dataset records no exposures; ``"trajectory"``: an :class:`agrinerf_ns.trajectory.CameraTrajectory`
  giving the camera-to-world pose (3x4, this parser's world frame and scale, OpenGL camera axes like
  ``cameras.camera_to_worlds``) at any time, from the dataset's ``trajectory.txt`` (the capture's odometry) when it
  has one, else from every frame's pose and timestamp (all splits: poses are inputs, not targets). The three are
  absent when the frames carry no ``timestamp``. Times are float64 seconds: subtract a reference before float32.

The thermal and event frames are aligned to the RGB camera, so they must have the RGB frame's full resolution
(``w`` x ``h`` in ``transforms.json``); the dataset resizes them like the image when the image is downscaled.
Before Nerfstudio's parser runs, ``dataset_checks`` checks the JSON, every frame's pose, intrinsics and every image it
names (there, whole, at the RGB frame's size); every :class:`AgriNeRFDataError` names the file (and the frame).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Dict, List, Optional, Tuple, Type

from nerfstudio.data.dataparsers.base_dataparser import DataparserOutputs
from nerfstudio.data.dataparsers.nerfstudio_dataparser import Nerfstudio, NerfstudioDataParserConfig
from nerfstudio.plugins.registry_dataparser import DataParserSpecification
from nerfstudio.utils.rich_utils import CONSOLE

from agrinerf_ns.dataparsers.dataset_checks import AgriNeRFDataError, check_dataset
from agrinerf_ns.dataparsers.fruit_masks import fruit_mask_paths
from agrinerf_ns.dataparsers.sfm_points import PlyError, load_points3d, saved_to_output
from agrinerf_ns.dataset_format import (
    ALIGNED_FRAMES,
    BLOCK,
    EVENT_MASK,
    EVENT_SUMS,
    EVENTS,
    EXPOSURE_END,
    EXPOSURE_START,
    FRUIT_MASK,
    FRUIT_MASK_CAMERA,
    TEMPERATURE,
    THERMAL,
    THERMAL_MASK,
    THERMAL_TIMESTAMP,
    TRANSFORMS,
)
from agrinerf_ns.modalities import ALL_MODALITIES, DARK_RGB_LEVEL, Modality
from agrinerf_ns.trajectory import CameraTrajectory, TrajectoryError, read_tum
from agrinerf_ns.views import evenly_spaced

if TYPE_CHECKING:
    from agrinerf_ns.dataparsers.event_stream import EventCamera


@dataclass
class AgriNeRFDataParserConfig(NerfstudioDataParserConfig):
    """Nerfstudio dataset config plus the thermal and event frames of an AgriNeRF dataset."""

    _target: Type = field(default_factory=lambda: AgriNeRFDataParser)
    """target class to instantiate"""
    modalities: Tuple[Modality, ...] = ALL_MODALITIES
    """Modalities to load when the dataset has them; a modality the dataset lacks is simply absent."""
    dark_rgb_target: Optional[float] = None
    """Where the dataset's RGB frames are dark (their mean below `dark_rgb_level` of full scale), scale them so that
    their mean reaches this fraction of full scale (clipped at 1; metadata ``rgb_gain``), so that the RGB loss shapes
    the scene as a lit frame's does: a few DN of signal under noise average out over many views (RawNeRF's
    observation). None: the frames as they are, whose loss is then a few DN deep."""
    dark_rgb_level: float = DARK_RGB_LEVEL
    """A mean RGB level (fraction of full scale) below which the frames are dark (the model's ``low_light_level``)."""


@dataclass
class AgriNeRFDataParser(Nerfstudio):
    """Nerfstudio's dataparser, extended with the per-frame thermal and event frames of an AgriNeRF dataset."""

    config: AgriNeRFDataParserConfig

    def _generate_dataparser_outputs(self, split: str = "train") -> DataparserOutputs:
        transforms_path = self.config.data if self.config.data.suffix == ".json" else self.config.data / TRANSFORMS
        # checked before Nerfstudio's parser reads it, so a bad file fails with its name before any training: the
        # JSON, every frame's pose and intrinsics, and every image it names (there, whole, at the RGB frame's size)
        meta = check_dataset(transforms_path)
        outputs = super()._generate_dataparser_outputs(split)
        data_dir = transforms_path.parent
        frames: List[Dict[str, Any]] = meta["frames"]

        present = _present_frame_keys(frames, transforms_path)
        block = meta.get(BLOCK, {}) or {}
        _warn_on_block_mismatch(block, present, transforms_path)

        # Nerfstudio sorts the frames and keeps those of the split: map its image paths back to their frames.
        frame_by_image = {self._get_fname(Path(f["file_path"]), data_dir): f for f in frames}
        kept = [frame_by_image[path] for path in outputs.image_filenames]

        metadata: Dict[str, Any] = {}
        for aligned in ALIGNED_FRAMES:
            if aligned.key not in present or aligned.modality not in self.config.modalities:
                continue
            metadata[aligned.metadata] = [data_dir / frame[aligned.key] for frame in kept]

        fruit_masks = fruit_mask_paths(kept, data_dir, transforms_path)
        if fruit_masks is not None:
            metadata[FRUIT_MASK.metadata] = fruit_masks
            # whose view each mask holds: the thermal camera's masks are supervised along its rays
            metadata["fruit_mask_thermal"] = [frame.get(FRUIT_MASK_CAMERA, "rgb") == "thermal" for frame in kept]
        if THERMAL.metadata in metadata:
            metadata.update(_temperature(frames, kept, block, meta, data_dir, transforms_path))
            camera = _warped_camera(block, outputs, meta, "thermal")
            if camera is not None:
                metadata["thermal_camera"] = camera

        if "events" in self.config.modalities and kept and all(EVENT_SUMS.key in f for f in kept):
            metadata.update(_event_sums(data_dir, kept))
            camera = _warped_camera(block, outputs, meta, "event")
            if camera is not None:
                metadata["event_camera"] = camera
            stream = _event_stream(block, outputs, meta, data_dir, transforms_path)
            if stream is not None:
                metadata["event_stream"] = stream

        sizes = {_frame_size(frame, meta) for frame in kept}
        if len(sizes) > 1 and any(aligned.metadata in metadata for aligned in ALIGNED_FRAMES):
            raise AgriNeRFDataError(
                f"{transforms_path}: frames have different sizes {sorted(sizes)[:3]}; thermal and event frames need "
                "one RGB resolution (Nerfstudio's variable-resolution batches cannot carry extra per-pixel keys)."
            )

        modalities = tuple(
            m
            for m in ALL_MODALITIES
            if m in self.config.modalities
            and (m == "rgb" or any(f.key in present for f in ALIGNED_FRAMES if f.modality == m and not f.valid_mask))
        )
        metadata["modalities"] = modalities
        metadata[BLOCK] = dict(block)
        metadata["rgb_level"] = rgb_level(outputs.image_filenames)
        metadata["rgb_gain"] = self._rgb_gain(frames, data_dir)
        metadata["metres_per_unit"] = metres_per_unit(block, meta, outputs)
        if "ply_file_path" in meta and "points3D_xyz" not in outputs.metadata:
            # SfM points (ns-process-data's sparse_pc.ply): where the model's first full-resolution box goes
            ply = data_dir / meta["ply_file_path"]
            if not ply.exists():
                raise AgriNeRFDataError(f"{transforms_path}: ply_file_path {meta['ply_file_path']} does not exist")
            try:  # read with NumPy: Nerfstudio's reader imports open3d, which needs libusb (sfm_points.py)
                transform = saved_to_output(meta, data_dir, outputs.dataparser_transform)
                points = load_points3d(ply, transform, float(outputs.dataparser_scale))
            except PlyError as err:
                raise AgriNeRFDataError(f"{transforms_path}: ply_file_path: {err}") from err
            metadata.update(points)  # points3D_xyz and points3D_rgb, the pair Nerfstudio's pipeline reads
        metadata.update(_timing(frames, kept, block, outputs, meta, data_dir, transforms_path))
        outputs.metadata.update(metadata)
        return outputs

    def _rgb_gain(self, frames: List[Dict[str, Any]], data_dir: Path) -> float:
        """The factor every RGB frame of every split is scaled by (`dark_rgb_target`); 1 for lit frames or when
        off. One level over all frames, so that held-out frames are scaled as the training frames are."""
        target = self.config.dark_rgb_target
        if target is None:
            return 1.0
        if not 0.0 < target <= 1.0:
            raise ValueError(f"dark_rgb_target must be in (0, 1], got {target}")
        level = rgb_level([self._get_fname(Path(f["file_path"]), data_dir) for f in frames])
        if not level < self.config.dark_rgb_level:  # lit (or no frames: NaN)
            return 1.0
        return target / max(level, 1.0 / 255.0)


def metres_per_unit(block: Dict[str, Any], meta: Dict[str, Any], outputs: DataparserOutputs) -> Optional[float]:
    """Metres per unit of this parser's world frame, where the saved poses are metric (the capture's odometry:
    ``agrinerf.poses.source`` "given"); None where the scale is unknown (SfM without a metric reference)."""
    if (block.get("poses") or {}).get("source") != "given":
        return None
    return float(meta.get("applied_scale", 1.0)) / float(outputs.dataparser_scale)


RGB_LEVEL_FRAMES = 8
"""Frames (evenly spaced over the split) whose mean gives the split's RGB level."""


def rgb_level(image_paths: List[Path]) -> float:
    """Mean RGB value of the split's frames as a fraction of full scale (0: black, 1: white), from up to
    RGB_LEVEL_FRAMES of them: how much light the RGB camera got (frames of a few DN carry mostly noise). NaN without
    frames."""
    import numpy as np
    from PIL import Image

    if not image_paths:
        return float("nan")
    means = []
    for k in evenly_spaced(len(image_paths), RGB_LEVEL_FRAMES):
        with Image.open(image_paths[k]) as image:
            array = np.asarray(image.convert("RGB"))
        means.append(float(array.mean()) / 255.0)
    return float(np.mean(means))


TEMPERATURE_STATS = ("mean_c", "std_c", "min_c", "max_c")


def _temperature(
    frames: List[Dict[str, Any]],
    kept: List[Dict[str, Any]],
    block: Dict[str, Any],
    meta: Dict[str, Any],
    data_dir: Path,
    transforms_path: Path,
) -> Dict[str, Any]:
    """``temperature_filenames`` (the frames' temperature images, checked like the thermal frames) and
    ``temperature_stats`` (mean_c, std_c, min_c, max_c: from ``agrinerf.thermal_temperature``, else from this split's
    images); empty when the dataset has no temperature images (its thermal camera has no radiometric calibration)."""
    import numpy as np

    from agrinerf_ns.temperature import decode_celsius

    given = [f for f in frames if TEMPERATURE.key in f]
    if not given:
        return {}
    if len(given) != len(frames):
        raise AgriNeRFDataError(
            f"{transforms_path}: '{TEMPERATURE.key}' is given in {len(given)} of {len(frames)} frames; give it for "
            "every frame or none."
        )
    paths = [data_dir / frame[TEMPERATURE.key] for frame in kept]
    recorded = block.get("thermal_temperature") or {}
    if all(k in recorded for k in TEMPERATURE_STATS):
        stats = {k: float(recorded[k]) for k in TEMPERATURE_STATS}
    else:
        from PIL import Image

        values = []
        for path in paths:
            celsius, valid = decode_celsius(np.asarray(Image.open(path)))
            values.append(celsius[valid])
        flat = np.concatenate(values) if values else np.zeros(0)
        if flat.size == 0:
            raise AgriNeRFDataError(f"{transforms_path}: the '{TEMPERATURE.key}' images hold no valid temperature")
        stats = {"mean_c": float(flat.mean()), "std_c": float(flat.std()), "min_c": float(flat.min()),
                 "max_c": float(flat.max())}  # fmt: skip
    if not all(np.isfinite(v) for v in stats.values()) or stats["max_c"] < stats["min_c"]:
        raise AgriNeRFDataError(f"{transforms_path}: temperature statistics {stats} are not finite and ordered")
    return {TEMPERATURE.metadata: paths, "temperature_stats": stats}


def _event_sums(data_dir: Path, kept: List[Dict[str, Any]]) -> Dict[str, Any]:
    """``event_sums_filenames`` (the frames' ``event_sums_path`` npz files) and ``event_windows`` (float64 [N, 2]: each
    file's ``t_start``, ``t_end`` in seconds), for the event loss."""
    import numpy as np
    import torch

    paths = [data_dir / frame[EVENT_SUMS.key] for frame in kept]
    windows = np.zeros((len(paths), 2), dtype=np.float64)
    for i, path in enumerate(paths):
        try:
            with np.load(path) as sums:
                windows[i] = (float(sums["t_start"]), float(sums["t_end"]))
        except (OSError, KeyError, ValueError) as error:
            raise AgriNeRFDataError(f"{path}: not an event-sums file with t_start and t_end ({error})") from error
    if not np.all(np.isfinite(windows)) or np.any(windows[:, 1] < windows[:, 0]):
        bad = int(np.flatnonzero(~(np.isfinite(windows).all(1) & (windows[:, 1] >= windows[:, 0])))[0])
        raise AgriNeRFDataError(f"{paths[bad]}: event window {windows[bad].tolist()} is not finite and ordered")
    return {EVENT_SUMS.metadata: paths, "event_windows": torch.from_numpy(windows)}


def _warped_camera(
    block: Dict[str, Any], outputs: DataparserOutputs, meta: Dict[str, Any], name: str
) -> Optional[Dict[str, Any]]:
    """Where the rays of the rig camera `name` ("thermal", "event"), whose frames were warped into the RGB camera,
    start: ``camera_centre``, its centre in the RGB camera's frame (OpenGL axes, this parser's scale, float64 [3]),
    and ``plane_depth``, the depth (same scale) of the plane the frames were warped at (inf: at infinity). None when
    the calibration has no such camera."""
    import numpy as np

    from agrinerf_ns.dataparsers.event_stream import rig_offset

    calib = (block.get("calibration") or {}).get(name)
    if not calib or "T_cam_rgb" not in calib:
        return None
    scale = float(outputs.dataparser_scale) / float(meta.get("applied_scale", 1.0))
    depth = float((block.get("alignment") or {}).get("plane_depth", "inf"))
    _, centre = rig_offset(np.asarray(calib["T_cam_rgb"], dtype=np.float64), scale)
    return {"camera_centre": centre, "plane_depth": depth * scale}


def _event_stream(
    block: Dict[str, Any], outputs: DataparserOutputs, meta: Dict[str, Any], data_dir: Path, transforms_path: Path
) -> Optional["EventCamera"]:
    """The event camera at its own pixels, for the event loss (:class:`agrinerf_ns.dataparsers.event_stream.EventCamera`:
    the dataset's ``events/stream.h5``, the calibration, the rig offset in this parser's scale). None when the
    dataset has no stream or no event calibration."""
    import numpy as np

    from agrinerf_ns.dataparsers.event_stream import EventCamera, rig_offset

    name = (block.get("events") or {}).get("stream")
    calib = (block.get("calibration") or {}).get("event")
    if not name or not calib or "T_cam_rgb" not in calib:
        return None
    path = data_dir / name
    if not path.exists():
        raise AgriNeRFDataError(f"{transforms_path}: agrinerf.events.stream names {path}, which does not exist")
    width, height = (int(v) for v in calib["resolution"])
    scale = float(outputs.dataparser_scale) / float(meta.get("applied_scale", 1.0))
    rotation, centre = rig_offset(np.asarray(calib["T_cam_rgb"], dtype=np.float64), scale)
    fx, fy, cx, cy = (float(v) for v in calib["intrinsics"])
    distortion = tuple(float(v) for v in calib.get("distortion_coeffs", ()))
    return EventCamera(path, width, height, (fx, fy, cx, cy), distortion, rotation, centre)


TRAJECTORY_CHECK_TOL = 1e-4
"""Largest difference (dataparser units) between the trajectory at a frame's time and the frame's camera pose."""


def _timing(
    frames: List[Dict[str, Any]],
    kept: List[Dict[str, Any]],
    block: Dict[str, Any],
    outputs: DataparserOutputs,
    meta: Dict[str, Any],
    data_dir: Path,
    transforms_path: Path,
) -> Dict[str, Any]:
    """The ``times``, ``exposure``, ``thermal_times`` and ``trajectory`` metadata of the kept frames (empty without
    timestamps)."""
    import numpy as np
    import torch

    if any("timestamp" not in f for f in frames):
        if any("timestamp" in f for f in frames):
            raise AgriNeRFDataError(f"{transforms_path}: 'timestamp' is given in some frames only; give it in all.")
        return {}
    with_exposure = [EXPOSURE_START in f and EXPOSURE_END in f for f in frames]
    if any(with_exposure) and not all(with_exposure):
        raise AgriNeRFDataError(
            f"{transforms_path}: 'exposure_start'/'exposure_end' are given in {sum(with_exposure)} of {len(frames)} "
            "frames; give them in every frame or none."
        )
    times = np.array([float(f["timestamp"]) for f in kept], dtype=np.float64)
    if all(with_exposure):
        exposure = np.array([[float(f[EXPOSURE_START]), float(f[EXPOSURE_END])] for f in kept], dtype=np.float64)
        exposure = exposure.reshape(-1, 2)  # an empty split too
        bad = np.flatnonzero(~(exposure[:, 1] >= exposure[:, 0]))
        if bad.size:
            raise AgriNeRFDataError(f"{transforms_path}: frame {kept[bad[0]]['file_path']} ends its exposure before "
                                    "it starts")  # fmt: skip
    else:
        exposure = np.stack([times, times], -1)

    # poses saved in transforms.json -> this parser's world frame: Nerfstudio's transform and scale, without the
    # applied_transform / applied_scale it folds into them (those describe the saved poses, not a change of them)
    transform = np.eye(4)
    transform[:3] = outputs.dataparser_transform.double().numpy()
    scale = float(outputs.dataparser_scale)
    if "applied_transform" in meta:
        applied = np.eye(4)
        applied[:3] = np.asarray(meta["applied_transform"], dtype=np.float64)
        transform = transform @ np.linalg.inv(applied)
    if "applied_scale" in meta:
        scale /= float(meta["applied_scale"])
    traj_block = block.get("trajectory") or {}
    try:
        if traj_block.get("file"):
            try:
                t_samples, c2w = read_tum(data_dir / traj_block["file"])
            except TrajectoryError as error:
                raise AgriNeRFDataError(f"trajectory named by agrinerf.trajectory.file: {error}") from error
        else:
            order = np.argsort([float(f["timestamp"]) for f in frames], kind="stable")
            t_samples = np.array([float(frames[i]["timestamp"]) for i in order])
            c2w = np.array([frames[i]["transform_matrix"] for i in order], dtype=np.float64)
        trajectory = CameraTrajectory(t_samples, c2w).transformed(transform[:3], scale)
    except TrajectoryError as error:
        raise AgriNeRFDataError(f"{transforms_path}: camera trajectory: {error}") from error

    out: Dict[str, Any] = {"times": torch.from_numpy(times), "exposure": torch.from_numpy(exposure)}
    if any(THERMAL_TIMESTAMP in f for f in kept):  # an unsynchronised thermal camera took its frame at another time
        thermal = [float(f.get(THERMAL_TIMESTAMP, f["timestamp"])) for f in kept]
        out["thermal_times"] = torch.from_numpy(np.array(thermal, dtype=np.float64))
    # the trajectory must reproduce the cameras at their own times (it cannot when the saved poses were changed
    # in a way this parser does not know, e.g. Nerfstudio's COLMAP default transform)
    err = np.abs(trajectory.poses_at(times) - outputs.cameras.camera_to_worlds.double().numpy()).max(initial=0.0)
    if err > TRAJECTORY_CHECK_TOL and not traj_block.get("file"):
        CONSOLE.print(f"[bold yellow]Warning: {transforms_path}: the frame poses interpolated at the frames' times "
                      f"differ from the cameras by {err:.2g}; no 'trajectory' in the dataparser metadata.")  # fmt: skip
    else:
        out["trajectory"] = trajectory
    return out


def _present_frame_keys(frames: List[Dict[str, Any]], transforms_path: Path) -> List[str]:
    """Per-frame keys given in every frame; raises if one is given in some frames only ("all or none")."""
    present = []
    for frame_key in (aligned.key for aligned in ALIGNED_FRAMES):
        missing = [f["file_path"] for f in frames if frame_key not in f]
        if len(missing) == len(frames):
            continue
        if missing:
            raise AgriNeRFDataError(
                f"{transforms_path}: '{frame_key}' is given in {len(frames) - len(missing)} of {len(frames)} frames "
                f"(missing for {missing[:3]}{' ...' if len(missing) > 3 else ''}); give it for every frame or none."
            )
        present.append(frame_key)
    for mask_key, file_key in ((THERMAL_MASK.key, THERMAL.key), (EVENT_MASK.key, EVENTS.key)):
        if mask_key in present and file_key not in present:
            raise AgriNeRFDataError(f"{transforms_path}: frames give '{mask_key}' but no '{file_key}'.")
    return present


def _warn_on_block_mismatch(block: Dict[str, Any], present: List[str], transforms_path: Path) -> None:
    """Warns when the ``agrinerf.modalities`` list disagrees with the per-frame files (the files win)."""
    if "modalities" not in block:
        return
    listed = set(block["modalities"])
    for modality, frame_key in ((THERMAL.modality, THERMAL.key), (EVENTS.modality, EVENTS.key)):
        if (modality in listed) != (frame_key in present):
            CONSOLE.print(
                f"[bold yellow]Warning: {transforms_path}: agrinerf.modalities {sorted(listed)} "
                f"{'lists' if modality in listed else 'does not list'} '{modality}' but the frames "
                f"{'lack' if modality in listed else 'give'} '{frame_key}'; going by the frames."
            )


def _frame_size(frame: Dict[str, Any], meta: Dict[str, Any]) -> Optional[Tuple[int, int]]:
    """Full-resolution (width, height) of a frame's RGB image, from the frame or the file's top level."""
    width, height = frame.get("w", meta.get("w")), frame.get("h", meta.get("h"))
    if width is None or height is None:
        return None
    return int(width), int(height)


agrinerf_dataparser = DataParserSpecification(
    config=AgriNeRFDataParserConfig(),
    description="AgriNeRF tri-modal dataset: Nerfstudio transforms.json plus aligned thermal and event frames",
)
