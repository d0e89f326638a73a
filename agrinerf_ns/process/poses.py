"""Camera poses: from the capture's odometry (``given``) or pycolmap SfM, in Nerfstudio's convention.

Conventions: raw poses (odometry.txt, truth/poses.txt) are camera-to-world with OpenCV camera axes (x right, y down,
z forward). Nerfstudio's ``transforms.json`` wants camera-to-world with OpenGL camera axes (x right, y up, z back):
:func:`opencv_to_opengl` flips the camera's y and z columns. World axes are kept as they are.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Literal, Optional, Tuple

import numpy as np
from jaxtyping import Float

from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.trajectory import read_tum


def opencv_to_opengl(c2w: Float[np.ndarray, "*b 4 4"]) -> Float[np.ndarray, "*b 4 4"]:
    """Camera-to-world, OpenCV camera axes -> OpenGL camera axes (the conversion is its own inverse)."""
    out = np.array(c2w, dtype=np.float64, copy=True)
    out[..., :3, 1:3] *= -1
    return out


def match_times(query: Float[np.ndarray, " n"], ref: Float[np.ndarray, " m"], tol: float) -> np.ndarray:
    """Index into ``ref`` of the nearest time to each query time, or -1 when farther than ``tol``."""
    idx = np.clip(np.searchsorted(ref, query), 1, max(1, len(ref) - 1))
    if len(ref) == 1:
        idx = np.zeros_like(idx)
        best = idx
    else:
        left, right = idx - 1, idx
        best = np.where(np.abs(ref[left] - query) <= np.abs(ref[right] - query), left, right)
    out = np.where(np.abs(ref[best] - query) <= tol, best, -1)
    return out.astype(np.int64)


def poses_from_odometry(
    odometry: Path, rgb_times: Float[np.ndarray, " n"], tol: float
) -> Tuple[Float[np.ndarray, "n 4 4"], np.ndarray]:
    """RGB camera-to-world (OpenCV axes) per RGB frame from a TUM file; second value: bool, frame has a pose."""
    t, c2w = read_tum(odometry)
    if np.any(np.diff(t) < 0):
        raise RawInputError(f"{odometry}: times must not decrease")
    idx = match_times(rgb_times, t, tol)
    if np.all(idx < 0):
        raise RawInputError(
            f"{odometry}: no pose within {tol:.4f} s of any RGB frame (odometry {t[0]:.3f}..{t[-1]:.3f} s, "
            f"RGB {rgb_times[0]:.3f}..{rgb_times[-1]:.3f} s): timestamps do not overlap"
        )
    poses = np.tile(np.eye(4), (len(rgb_times), 1, 1))
    ok = idx >= 0
    poses[ok] = c2w[idx[ok]]
    return poses, ok


# ----------------------------------------------------------------------------------------------------------------
# similarity alignment and pose errors


def camera_similarity(
    src_c2w: Float[np.ndarray, "n 4 4"], dst_c2w: Float[np.ndarray, "n 4 4"]
) -> Tuple[float, Float[np.ndarray, "3 3"], Float[np.ndarray, "3"], float]:
    """The similarity ``p_dst = s R p_src + t`` between two estimates of the same cameras (camera-to-world, the same
    camera axes): the rotation from their orientations (the mean relative rotation, projected onto SO(3); the
    centres alone leave the rotation about a straight path undetermined, and a rig drives straight along a row),
    then scale and translation from the centres by least squares; with the RMS distance of the fitted centres."""
    src_c2w, dst_c2w = np.asarray(src_c2w, np.float64), np.asarray(dst_c2w, np.float64)
    rot = common_rotation(src_c2w[:, :3, :3], dst_c2w[:, :3, :3])
    a, b = src_c2w[:, :3, 3], dst_c2w[:, :3, 3]
    a0, b0 = a - a.mean(0), b - b.mean(0)
    scale = float(np.sum(b0 * (a0 @ rot.T)) / max(float(np.sum(a0**2)), 1e-12))
    t = b.mean(0) - scale * rot @ a.mean(0)
    rms = float(np.sqrt(np.mean(np.sum((scale * a @ rot.T + t - b) ** 2, axis=1))))
    return scale, rot, t, rms


def common_rotation(src: Float[np.ndarray, "n 3 3"], dst: Float[np.ndarray, "n 3 3"]) -> Float[np.ndarray, "3 3"]:
    """The one rotation R that best carries the orientations ``src`` onto ``dst`` (R src_i ~ dst_i): the chordal
    mean of dst_i src_i^T, projected onto SO(3)."""
    u, _, vt = np.linalg.svd(np.einsum("nij,nkj->ik", dst, src))
    return u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt


def apply_similarity(
    c2w: Float[np.ndarray, "n 4 4"], scale: float, rot: Float[np.ndarray, "3 3"], t: Float[np.ndarray, "3"]
) -> Float[np.ndarray, "n 4 4"]:
    """Camera-to-world poses moved by the similarity ``p -> scale rot p + t`` (orientations rotated, centres moved)."""
    out = np.array(c2w, np.float64)
    out[:, :3, :3] = rot @ out[:, :3, :3]
    out[:, :3, 3] = scale * out[:, :3, 3] @ rot.T + t
    return out


def umeyama(src: Float[np.ndarray, "n 3"], dst: Float[np.ndarray, "n 3"]) -> Tuple[float, np.ndarray, np.ndarray]:
    """Similarity (s, R, t) minimising sum ||dst - (s R src + t)||^2 (Umeyama 1991)."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / src.shape[0]
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    var_s = (xs**2).sum() / src.shape[0]
    s = float(np.trace(np.diag(D) @ S) / max(var_s, 1e-12))
    t = mu_d - s * R @ mu_s
    return s, R, t


def pose_errors(est_c2w: Float[np.ndarray, "n 4 4"], true_c2w: Float[np.ndarray, "n 4 4"]) -> Dict[str, float]:
    """Errors of estimated camera poses against truth, up to the similarity that SfM cannot observe.

    - translation: Umeyama similarity of the camera centres, then distances (truth units);
    - rotation: the best common rotation of the orientations (chordal mean of R_true R_est^T, which is also
      defined when the path is a straight line, where the centres leave the roll about it free), then the
      angle of each residual (degrees);
    - relative rotation: angle between estimated and true rotations from each frame to the next (no alignment).
    Both sets in the same camera-axis convention.
    """
    s, R, t = umeyama(est_c2w[:, :3, 3], true_c2w[:, :3, 3])
    centres = (s * (R @ est_c2w[:, :3, 3].T)).T + t
    trans_err = np.linalg.norm(centres - true_c2w[:, :3, 3], axis=1)
    R_rot = common_rotation(est_c2w[:, :3, :3], true_c2w[:, :3, :3])
    rot_err = rotation_angles_deg(np.einsum("ij,njk->nik", R_rot, est_c2w[:, :3, :3]), true_c2w[:, :3, :3])
    rel_est = np.einsum("nji,njk->nik", est_c2w[:-1, :3, :3], est_c2w[1:, :3, :3])
    rel_true = np.einsum("nji,njk->nik", true_c2w[:-1, :3, :3], true_c2w[1:, :3, :3])
    rel_err = rotation_angles_deg(rel_est, rel_true) if len(est_c2w) > 1 else np.zeros(1)
    return {
        "rotation_deg_mean": float(rot_err.mean()),
        "rotation_deg_max": float(rot_err.max()),
        "relative_rotation_deg_mean": float(rel_err.mean()),
        "translation_mean": float(trans_err.mean()),
        "translation_max": float(trans_err.max()),
        "scale": s,
    }


def rotation_angles_deg(Ra: Float[np.ndarray, "n 3 3"], Rb: Float[np.ndarray, "n 3 3"]) -> Float[np.ndarray, " n"]:
    """The angle (degrees) between each pair of rotations."""
    rel = np.einsum("nji,njk->nik", Ra, Rb)
    return np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))


# ----------------------------------------------------------------------------------------------------------------
# SfM with pycolmap


@dataclass
class SfmConfig:
    """pycolmap SfM settings tuned for small frames."""

    max_num_features: int = 8192
    """SIFT features per image."""
    peak_threshold: float = 0.002
    """SIFT peak threshold (COLMAP default 0.0067; lower finds more features on small, low-contrast frames)."""
    upscale: int = 2
    """Upsample images by this factor before SfM (intrinsics scaled to match, poses unaffected)."""
    min_num_matches: int = 15
    """Minimum verified matches for an image pair."""
    seed: int = 0
    """Random seed for the mapper."""
    thermal_clahe: bool = True
    """Thermal SfM input only: CLAHE (clip 2, 4x4 tiles) on the rescaled frames for more features (the dataset's
    thermal frames are not changed)."""
    num_threads: int = 1
    """Threads for extraction, matching and mapping; 1 keeps the result deterministic given the seed."""
    matching: Literal["auto", "exhaustive", "sequential"] = "auto"
    """Image pairs to match: every pair (cost grows with the square of the frame count), each frame with its next
    ``sequential_overlap`` frames (linear; for video along a row), or auto: exhaustive up to
    ``exhaustive_max_frames`` frames, sequential above. Loop detection is off: COLMAP's needs a vocabulary tree
    file, which is not shipped."""
    exhaustive_max_frames: int = 80
    """auto: the largest frame count matched exhaustively."""
    sequential_overlap: int = 20
    """sequential: frames each frame is matched with (its successors)."""
    sequential_quadratic_overlap: bool = True
    """sequential: also match with the successors at distance 2^k beyond the overlap (ties longer spans)."""
    mapper: Literal["incremental", "global"] = "incremental"
    """pycolmap's incremental mapper, or its global mapper (GLOMAP: rotation averaging + global positioning)."""
    verbose: bool = False
    """Show COLMAP's log (warnings only otherwise)."""


@dataclass
class SfmResult:
    """Per frame camera-to-world (OpenCV axes; identity where unregistered) and which frames registered."""

    c2w: Float[np.ndarray, "n 4 4"]
    registered: np.ndarray
    source: str

    @property
    def num_registered(self) -> int:
        return int(self.registered.sum())


def write_sfm_images(
    images: List[np.ndarray], masks: Optional[List[np.ndarray]], work_dir: Path, upscale: int
) -> Tuple[Path, Optional[Path], List[str]]:
    """``images`` (RGB or grey uint8) as PNGs for COLMAP, upscaled by ``upscale``, and their ``masks`` (COLMAP's
    ``<image name>.png``): the image folder, the mask folder (None without masks) and the image names in order."""
    import cv2

    img_dir = work_dir / "images"
    img_dir.mkdir(exist_ok=True)
    mask_dir = work_dir / "masks"
    names = []
    for i, img in enumerate(images):
        name = f"{i:06d}.png"
        big = img
        if upscale > 1:
            big = cv2.resize(img, None, fx=upscale, fy=upscale, interpolation=cv2.INTER_CUBIC)
        if big.ndim == 3:
            big = cv2.cvtColor(big, cv2.COLOR_RGB2BGR)
        cv2.imwrite(str(img_dir / name), big)
        if masks is not None:
            mask_dir.mkdir(exist_ok=True)
            m = cv2.resize(masks[i], None, fx=upscale, fy=upscale, interpolation=cv2.INTER_NEAREST)
            cv2.imwrite(str(mask_dir / f"{name}.png"), m)
        names.append(name)
    return img_dir, (mask_dir if masks is not None else None), names


def extract_and_match(
    db_path: Path,
    img_dir: Path,
    mask_dir: Optional[Path],
    K: Float[np.ndarray, "3 3"],
    config: SfmConfig,
    num_frames: int,
) -> None:
    """SIFT features of every image in ``img_dir`` (one shared pinhole camera, ``K`` scaled by ``config.upscale``)
    and their verified matches, into a new COLMAP database at ``db_path``."""
    import pycolmap

    s = config.upscale
    # COLMAP puts the centre of the top-left pixel at (0.5, 0.5); OpenCV and Kalibr at (0, 0)
    fx, fy, cx, cy = K[0, 0] * s, K[1, 1] * s, (K[0, 2] + 0.5) * s, (K[1, 2] + 0.5) * s
    if db_path.exists():
        db_path.unlink()
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    reader.camera_params = f"{fx},{fy},{cx},{cy}"
    if mask_dir is not None:
        reader.mask_path = str(mask_dir)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.sift.max_num_features = config.max_num_features
    extraction.sift.peak_threshold = config.peak_threshold
    extraction.use_gpu = False
    extraction.num_threads = config.num_threads
    pycolmap.extract_features(
        db_path, img_dir, camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader, extraction_options=extraction
    )
    matching = pycolmap.FeatureMatchingOptions()
    matching.use_gpu = False
    matching.num_threads = config.num_threads
    verification = pycolmap.TwoViewGeometryOptions()
    verification.min_num_inliers = config.min_num_matches
    if sfm_matching(config, num_frames) == "exhaustive":
        # every pair (on short thermal sequences sequential pairing registered far fewer frames in trials here)
        pycolmap.match_exhaustive(db_path, matching_options=matching, verification_options=verification)
    else:
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = config.sequential_overlap
        pairing.quadratic_overlap = config.sequential_quadratic_overlap
        pairing.loop_detection = False
        pycolmap.match_sequential(
            db_path, matching_options=matching, pairing_options=pairing, verification_options=verification
        )


def map_reconstructions(db_path: Path, img_dir: Path, sparse_dir: Path, config: SfmConfig) -> Dict[int, Any]:
    """The reconstructions (id -> pycolmap.Reconstruction) of ``config.mapper`` from the matches in ``db_path``;
    the intrinsics stay fixed."""
    import pycolmap

    sparse_dir.mkdir(exist_ok=True)
    if config.mapper == "global":
        gopts = pycolmap.GlobalPipelineOptions()
        gopts.min_num_matches = config.min_num_matches
        gopts.num_threads = gopts.mapper.num_threads = config.num_threads
        gopts.random_seed = gopts.mapper.random_seed = config.seed
        ba = gopts.mapper.bundle_adjustment
        ba.refine_focal_length = ba.refine_principal_point = ba.refine_extra_params = False
        ba.ceres.use_gpu = False
        return pycolmap.global_mapping(db_path, img_dir, sparse_dir, options=gopts)
    pipeline = pycolmap.IncrementalPipelineOptions()
    pipeline.min_num_matches = config.min_num_matches
    pipeline.ba_refine_focal_length = False
    pipeline.ba_refine_principal_point = False
    pipeline.ba_refine_extra_params = False
    pipeline.num_threads = config.num_threads
    pipeline.random_seed = config.seed
    return pycolmap.incremental_mapping(db_path, img_dir, sparse_dir, options=pipeline)


def largest_reconstruction_poses(recs: Dict[int, Any], names: List[str], source: str) -> SfmResult:
    """Camera-to-world of the frames ``names`` registered in the reconstruction with the most registered images."""
    n = len(names)
    c2w = np.tile(np.eye(4), (n, 1, 1))
    registered = np.zeros(n, dtype=bool)
    if not recs:
        return SfmResult(c2w, registered, source)
    rec = max(recs.values(), key=lambda r: r.num_reg_images())
    for image in rec.images.values():
        if not _is_registered(image):
            continue
        i = names.index(image.name)
        w2c = np.eye(4)
        w2c[:3, :4] = _cam_from_world_matrix(image)
        c2w[i] = np.linalg.inv(w2c)
        registered[i] = True
    return SfmResult(c2w, registered, source)


def run_sfm(
    images: List[np.ndarray],
    K: Float[np.ndarray, "3 3"],
    work_dir: Path,
    config: SfmConfig,
    source: str,
    masks: Optional[List[np.ndarray]] = None,
) -> SfmResult:
    """Feature extraction, matching and incremental mapping with pycolmap on ``images`` (uint8, one shared
    pinhole camera with known, fixed intrinsics K). The largest reconstruction is kept."""
    import pycolmap

    pycolmap.logging.minloglevel = 1 if config.verbose else 2  # glog: 0 INFO, 1 WARNING, 2 ERROR
    work_dir.mkdir(parents=True, exist_ok=True)
    img_dir, mask_dir, names = write_sfm_images(images, masks, work_dir, config.upscale)
    db_path = work_dir / "database.db"
    extract_and_match(db_path, img_dir, mask_dir, K, config, len(images))
    recs = map_reconstructions(db_path, img_dir, work_dir / "sparse", config)
    return largest_reconstruction_poses(recs, names, source)


def sfm_matching(config: SfmConfig, num_frames: int) -> str:
    """The pairing ``config`` gives for ``num_frames`` frames: exhaustive or sequential."""
    if config.matching != "auto":
        return config.matching
    return "exhaustive" if num_frames <= config.exhaustive_max_frames else "sequential"


def _is_registered(image) -> bool:
    val = getattr(image, "has_pose", None)
    if val is None:
        val = getattr(image, "registered", True)
    return bool(val() if callable(val) else val)


def _cam_from_world_matrix(image) -> np.ndarray:
    cfw = image.cam_from_world
    cfw = cfw() if callable(cfw) else cfw
    return np.asarray(cfw.matrix())
