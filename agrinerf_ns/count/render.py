"""Rendered views for counting: every camera of a trained run with its colour, cross-spectral, temperature, depth and
rays, cached as one ``.npz`` per view beside a ``renders.json`` (so detectors and clustering can be re-run without
rendering again).

Depth semantics: Nerfstudio's NeRF models (AgriNeRF, nerfacto, TensoRF) render ``depth`` as a distance along the
ray, in units of the ray direction, and the directions from ``Cameras.generate_rays`` are unit vectors
(``metadata["directions_norm"]`` holds the norm before normalisation, i.e. 1 / cos of the angle to the optical axis).
So a pixel's surface point is ``origin + direction * depth`` in Nerfstudio's (dataparser-transformed) frame, not
``depth * direction / directions_norm``, which would be a z-depth. AgriNeRF's ``depth`` is the median depth;
``expected_depth`` where a model has it is the weighted mean along the same ray.
"""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, Dict, List, Optional, Sequence

import numpy as np
from jaxtyping import Float

from agrinerf_ns.count.errors import CountInputError
from agrinerf_ns.count.source_table import SOURCE_TABLE, rendered_outputs
from agrinerf_ns.count.sources import RunOutputs, rgb_frames_dark
from agrinerf_ns.dataset_format import BLOCK, TRANSFORMS

if TYPE_CHECKING:
    from agrinerf_ns.run_loading import LoadedRun

RENDERS_JSON = "renders.json"


@dataclass(frozen=True)
class WorldFrame:
    """Nerfstudio's frame against the dataset's (``transforms.json``): ``p_ns = scale * (R p + t)``, as in the run
    folder's ``dataparser_transforms.json``."""

    transform: Float[np.ndarray, "3 4"]
    scale: float

    def to_dataset(self, points: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, "n 3"]:
        """Nerfstudio's frame -> the dataset's."""
        rot, t = self.transform[:, :3], self.transform[:, 3]
        return (np.asarray(points, np.float64).reshape(-1, 3) / self.scale - t) @ rot

    def to_ns(self, points: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, "n 3"]:
        """The dataset's frame -> Nerfstudio's."""
        rot, t = self.transform[:, :3], self.transform[:, 3]
        return self.scale * (np.asarray(points, np.float64).reshape(-1, 3) @ rot.T + t)

    @classmethod
    def read(cls, path: Path) -> "WorldFrame":
        """Read a ``dataparser_transforms.json``; raises :class:`CountInputError` naming it when malformed."""
        try:
            data = json.loads(Path(path).read_text())
            transform = np.asarray(data["transform"], dtype=np.float64)
            scale = float(data["scale"])
        except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
            raise CountInputError(f"{path}: not a Nerfstudio dataparser_transforms.json ({err!r})") from err
        if transform.shape != (3, 4) or not np.isfinite(transform).all() or not scale > 0:
            raise CountInputError(f"{path}: need a finite 3x4 'transform' and a 'scale' > 0")
        return cls(transform, scale)


@dataclass
class RenderedView:
    """One camera's rendered outputs, (H, W[, C]) arrays in Nerfstudio's frame."""

    name: str
    """The frame's stem (``000003``)."""
    split: str
    """``train`` or ``eval``."""
    file_path: str
    """The frame's RGB image relative to the dataset folder (``images/000003.png``)."""
    rgb: Optional[Float[np.ndarray, "h w 3"]]
    """None where the run has no RGB head (a Table IV ablation trained on thermal frames alone)."""
    depth: Float[np.ndarray, "h w"]
    accumulation: Float[np.ndarray, "h w"]
    origins: Float[np.ndarray, "h w 3"]
    directions: Float[np.ndarray, "h w 3"]
    """Unit ray directions."""
    focal: float
    """Focal length in pixels at this resolution (mean of fx, fy)."""
    thermal: Optional[Float[np.ndarray, "h w"]] = None
    temperature: Optional[Float[np.ndarray, "h w"]] = None
    fruit: Optional[Float[np.ndarray, "h w"]] = None
    """The fruit head's rendered probability (a run trained with fruit masks)."""
    fruit_depth: Optional[Float[np.ndarray, "h w"]] = None
    """Where along each ray the fruit head puts the fruit (the rendered depth where it puts none)."""
    extra: Dict[str, np.ndarray] = field(default_factory=dict)
    """The outputs of counting sources added to the table that are none of the above, by name."""

    def output(self, name: str) -> Optional[np.ndarray]:
        """The rendered output ``name`` (an attribute above or an ``extra``); None where the run renders none."""
        return getattr(self, name) if name in VIEW_ATTRIBUTES else self.extra.get(name)

    def optional_output(self, name: str) -> Float[np.ndarray, "h w *channels"]:
        """A counting source's rendered image (``rgb``, ``thermal``, ``temperature``, ``fruit``, ...); ValueError
        naming the view where the run renders none."""
        image = self.output(name)
        if image is None:
            kept = rendered_outputs().get(name)
            what = (kept.what if kept is not None else "") or f"'{name}'"
            why = kept.missing if kept is not None else ""
            raise ValueError(f"view {self.name}: the run renders no {what} output{why}")
        return image

    def outputs(self, dark: Optional[bool] = None) -> RunOutputs:
        """The sources this view holds (:func:`agrinerf_ns.count.sources.resolve_source`): those found in views whose
        first rendered output it holds; ``dark``: whether the run's RGB frames are dark (None: not known)."""
        held = {name: bool(row.finds_in_views() and row.renders and self.output(row.renders[0].name) is not None)
                for name, row in SOURCE_TABLE.items()}  # fmt: skip
        return RunOutputs(dark=dark, **held)

    def points(self) -> Float[np.ndarray, "h w 3"]:
        """The surface point of every pixel: origin + direction x depth."""
        return self.origins + self.directions * self.depth[..., None]

    def save(self, path: Path) -> None:
        arrays: Dict[str, np.ndarray] = {
            "depth": self.depth.astype(np.float32),
            "accumulation": self.accumulation.astype(np.float16),
            "origins": self.origins.astype(np.float32),
            "directions": self.directions.astype(np.float32),
        }
        for name, kept in rendered_outputs().items():  # the counting sources' outputs, as their rows store them
            image = self.output(name)
            if image is not None:
                arrays[name] = image.astype(kept.dtype)
        np.savez_compressed(path, focal=np.float64(self.focal), **arrays)


VIEW_ATTRIBUTES = frozenset(f.name for f in fields(RenderedView)) - {"extra"}
"""The outputs a :class:`RenderedView` holds as attributes (any other output of a source: in its ``extra``)."""


def view_outputs(arrays: Dict[str, np.ndarray]) -> Dict[str, Any]:
    """The :class:`RenderedView` arguments that hold ``arrays`` (the sources' rendered outputs, by name)."""
    named = {name: image for name, image in arrays.items() if name in VIEW_ATTRIBUTES}
    return {"rgb": None, **named, "extra": {name: image for name, image in arrays.items() if name not in named}}


@dataclass
class RenderSet:
    """The rendered views of a run and what is needed to read them: the frame conversion and the dataset folder."""

    views: List[RenderedView]
    frame: WorldFrame
    dataset: Optional[Path]
    config: Optional[Path]
    method: Optional[str]
    dark: Optional[bool] = None
    """Whether the run's RGB frames are dark by its model's low-light rule (None: not known, e.g. a render folder
    written before it was recorded); it decides the view path's ``auto`` source."""
    poses: Dict[str, str] = field(default_factory=dict)
    """Where the rendered views' poses come from: the dataset's pose ``source`` (odometry ``given``, ``sfm-rgb``,
    ...) and, per split, whether the run's pose refinement was applied (:func:`refined_camera`)."""

    def outputs(self) -> RunOutputs:
        """The sources its views hold (those of the first: every view of a run renders the same outputs)."""
        return self.views[0].outputs(self.dark) if self.views else RunOutputs(dark=self.dark)


def render_run(
    config_path: Path,
    out_dir: Optional[Path] = None,
    splits: Sequence[str] = ("train", "eval"),
    eval_num_rays_per_chunk: Optional[int] = None,
) -> RenderSet:
    """Render every camera of ``splits`` of the run saved at ``config_path`` (and cache them under ``out_dir``).

    Raises :class:`CountInputError` naming the config when the model renders no ``depth`` (checked on the first
    view) or the run folder lacks ``dataparser_transforms.json``.
    """
    from agrinerf_ns.run_loading import load_run

    config_path = Path(config_path)
    transforms = config_path.parent / "dataparser_transforms.json"
    if not transforms.is_file():
        raise CountInputError(
            f"{transforms}: missing; the run folder of {config_path} must hold it (ns-train writes it)"
        )
    return render_loaded_run(load_run(config_path, eval_num_rays_per_chunk), out_dir, splits)


def render_loaded_run(
    run: "LoadedRun", out_dir: Optional[Path] = None, splits: Sequence[str] = ("train", "eval")
) -> RenderSet:
    """:func:`render_run` of a run already loaded (``agrinerf_ns.run_loading.load_run``), e.g. one whose field a
    count has just sampled: the checkpoint is not read twice."""
    import torch

    from agrinerf_ns.progress import work_progress

    config_path = run.config_path
    frame = WorldFrame.read(config_path.parent / "dataparser_transforms.json")
    datamanager = run.pipeline.datamanager
    datasets = {"train": datamanager.train_dataset, "eval": datamanager.eval_dataset}
    dataset_dir = run.dataset_dir
    views: List[RenderedView] = []
    total = sum(len(datasets[s]) for s in splits if datasets[s] is not None)
    with work_progress(f"rendering {total} views ({run.method})", total) as progress:
        for split in splits:
            dataset = datasets[split]
            for index in range(0 if dataset is None else len(dataset)):
                camera = dataset.cameras[index : index + 1].to(run.pipeline.device)
                if split == "train":  # the poses the field was trained at, refined where the run refined them
                    camera = refined_camera(run.pipeline.model, camera, index)
                with torch.no_grad():
                    rays = camera.generate_rays(camera_indices=0, keep_shape=True)
                    outputs = run.pipeline.model.get_outputs_for_camera(camera)
                view = _view_from_outputs(outputs, rays, camera, dataset, index, split, config_path)
                if dataset_dir is not None:
                    view.file_path = relative_path(Path(dataset.image_filenames[index]), dataset_dir)
                views.append(view)
                progress.advance()
    result = RenderSet(views, frame, dataset_dir, config_path, run.method, rgb_frames_dark(run.pipeline.model),
                       pose_record(run.pipeline.model, dataset_dir))  # fmt: skip
    if out_dir is not None:
        save_renders(result, Path(out_dir))
    return result


def refinement_mode(model: Any) -> str:
    """The run's pose refinement (Nerfstudio's camera optimizer mode; ``off`` without one)."""
    optimizer = getattr(model, "camera_optimizer", None)
    return str(getattr(getattr(optimizer, "config", None), "mode", "off"))


def refined_camera(model: Any, camera: Any, index: int) -> Any:
    """Training camera ``index`` at the pose the run refined it to (Nerfstudio applies the camera optimizer to
    training rays only, so a render at the dataset's pose would sit where the field was not fitted); unchanged when
    the run did not refine poses."""
    import torch

    if refinement_mode(model) == "off":
        return camera
    adjusted = copy.copy(camera)
    adjusted.metadata = {**(camera.metadata or {}), "cam_idx": index}
    with torch.no_grad():
        adjusted.camera_to_worlds = model.camera_optimizer.apply_to_camera(adjusted)
    return adjusted


def pose_record(model: Any, dataset_dir: Optional[Path]) -> Dict[str, str]:
    """Where the views' poses come from (:attr:`RenderSet.poses`)."""
    source = "unknown" if dataset_dir is None else dataset_pose_source(dataset_dir)
    mode = refinement_mode(model)
    train = "as in the dataset" if mode == "off" else f"refined by the run ({mode})"
    return {"source": source, "train_views": train, "eval_views": "as in the dataset"}


def dataset_pose_source(dataset: Path) -> str:
    """Where a dataset's poses came from (``given``, ``sfm``; ``unknown`` where it does not say)."""
    try:
        meta = json.loads((Path(dataset) / TRANSFORMS).read_text()).get(BLOCK, {})
        return str(meta.get("poses", {}).get("source", "unknown"))
    except (OSError, json.JSONDecodeError, AttributeError):
        return "unknown"


def relative_path(image: Path, dataset_dir: Path) -> str:
    """An image's path relative to the dataset folder (as ``transforms.json``'s ``file_path``), else its name."""
    try:
        return str(image.resolve().relative_to(dataset_dir.resolve()))
    except ValueError:
        return image.name


def require_depth(outputs: Dict[str, Any], config_path: Path) -> None:
    """Raise :class:`CountInputError` naming the run's config when its model's ``outputs`` have no ``depth``."""
    if "depth" not in outputs:
        raise CountInputError(
            f"{config_path}: the run's model renders no 'depth' output (it renders: {', '.join(sorted(outputs))}); "
            "counting lifts detections to 3D with it"
        )


def _view_from_outputs(
    outputs: Dict[str, Any], rays: Any, camera: Any, dataset: Any, index: int, split: str, config_path: Path
) -> RenderedView:
    require_depth(outputs, config_path)

    def array(name: str) -> np.ndarray:
        return outputs[name].detach().float().cpu().numpy()

    path = Path(dataset.image_filenames[index])
    return RenderedView(
        name=path.stem,
        split=split,
        file_path=path.name,
        depth=array("depth")[..., 0],
        accumulation=array("accumulation")[..., 0] if "accumulation" in outputs else np.ones(array("depth").shape[:2]),
        origins=rays.origins.detach().float().cpu().numpy(),
        directions=rays.directions.detach().float().cpu().numpy(),
        focal=float((camera.fx[0, 0] + camera.fy[0, 0]).item() / 2),
        **view_outputs({name: array(name)[..., 0] if kept.channels == 1 else array(name)
                        for name, kept in rendered_outputs().items() if name in outputs}),
    )  # fmt: skip


def save_renders(renders: RenderSet, out_dir: Path) -> None:
    """Write ``<split>_<frame>.npz`` per view and ``renders.json`` into ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for view in renders.views:
        view.save(out_dir / f"{view.split}_{view.name}.npz")
    meta = {
        "config": None if renders.config is None else str(renders.config),
        "method": renders.method,
        "dataset": None if renders.dataset is None else str(renders.dataset),
        "dataparser_transform": renders.frame.transform.tolist(),
        "dataparser_scale": renders.frame.scale,
        "rgb_dark": renders.dark,
        "poses": renders.poses,
        "views": [{"name": v.name, "split": v.split, "file_path": v.file_path} for v in renders.views],
    }
    (out_dir / RENDERS_JSON).write_text(json.dumps(meta, indent=1) + "\n")


def load_renders(folder: Path) -> RenderSet:
    """Read a folder written by :func:`save_renders`; raises :class:`CountInputError` naming the folder or file when
    it is empty, lacks ``renders.json`` or a view file, or a view lacks depth."""
    folder = Path(folder)
    meta_path = folder / RENDERS_JSON
    if not folder.is_dir() or not any(folder.glob("*.npz")):
        raise CountInputError(
            f"{folder}: empty render folder (no <split>_<frame>.npz views; agrinerf-count --config "
            "writes them under OUT/renders)"
        )
    if not meta_path.is_file():
        raise CountInputError(f"{meta_path}: missing; a render folder needs it beside the .npz views")
    try:
        meta = json.loads(meta_path.read_text())
        frame = WorldFrame(np.asarray(meta["dataparser_transform"], np.float64), float(meta["dataparser_scale"]))
        entries = list(meta["views"])
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
        raise CountInputError(f"{meta_path}: not a render index ({err!r})") from err
    views = []
    for entry in entries:
        path = folder / f"{entry['split']}_{entry['name']}.npz"
        if not path.is_file():
            raise CountInputError(f"{path}: listed in {meta_path} but missing")
        with np.load(path) as data:
            if "depth" not in data:
                raise CountInputError(f"{path}: no 'depth' array (counting lifts detections to 3D with it)")
            views.append(
                RenderedView(
                    name=entry["name"],
                    split=entry["split"],
                    file_path=entry["file_path"],
                    depth=data["depth"].astype(np.float32),
                    accumulation=data["accumulation"].astype(np.float32),
                    origins=data["origins"].astype(np.float32),
                    directions=data["directions"].astype(np.float32),
                    focal=float(data["focal"]),
                    **view_outputs(
                        {name: data[name].astype(np.float32) for name in rendered_outputs() if name in data}
                    ),
                )
            )
    dataset = Path(meta["dataset"]) if meta.get("dataset") else None
    config = Path(meta["config"]) if meta.get("config") else None
    return RenderSet(views, frame, dataset, config, meta.get("method"), meta.get("rgb_dark"), meta.get("poses", {}))
