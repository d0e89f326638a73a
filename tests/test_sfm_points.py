"""SfM points as ns-process-data writes them (``ply_file_path``: ``sparse_pc.ply``), read without open3d: the reader
against the PLY layouts in use, the dataparser's metadata as Nerfstudio's pipeline reads it, and ``ns-train`` on such
a dataset on a machine where open3d cannot be imported."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from agrinerf_ns.dataparsers.sfm_points import GREY, PlyError, load_points3d, read_ply_points


def _colmap_dataset(root: Path, n_points: int = 300) -> Path:
    """A 4-view RGB scene whose SfM points are written by Nerfstudio's own ``create_ply_from_colmap`` (what
    ns-process-data runs after COLMAP) from a COLMAP ``points3D.txt``, with ``ply_file_path`` in transforms.json."""
    from helpers.model_scene import write_model_scene
    from nerfstudio.process_data.colmap_utils import create_ply_from_colmap

    data = write_model_scene(root, views=4, modalities=("rgb",))
    gen = np.random.default_rng(0)
    xyz = gen.uniform([-0.3, -0.2, -0.1], [0.2, 0.3, 0.25], size=(n_points, 3))
    rgb = gen.integers(0, 256, size=(n_points, 3))
    recon = root / "colmap" / "sparse" / "0"
    recon.mkdir(parents=True)
    rows = [
        f"{i + 1} {x} {y} {z} {r} {g} {b} 0.5 1 0 2 0"
        for i, ((x, y, z), (r, g, b)) in enumerate(zip(xyz, rgb, strict=True))
    ]
    (recon / "points3D.txt").write_text("# 3D point list\n" + "\n".join(rows) + "\n")
    applied = np.eye(4)[[0, 2, 1], :]  # what ns-process-data applies to COLMAP's frame (colmap_to_json)
    applied[2] *= -1
    create_ply_from_colmap("sparse_pc.ply", recon, data, torch.from_numpy(applied[:3]).float())
    meta = json.loads((data / "transforms.json").read_text())
    meta["ply_file_path"] = "sparse_pc.ply"
    meta["applied_transform"] = applied[:3].tolist()
    (data / "transforms.json").write_text(json.dumps(meta))
    return data


def _binary_ply(path: Path, order: str, xyz: np.ndarray, rgb: np.ndarray) -> None:
    """A binary PLY with double positions, float normals and uchar colours after a scalar-only element."""
    fmt = {"<": "binary_little_endian", ">": "binary_big_endian"}[order]
    header = (
        f"ply\nformat {fmt} 1.0\ncomment made by a test\nelement camera 1\nproperty float view\n"
        f"element vertex {len(xyz)}\nproperty double x\nproperty double y\nproperty double z\nproperty float nx\n"
        "property float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
        "end_header\n"
    )
    camera = np.zeros(1, dtype=[("view", order + "f4")])
    vertex = np.zeros(len(xyz), dtype=[(a, order + "f8") for a in "xyz"] + [(a, order + "f4") for a in ("nx", "ny", "nz")]
                      + [(c, "u1") for c in ("red", "green", "blue")])  # fmt: skip
    for i, a in enumerate("xyz"):
        vertex[a] = xyz[:, i]
    for i, c in enumerate(("red", "green", "blue")):
        vertex[c] = rgb[:, i]
    path.write_bytes(header.encode() + camera.tobytes() + vertex.tobytes())


def test_reads_what_nerfstudio_writes_and_binary_plys(tmp_path: Path) -> None:
    data = _colmap_dataset(tmp_path / "scene")
    xyz, rgb = read_ply_points(data / "sparse_pc.ply")
    rows = np.loadtxt(tmp_path / "scene" / "colmap" / "sparse" / "0" / "points3D.txt", comments="#")
    saved = rows[:, 1:4] @ np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]]).T  # the applied transform
    np.testing.assert_allclose(xyz, saved, atol=1e-6)  # Nerfstudio writes 6 decimals
    np.testing.assert_array_equal(rgb, rows[:, 4:7].astype(np.uint8))
    gen = np.random.default_rng(1)
    points, colours = gen.normal(size=(50, 3)), gen.integers(0, 256, size=(50, 3)).astype(np.uint8)
    for order in "<>":
        _binary_ply(tmp_path / f"b{order == '<'}.ply", order, points, colours)
        got_xyz, got_rgb = read_ply_points(tmp_path / f"b{order == '<'}.ply")
        np.testing.assert_array_equal(got_xyz, points)
        np.testing.assert_array_equal(got_rgb, colours)


def test_points_without_colours_are_grey_and_bad_files_name_themselves(tmp_path: Path) -> None:
    plain = tmp_path / "plain.ply"
    plain.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
                     "end_header\n0 0 0\n1 2 3\n")  # fmt: skip
    xyz, rgb = read_ply_points(plain)
    assert xyz.tolist() == [[0, 0, 0], [1, 2, 3]] and (rgb == GREY).all()
    cases = {
        "not_ply.ply": b"solid cube\n",
        "short.ply": b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        b"end_header\n0 0 0\n",
        "truncated.ply": b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        b"property float z\nend_header\n" + b"\0" * 20,
        "no_xyz.ply": b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float u\nend_header\n0\n",
    }
    for name, content in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(PlyError, match=name):
            read_ply_points(tmp_path / name)


def test_points_move_with_the_dataparser_transform(tmp_path: Path) -> None:
    path = tmp_path / "p.ply"
    _binary_ply(path, "<", np.array([[1.0, 2.0, 3.0]]), np.array([[10, 20, 30]], dtype=np.uint8))
    transform = torch.tensor([[0.0, -1.0, 0.0, 0.5], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, -1.0]])
    points = load_points3d(path, transform, 2.0)
    assert points["points3D_xyz"].dtype == torch.float32 and points["points3D_rgb"].dtype == torch.uint8
    assert points["points3D_xyz"].tolist() == [[2.0 * (-2.0 + 0.5), 2.0 * 1.0, 2.0 * (3.0 - 1.0)]]
    assert points["points3D_rgb"].tolist() == [[10, 20, 30]]


def test_dataparser_gives_the_points_nerfstudios_pipeline_reads(tmp_path: Path) -> None:
    """points3D_xyz with points3D_rgb (VanillaPipeline reads both), and the points where Nerfstudio's own parser
    puts them (its open3d reader, where open3d imports)."""
    from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataParserConfig

    data = _colmap_dataset(tmp_path / "scene")
    outputs = AgriNeRFDataParserConfig(data=data).setup().get_dataparser_outputs("train")
    xyz, rgb = outputs.metadata["points3D_xyz"], outputs.metadata["points3D_rgb"]
    assert xyz.shape == (300, 3) and rgb.shape == (300, 3) and rgb.dtype == torch.uint8
    try:
        import open3d  # noqa: F401
    except Exception:  # noqa: BLE001 - libusb missing: nothing to compare with
        return
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

    theirs = NerfstudioDataParserConfig(data=data, load_3D_points=True).setup().get_dataparser_outputs("train")
    torch.testing.assert_close(xyz, theirs.metadata["points3D_xyz"].float(), atol=1e-5, rtol=0)
    # open3d reads colours as c / 255 and Nerfstudio truncates c / 255 * 255: one unit lower at some values
    assert int((rgb.int() - theirs.metadata["points3D_rgb"].int()).abs().max()) <= 1


@pytest.mark.slow
def test_ns_train_on_a_dataset_with_sfm_points_without_open3d(tmp_path: Path, monkeypatch) -> None:
    """`ns-train agrinerf-lite` for 5 steps on such a dataset, with every import of open3d failing as it does on a
    machine without libusb."""
    from agrinerf_ns.ns_commands import ns_train

    blocker = tmp_path / "no_open3d" / "open3d"
    blocker.mkdir(parents=True)
    (blocker / "__init__.py").write_text('raise ImportError("open3d blocked by the test: libusb-1.0.so.0 missing")\n')
    monkeypatch.setenv("PYTHONPATH", str(blocker.parent))
    data = _colmap_dataset(tmp_path / "scene")
    small = ["--pipeline.model.init-resolution", "16", "--pipeline.model.final-resolution", "24",
             "--pipeline.model.upsampling-iters", "--pipeline.model.box-fit-iters", "3",
             "--pipeline.model.box-fit-rays", "512", "--machine.device-type", "cpu"]  # fmt: skip
    run = ns_train("agrinerf-lite", data, tmp_path / "outputs", "sfm", max_steps=5, rays_per_batch=256,
                   extra_args=small, steps_per_save=5, timeout=600.0)  # fmt: skip
    log = run.config.parent.parent.parent / "agrinerf-lite.train.log"
    assert run.checkpoints(), log.read_text()[-2000:]
    assert "open3d blocked" not in log.read_text()
