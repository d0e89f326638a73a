"""``agrinerf-export pointcloud``: Nerfstudio's point-cloud export that also keeps a single-channel output (the
cross-spectral ``thermal``) as a float property of every point, beside its colormap colours.

``ns-export pointcloud --rgb-output-name thermal --normal-method open3d`` works on AgriNeRF runs too: the model's
``get_rgba_image`` colours the thermal output by a colormap and takes the accumulation as alpha. But Nerfstudio's
``generate_point_cloud`` keeps only the three colour channels, so the value itself is lost. This command is Nerfstudio's
``ExportPointCloud`` (same flags, same sampling: training rays, the depth output, alpha > 0.5, open3d statistical outlier
removal and normals) with its own sampling loop, written here because the value must follow the points through the
outlier removal and Nerfstudio's function returns no index for it. The PLY is written with open3d's tensor writer,
which stores extra point attributes as PLY properties.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Dict, List, Literal, Optional

import numpy as np
import torch
import tyro
from jaxtyping import Float
from torch import Tensor

from agrinerf_ns.system_deps import SystemDependencyError, import_open3d

ALPHA_THRESHOLD = 0.5
"""A ray gives a point where the alpha of `get_rgba_image` (AgriNeRF: the accumulation) is above this, as in ns-export."""
MAX_EMPTY_BATCHES = 20
"""Give up after this many batches in a row without a single point (an untrained run or a crop box with nothing)."""


class ExportError(ValueError):
    """The run cannot be exported as asked (an output it does not have, no point passed alpha or the crop box)."""


def sample_points(
    pipeline: Any,
    output_name: str,
    depth_output_name: str,
    num_points: int,
    crop_obb: Optional[Any] = None,
    normal_output_name: Optional[str] = None,
) -> Dict[str, Tensor]:
    """Points from batches of training rays until `num_points`: origin + direction x depth where alpha > 0.5.

    Returns "points" [N, 3], "colours" [N, 3] (the model's `get_rgba_image`), "directions" [N, 3], "values"
    [N, C] (the output itself: C = 1 for thermal, 3 for rgb) and, when asked, "normals" [N, 3] in [-1, 1].
    Raises ExportError naming the model's outputs when an asked output is not one of them.
    """
    names = [output_name, depth_output_name] + ([normal_output_name] if normal_output_name else [])
    parts: Dict[str, List[Tensor]] = {}
    count, empty = 0, 0
    while count < num_points:
        with torch.no_grad():
            ray_bundle, _ = pipeline.datamanager.next_train(0)
            outputs = pipeline.model(ray_bundle)
            missing = [name for name in names if name not in outputs]
            if missing:
                raise ExportError(f"{missing} not among the model's outputs {sorted(outputs)}")
            rgba = pipeline.model.get_rgba_image(outputs, output_name)
        keep = rgba[..., -1] > ALPHA_THRESHOLD
        batch = {
            "points": (ray_bundle.origins + ray_bundle.directions * outputs[depth_output_name])[keep],
            "colours": rgba[..., :3][keep],
            "directions": ray_bundle.directions[keep],
            "values": outputs[output_name][keep],
        }
        if normal_output_name:
            batch["normals"] = outputs[normal_output_name][keep] * 2.0 - 1.0  # Nerfstudio's normals are in [0, 1]
        if crop_obb is not None:
            inside = crop_obb.within(batch["points"])
            batch = {k: v[inside] for k, v in batch.items()}
        found = batch["points"].shape[0]
        empty = 0 if found else empty + 1
        if empty >= MAX_EMPTY_BATCHES:
            raise ExportError(
                f"no ray of {MAX_EMPTY_BATCHES} batches passed alpha > {ALPHA_THRESHOLD} (or the crop box)"
            )
        for key, value in batch.items():
            parts.setdefault(key, []).append(value.float().cpu())
        count += found
    return {key: torch.cat(values)[:num_points] for key, values in parts.items()}


def write_ply_atomically(o3d: Any, cloud: Any, path: os.PathLike) -> None:
    """Write an open3d tensor point cloud to `path` through a temporary sibling renamed into place."""
    path = os.fspath(path)
    tmp = os.path.join(os.path.dirname(path), f".{os.path.basename(path)}.tmp-{os.getpid()}.ply")
    try:
        if not o3d.t.io.write_point_cloud(tmp, cloud):
            raise OSError(f"{path}: open3d could not write the point cloud")
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def to_world_frame(pipeline: Any, points: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, "n 3"]:
    """Points from the model's scaled, reoriented frame back into the dataset's (Nerfstudio's inverse transform)."""
    poses = np.tile(np.eye(4, dtype=np.float32)[None, :3, :], (points.shape[0], 1, 1))
    poses[:, :3, 3] = points
    outputs = pipeline.datamanager.train_dataparser_outputs
    return outputs.transform_poses_to_original_space(torch.from_numpy(poses))[:, :3, 3].numpy()


def export_point_cloud_command() -> type:
    """The command's dataclass, a subclass of Nerfstudio's (built on call: importing it loads open3d)."""
    from nerfstudio.scripts.exporter import ExportPointCloud

    @dataclass
    class ExportValuePointCloud(ExportPointCloud):
        """Export a point cloud; a single-channel output (thermal) is also written as a float PLY property named
        after the output, beside its colormap colours."""

        rgb_output_name: str = "thermal"
        """Output to colour the points by (one channel: colormap colours plus the value as a property)."""
        normal_method: Literal["open3d", "model_output"] = "open3d"
        """Method to estimate normals with (AgriNeRF renders no normals: open3d)."""

        def main(self) -> None:
            """Export `point_cloud.ply` into `output_dir`."""
            from nerfstudio.data.scene_box import OrientedBox
            from nerfstudio.utils.eval_utils import eval_setup
            from nerfstudio.utils.rich_utils import CONSOLE

            o3d = import_open3d()
            self.output_dir.mkdir(parents=True, exist_ok=True)
            _, pipeline, _, _ = eval_setup(self.load_config)
            # the datamanager is an nn.Module, so mypy types its attributes Tensor | Module
            sampler = pipeline.datamanager.train_pixel_sampler
            sampler.num_rays_per_batch = self.num_rays_per_batch  # type: ignore[union-attr]
            crop_obb = None
            if self.obb_center is not None and self.obb_rotation is not None and self.obb_scale is not None:
                crop_obb = OrientedBox.from_params(self.obb_center, self.obb_rotation, self.obb_scale)
            normal_name = self.normal_output_name if self.normal_method == "model_output" else None
            sampled = sample_points(
                pipeline, self.rgb_output_name, self.depth_output_name, self.num_points, crop_obb, normal_name
            )
            cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(sampled["points"].double().numpy()))
            cloud.colors = o3d.utility.Vector3dVector(sampled["colours"].double().clamp(0, 1).numpy())
            kept = np.arange(len(cloud.points))
            if self.remove_outliers:
                cloud, kept = cloud.remove_statistical_outlier(nb_neighbors=20, std_ratio=self.std_ratio)
                kept = np.asarray(kept)
            if normal_name is None:
                cloud.estimate_normals()
            else:
                cloud.normals = o3d.utility.Vector3dVector(sampled["normals"].double().numpy()[kept])
            if self.reorient_normals:  # normals face the cameras that saw the points
                normals = np.asarray(cloud.normals)
                normals[np.sum(sampled["directions"].numpy()[kept] * normals, axis=-1) > 0] *= -1
                cloud.normals = o3d.utility.Vector3dVector(normals)
            if self.save_world_frame:
                cloud.points = o3d.utility.Vector3dVector(to_world_frame(pipeline, np.asarray(cloud.points)))
            tensor_cloud = o3d.t.geometry.PointCloud.from_legacy(cloud)
            tensor_cloud.point.colors = (tensor_cloud.point.colors * 255).to(o3d.core.Dtype.UInt8)
            values = sampled["values"].numpy()[kept]
            if values.shape[-1] == 1:
                tensor_cloud.point[self.rgb_output_name] = o3d.core.Tensor(values.astype(np.float32))
            path = self.output_dir / "point_cloud.ply"
            write_ply_atomically(o3d, tensor_cloud, path)
            CONSOLE.print(f"[bold green]{path}: {len(kept)} points coloured by '{self.rgb_output_name}'")

    return ExportValuePointCloud


def entrypoint() -> None:
    """Console script ``agrinerf-export``: checks open3d's system library before any work."""
    from agrinerf_ns import compat

    compat.activate()
    try:
        import_open3d()
        tyro.extras.set_accent_color("bright_yellow")
        command = tyro.extras.subcommand_cli_from_dict(
            {"pointcloud": export_point_cloud_command()}, config=(tyro.conf.FlagConversionOff,)
        )
        command.main()
    except (SystemDependencyError, ExportError) as err:
        raise SystemExit(f"agrinerf-export: {err}") from None


if __name__ == "__main__":
    entrypoint()
