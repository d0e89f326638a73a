"""The count renders the training views where the run fitted them: at the poses it refined, when it refined them."""

import json
from pathlib import Path

import numpy as np
import torch


def test_the_count_renders_training_views_at_the_refined_poses(tiny_run_config: Path, tmp_path: Path) -> None:
    from nerfstudio.cameras.camera_optimizers import CameraOptimizerConfig

    from agrinerf_ns.count.render import load_renders, render_loaded_run
    from agrinerf_ns.detect.render_views import load_run

    run = load_run(tiny_run_config)
    plain = render_loaded_run(run, splits=("train",))
    assert plain.poses["train_views"] == "as in the dataset" and plain.poses["source"] != "unknown"
    # the run as if trained with Nerfstudio's pose refinement: camera 1 moved 0.1 along x by the optimizer
    model = run.pipeline.model
    cameras = len(run.pipeline.datamanager.train_dataset)
    model.camera_optimizer = CameraOptimizerConfig(mode="SO3xR3").setup(num_cameras=cameras, device="cpu")
    with torch.no_grad():
        model.camera_optimizer.pose_adjustment[1, 0] = 0.1
    refined = render_loaded_run(run, tmp_path / "renders", splits=("train",))
    assert refined.poses["train_views"] == "refined by the run (SO3xR3)"
    shift = refined.views[1].origins - plain.views[1].origins
    np.testing.assert_allclose(shift[..., 0], 0.1, atol=1e-5)
    np.testing.assert_allclose(shift[..., 1:], 0.0, atol=1e-5)
    np.testing.assert_allclose(refined.views[0].origins, plain.views[0].origins, atol=1e-6)  # not adjusted
    # the pose record travels with the renders into a recount's count.json
    assert load_renders(tmp_path / "renders").poses == refined.poses
    assert json.loads((tmp_path / "renders" / "renders.json").read_text())["poses"]["train_views"].startswith("refined")
