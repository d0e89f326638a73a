"""What a user takes away from a trained AgriNeRF run, through the real commands on a tiny run: `ns-export pointcloud`
(rgb and thermal), `agrinerf-export pointcloud` (the thermal value as a PLY property), `ns-export tsdf` (thermal) and
`ns-render interpolate --output-format video` with the ffmpeg of imageio-ffmpeg (a dependency), between the training
cameras and on the split of one held-out camera.

The exporters run in this process through their console scripts' entry points with a command line in `sys.argv`
(the same parsing and code as the installed `ns-export`, without a new interpreter's 20 s of imports each);
`ns-render` runs as its own process, to check that it finds ffmpeg without the venv on PATH."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import matplotlib
import numpy as np
import pytest

from agrinerf_ns import system_deps

pytestmark = pytest.mark.slow

ENV = {**os.environ, "PYTHONWARNINGS": "ignore"}
TURBO = np.asarray(matplotlib.colormaps["turbo"].colors) * 255.0  # Nerfstudio's colormap for one-channel outputs


def _run(cmd, env=ENV) -> None:
    subprocess.run(cmd, check=True, env=env, timeout=600)


def _command(monkeypatch, entrypoint, argv) -> None:
    """Run a console script's entry point on the command line `argv` (argv[0]: the script's name)."""
    monkeypatch.setattr(sys, "argv", [str(a) for a in argv])
    entrypoint()


def _ns_export(monkeypatch, *args) -> None:
    from nerfstudio.scripts.exporter import entrypoint

    _command(monkeypatch, entrypoint, ["ns-export", *args])


def _on_turbo(colours: np.ndarray) -> np.ndarray:
    """Distance of each uint8 colour to the nearest entry of the turbo colormap."""
    return np.abs(colours[:, None, :].astype(float) - TURBO[None]).max(axis=-1).min(axis=-1)


def _read_cloud(path: Path):
    o3d = system_deps.import_open3d()
    assert path.is_file(), path
    return o3d.t.io.read_point_cloud(str(path)).point


@pytest.mark.parametrize("output", ["rgb", "thermal"])
def test_ns_export_pointcloud(tiny_run_config: Path, tmp_path: Path, monkeypatch, output: str) -> None:
    """Nerfstudio's own exporter: points where the accumulation passes 0.5, thermal coloured by the turbo colormap."""
    args = ["pointcloud", "--load-config", tiny_run_config, "--output-dir", tmp_path, "--rgb-output-name", output]
    _ns_export(monkeypatch, *args, "--normal-method", "open3d", "--num-points", "2000", "--num-rays-per-batch", "1024")
    cloud = _read_cloud(tmp_path / "point_cloud.ply")
    points, colours = cloud.positions.numpy(), cloud.colors.numpy()
    assert points.shape[0] > 1000 and np.isfinite(points).all()  # 2048 asked (whole batches), few outliers
    assert colours.shape == points.shape and cloud.normals.numpy().shape == points.shape
    on_turbo = _on_turbo(colours) <= 1.0
    if output == "thermal":
        assert on_turbo.all()
    else:
        assert not on_turbo.all()  # the rgb cloud holds the scene's colours (checker, sky), not a colormap


def test_agrinerf_export_keeps_the_thermal_value(tiny_run_config: Path, tmp_path: Path, monkeypatch) -> None:
    """The thermal value of every point is a float PLY property; the colours are its turbo colormap."""
    from agrinerf_ns.export import entrypoint

    argv = ["agrinerf-export", "pointcloud", "--load-config", tiny_run_config, "--output-dir", tmp_path]
    argv += ["--rgb-output-name", "thermal", "--num-points", "2000", "--num-rays-per-batch", "1024"]
    _command(monkeypatch, entrypoint, argv)
    cloud = _read_cloud(tmp_path / "point_cloud.ply")
    points, colours, values = cloud.positions.numpy(), cloud.colors.numpy(), cloud["thermal"].numpy()
    assert points.shape[0] > 1000 and values.shape == (points.shape[0], 1) and values.dtype == np.float32
    assert 0.0 <= values.min() < values.max() <= 1.0
    expected = TURBO[np.clip((values[:, 0] * 255).astype(int), 0, 255)]  # Nerfstudio's apply_float_colormap
    assert np.abs(colours - expected).max() <= 1.0  # uint8 truncation
    assert not list(tmp_path.glob(".*tmp*"))  # written atomically


def test_agrinerf_export_names_a_missing_output(tiny_run_config: Path, tmp_path: Path, monkeypatch) -> None:
    from agrinerf_ns.export import entrypoint

    argv = ["agrinerf-export", "pointcloud", "--load-config", tiny_run_config, "--output-dir", tmp_path]
    with pytest.raises(SystemExit, match=r"\['temperature'\] not among the model's outputs \[.*'thermal'"):
        _command(monkeypatch, entrypoint, argv + ["--rgb-output-name", "temperature"])
    assert not (tmp_path / "point_cloud.ply").exists()


def test_ns_export_tsdf_thermal(tiny_run_config: Path, tmp_path: Path, monkeypatch) -> None:
    """A mesh exporter that needs no normals (TSDF), coloured by the thermal output."""
    args = ["tsdf", "--load-config", tiny_run_config, "--output-dir", tmp_path, "--rgb-output-name", "thermal"]
    _ns_export(monkeypatch, *args, "--texture-method", "tsdf", "--resolution", "32")
    o3d = system_deps.import_open3d()
    mesh = o3d.io.read_triangle_mesh(str(tmp_path / "tsdf_mesh.ply"))
    assert len(mesh.vertices) > 100 and len(mesh.triangles) > 100 and mesh.has_vertex_colors()


def test_ns_render_interpolate_video(tiny_run_config: Path, tmp_path: Path) -> None:
    """`.venv/bin/ns-render` as a user runs it without activating the venv: PATH lacks the venv's bin folder, and the
    plugin's compat shim finds an ffmpeg (imageio-ffmpeg's). The video holds rgb | thermal side by side."""
    import mediapy

    venv_bin = str(Path(sys.executable).parent)
    path = os.pathsep.join(p for p in ENV["PATH"].split(os.pathsep) if p != venv_bin)
    video = tmp_path / "interpolated.mp4"
    cmd = [str(Path(venv_bin) / "ns-render"), "interpolate", "--load-config", str(tiny_run_config)]
    cmd += ["--output-path", str(video), "--output-format", "video", "--pose-source", "train"]
    cmd += ["--interpolation-steps", "1", "--frame-rate", "4", "--rendered-output-names", "rgb", "thermal"]
    _run(cmd, env={**ENV, "PATH": path})
    assert shutil.which("ffmpeg"), "the test reads the video back with ffmpeg (mediapy)"
    frames = mediapy.read_video(str(video))
    assert frames.shape == (8, 48, 128, 3)  # 9 training views, one step per transition; 64x48 rgb + thermal
    assert frames.std() > 5  # an image, not a blank frame


def test_ns_render_interpolate_on_one_held_out_camera_writes_a_video(tiny_run_config: Path, tmp_path: Path) -> None:
    """The tiny scene holds out one of its 10 views: `ns-render interpolate` (default `--pose-source eval`) renders
    that view for `--interpolation-steps` frames and names `--pose-source train`, instead of failing in numpy."""
    import mediapy

    venv_bin = str(Path(sys.executable).parent)
    path = os.pathsep.join(p for p in ENV["PATH"].split(os.pathsep) if p != venv_bin)
    video = tmp_path / "held_out.mp4"
    cmd = [str(Path(venv_bin) / "ns-render"), "interpolate", "--load-config", str(tiny_run_config)]
    cmd += ["--output-path", str(video), "--interpolation-steps", "3", "--frame-rate", "4"]
    done = subprocess.run(cmd, env={**ENV, "PATH": path, "COLUMNS": "200"}, capture_output=True, text=True,
                          timeout=600, check=False)  # fmt: skip
    assert done.returncode == 0, (done.stdout + done.stderr)[-3000:]
    assert "--pose-source train" in done.stdout + done.stderr
    frames = mediapy.read_video(str(video))
    assert frames.shape == (3, 48, 64, 3)  # the one held-out camera, 3 frames of its rgb render
    assert frames.std() > 5
    # the path holds still: the frames differ only by the lossy codec (an I-frame, then P-frames)
    change = np.abs(frames[0].astype(int) - frames[-1].astype(int))
    assert change.mean() < 0.5 and change.max() <= 8, (change.mean(), change.max())


def test_system_deps_report_nothing_missing_after_install(capsys) -> None:
    """`python -m agrinerf_ns.system_deps`, which scripts/install.sh runs: on a machine set up as .ci/run does, it
    finds open3d's libusb and an ffmpeg."""
    assert system_deps.main() == 0, capsys.readouterr().err


def test_pymeshlab_without_libopengl_gets_the_install_command(monkeypatch) -> None:
    """pymeshlab imports without libOpenGL.so.0 and then saves no PLY (seen on a fresh Debian); the check names the
    package."""

    def no_library(name, *args, **kwargs):
        raise OSError(f"{name}: cannot open shared object file: No such file or directory")

    assert system_deps.meshlab_opengl_problem() is None  # installed as scripts/install.sh does
    monkeypatch.setattr(system_deps.ctypes, "CDLL", no_library)
    assert "apt-get install libopengl0" in str(system_deps.meshlab_opengl_problem())


@pytest.mark.parametrize(
    ("soname", "package"), [("libusb-1.0.so.0", "libusb-1.0-0"), ("libEGL.so.1", "libegl1"), ("libGL.so.1", "libgl1")]
)
def test_a_missing_open3d_library_gets_the_install_command(monkeypatch, soname: str, package: str) -> None:
    """open3d's import error when one of its system libraries is absent (the messages seen on a fresh Debian: libusb,
    then libEGL on a minimal one) becomes one that says what to install."""

    class NoLibrary:
        def find_spec(self, name, path=None, target=None):
            if name == "open3d":
                raise ImportError(f"{soname}: cannot open shared object file: No such file or directory")
            return None

    for name in [m for m in sys.modules if m == "open3d" or m.startswith("open3d.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setattr(sys, "meta_path", [NoLibrary(), *sys.meta_path])
    with pytest.raises(system_deps.SystemDependencyError, match=rf"apt-get install {re.escape(package)}'"):
        system_deps.import_open3d()
