"""Generate a raw tri-modal capture folder (docs/formats.md) with its truth from a :class:`SynthConfig`."""

from __future__ import annotations

import dataclasses
import math
from contextlib import nullcontext
from pathlib import Path
from typing import Dict, List, Optional, Tuple, Union

import numpy as np
from jaxtyping import Float, Int

from agrinerf_ns.images import write_png
from agrinerf_ns.progress import WorkProgress, work_progress
from agrinerf_ns.synth import writer as W
from agrinerf_ns.synth.camera_rig import T0, THERMAL_DELAY, Rig, build_rig, frame_times, heldout_poses, odometry
from agrinerf_ns.synth.config import MAX_SUBFRAMES, SynthConfig, check_output_dir
from agrinerf_ns.synth.motion_blur import blur_lengths_px, exposure_average, subframe_count
from agrinerf_ns.synth.raycast import Hits, PinholeRadtan, cast
from agrinerf_ns.synth.scene import (
    LIGHTING_PRESETS,
    Lighting,
    Scene,
    build_scene,
    fruit_ids,
    radiance,
    rec709_luminance,
    temperature,
)
from agrinerf_ns.synth.sensors import (
    RADIOMETRIC_CALIBRATION,
    EventSimulator,
    ThermalSensor,
    clean_rgb,
    exposure_gains,
    noisy_rgb,
)

THERMAL_SUPERSAMPLE = 2
EVENT_EPS = 1e-6
"""Offset of the event camera's log intensity, in the radiance units of the bright preset (mean ~0.1-0.3)."""
BOX = Tuple[int, int, int, int, int, int]


def make_scene(config: SynthConfig) -> Tuple[Scene, Rig]:
    """The scene and rig of ``config`` (the scene covers the whole path with margin)."""
    rig = build_rig(config)
    length = config.speed * (config.views - 1) / config.fps
    return build_scene(config.scene, config.seed, rig.start_x - 9.0, rig.start_x + length + 9.0), rig


def render_radiance(
    scene: Scene, cam: PinholeRadtan, T_wc: np.ndarray, light: Lighting, supersample: int = 1
) -> Tuple[Float[np.ndarray, "h w 3"], Hits]:
    """Linear radiance image (box-filtered from ``supersample``^2 rays per pixel) and the hits of the dense render."""
    c = cam.scaled(supersample) if supersample > 1 else cam
    hits = cast(scene.prims, c, T_wc)
    rad = radiance(scene, hits, light).reshape(c.height, c.width, 3)
    if supersample > 1:
        s = supersample
        rad = rad.reshape(cam.height, s, cam.width, s, 3).mean(axis=(1, 3))
    return rad, hits


def truth_temperature(scene: Scene, hits: Hits, cam: PinholeRadtan, supersample: int) -> Float[np.ndarray, "h w"]:
    """Surface temperature (degrees C, float32) per pixel of ``cam``, the mean over the ``supersample``^2 rays of
    ``hits`` (a render of ``cam.scaled(supersample)``): the sharp scene, no optics blur, no sensor."""
    s = supersample
    temp = temperature(scene, hits).reshape(cam.height, s, cam.width, s).mean(axis=(1, 3))
    return temp.astype(np.float32)


def fruit_boxes(ids: Int[np.ndarray, "h w"], min_pixels: int) -> List[BOX]:
    """(fruit, x0, y0, x1, y1, visible pixels) of every fruit with at least ``min_pixels`` visible pixels."""
    h, w = ids.shape
    flat = ids.ravel()
    sel = np.nonzero(flat >= 0)[0]
    if sel.size == 0:
        return []
    uniq, inv, counts = np.unique(flat[sel], return_inverse=True, return_counts=True)
    xs, ys = sel % w, sel // w
    x0 = np.full(uniq.size, w)
    y0 = np.full(uniq.size, h)
    x1 = np.full(uniq.size, -1)
    y1 = np.full(uniq.size, -1)
    np.minimum.at(x0, inv, xs)
    np.minimum.at(y0, inv, ys)
    np.maximum.at(x1, inv, xs)
    np.maximum.at(y1, inv, ys)
    return [
        (int(f), int(a), int(b), int(c), int(d), int(n))
        for f, a, b, c, d, n in zip(uniq, x0, y0, x1, y1, counts, strict=True)
        if n >= min_pixels
    ]


def event_substeps(config: SynthConfig, scene: Scene, rig: Rig) -> Tuple[int, float]:
    """Event-camera renders per frame interval, and the image motion (pixels, 95th percentile over the event pixels)
    between two of them. ``config.event_substeps`` when fixed; else the fewest that keep that motion at most
    ``config.event_step_px``, measured over the first frame interval (the rig's speed is constant)."""
    cam = rig.cams["event"]
    T_a, T_b = rig.pose(T0, "event"), rig.pose(T0 + 1.0 / config.fps, "event")
    motion = float(np.percentile(blur_lengths_px(cam, cast(scene.prims, cam, T_a), T_a, T_b), 95))
    n = config.event_substeps or max(1, math.ceil(motion / config.event_step_px - 1e-9))
    return int(n), motion / n


def event_times(config: SynthConfig, substeps: Optional[int] = None) -> Float[np.ndarray, " n"]:
    """Sample times of the event camera, ``substeps`` per frame interval (default ``config.event_substeps``): the
    path from half a frame before the first frame to half after the last."""
    k = substeps or config.event_substeps
    if not k:
        raise ValueError("event_times: pass substeps when config.event_substeps is None (see event_substeps())")
    n = config.views * k
    return T0 - 0.5 / config.fps + np.arange(n + 1) / (config.fps * k)


def event_luminance(config: SynthConfig, scene: Scene, rig: Rig, light: Lighting, t: float) -> Float[np.ndarray, " n"]:
    """Linear luminance at every event pixel (row-major) at time ``t``: the mean of its ``event_supersample``^2 rays,
    as a real pixel integrates the light over its area. What the simulated event pixels respond to."""
    rad, _ = render_radiance(scene, rig.cams["event"], rig.pose(t, "event"), light, config.event_supersample)
    return rec709_luminance(rad.reshape(-1, 3))


def event_log_luminance(
    config: SynthConfig, scene: Scene, rig: Rig, light: Lighting, t: float
) -> Float[np.ndarray, " n"]:
    """The truth log intensity of every event pixel at time ``t`` (the simulator's ``log(Y + EVENT_EPS)``)."""
    return np.log(event_luminance(config, scene, rig, light, t) + EVENT_EPS)


def simulate_events(
    config: SynthConfig, scene: Scene, rig: Rig, light: Lighting, substeps: int, progress: Optional[WorkProgress] = None
) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Events (x, y, t_us, p) of the event camera along the continuous path, rendered ``substeps`` times per frame
    interval."""
    cam = rig.cams["event"]
    rng = np.random.default_rng([config.seed, 47])
    sim = EventSimulator(
        cam.width,
        cam.height,
        config.event_threshold,
        config.event_threshold_sigma,
        config.event_refractory_us,
        EVENT_EPS,
        rng,
    )
    times = event_times(config, substeps)
    for k, t in enumerate(times):
        lum = event_luminance(config, scene, rig, light, float(t))
        if k == 0:
            sim.reset(lum, float(t))
        else:
            sim.step(lum, float(t))
        if progress is not None:
            progress.advance()
    noise_hz = config.event_noise_hz * light.event_noise_scale
    return sim.finish(float(times[0]), float(times[-1]), noise_hz, rng)


def blur_summary(enabled: bool, exposure_s: float, subframes: List[int], blur_px: List[np.ndarray]) -> dict:
    """truth/scene.json's record of the RGB motion blur: exposure, sub-frames per frame, blur streak lengths (px)."""
    allpx = np.concatenate(blur_px) if blur_px else np.zeros(1)
    return {
        "enabled": bool(enabled),
        "exposure_s": round(float(exposure_s), 9),
        "subframes": [int(k) for k in subframes],
        "blur_px_median": round(float(np.median(allpx)), 4),
        "blur_px_p95": round(float(np.percentile(allpx, 95)), 4),
        "blur_px_p95_per_frame": [round(float(np.percentile(b, 95)), 4) for b in blur_px],
        "blur_px": "per pixel, image motion of the point seen there between exposure start and end poses",
    }


CAPTURE_DIRS = (
    "rgb",
    "thermal",
    "events",
    "truth/rgb_clean",
    "truth/depth",
    "truth/boxes_yolo",
    "truth/fruit_ids",
    "truth/temperature",
    "truth/heldout/boxes_yolo",
    "truth/heldout/temperature",
)
"""The folders of a raw capture and its truth, relative to the capture folder."""


@dataclasses.dataclass
class CaptureSetup:
    """What every frame of one capture shares: the scene, rig and lighting, the RGB exposure and gains, and the
    sensors' noise streams (each drawn in frame order, so a capture is reproducible from ``config.seed``)."""

    config: SynthConfig
    scene: Scene
    rig: Rig
    light: Lighting
    times: Float[np.ndarray, " n"]
    gain: float
    """Gain of the camera frames: auto-exposed on the first frame, capped (dark stays dark)."""
    truth_gain: float
    """Gain of the truth frames: auto-exposed as if the scene were lit by the bright preset."""
    exposure: float
    rng_rgb: np.random.Generator
    rng_th: np.random.Generator
    thermal: ThermalSensor
    ev_substeps: int
    ev_step_px: float


@dataclasses.dataclass
class PathRecord:
    """What the frames along the path leave for the files written after them."""

    poses: List[np.ndarray] = dataclasses.field(default_factory=list)
    boxes: List[List[BOX]] = dataclasses.field(default_factory=list)
    subframes: List[int] = dataclasses.field(default_factory=list)
    blur_px: List[np.ndarray] = dataclasses.field(default_factory=list)


def capture_setup(config: SynthConfig) -> CaptureSetup:
    """The scene, rig, exposure gains, sensors and event sampling of ``config`` (validated)."""
    scene, rig = make_scene(config)
    light = LIGHTING_PRESETS[config.lighting]
    times = frame_times(config)
    cam_rgb, cam_th = rig.cams["rgb"], rig.cams["thermal"]
    s = config.rgb_supersample

    # exposure from the first frame: the truth is auto-exposed, the camera is capped (dark stays dark)
    rad0, _ = render_radiance(scene, cam_rgb, rig.pose(float(times[0])), light, s)
    rad0_bright, _ = render_radiance(scene, cam_rgb, rig.pose(float(times[0])), LIGHTING_PRESETS["bright"], s)
    gain, truth_gain = exposure_gains(
        float(rec709_luminance(rad0.reshape(-1, 3)).mean()), float(rec709_luminance(rad0_bright.reshape(-1, 3)).mean())
    )
    ev_substeps, ev_step_px = event_substeps(config, scene, rig)
    return CaptureSetup(
        config=config,
        scene=scene,
        rig=rig,
        light=light,
        times=times,
        gain=gain,
        truth_gain=truth_gain,
        exposure=config.rgb_exposure_s(light.exposure_s),
        rng_rgb=np.random.default_rng([config.seed, 41]),
        rng_th=np.random.default_rng([config.seed, 43]),
        thermal=ThermalSensor.create(cam_th.width, cam_th.height, np.random.default_rng([config.seed, 44])),
        ev_substeps=ev_substeps,
        ev_step_px=ev_step_px,
    )


def write_rgb_frame(setup: CaptureSetup, dirs: Dict[str, Path], name: str, t: float, record: PathRecord) -> None:
    """The RGB camera frame at ``t`` (blurred over its exposure, noisy) and its truth: sharp frame, depth, surface
    temperature, fruit ids and boxes; its pose, boxes, sub-frames and blur streaks go to ``record``."""
    config, scene, rig, light = setup.config, setup.scene, setup.rig, setup.light
    cam_rgb = rig.cams["rgb"]
    H, Wd = cam_rgb.height, cam_rgb.width
    s, exposure = config.rgb_supersample, setup.exposure
    T = rig.pose(t)
    record.poses.append(T)
    rad, hits = render_radiance(scene, cam_rgb, T, light, s)
    np.save(dirs["truth/temperature"] / name.replace(".png", ".npy"), truth_temperature(scene, hits, cam_rgb, s))
    if s > 1:
        hits = cast(scene.prims, cam_rgb, T)
    # the camera frame integrates the moving scene over its exposure; the truth stays the sharp frame at t
    t_a, t_b = t - exposure / 2, t + exposure / 2
    streak = blur_lengths_px(cam_rgb, hits, rig.pose(t_a), rig.pose(t_b))
    record.blur_px.append(streak)
    p95 = float(np.percentile(streak, 95))
    k = config.blur_subframes or subframe_count(p95, config.blur_step_px, MAX_SUBFRAMES)
    record.subframes.append(k if exposure > 0 else 1)
    rad_cam = exposure_average(lambda tj: render_radiance(scene, cam_rgb, rig.pose(tj), light, s)[0],
                               rad, t, exposure, record.subframes[-1])  # fmt: skip
    write_png(dirs["rgb"] / name, noisy_rgb(rad_cam, setup.gain, setup.rng_rgb))
    write_png(dirs["truth/rgb_clean"] / name, clean_rgb(rad, setup.truth_gain))
    np.save(dirs["truth/depth"] / name.replace(".png", ".npy"), hits.zdepth.reshape(H, Wd).astype(np.float32))
    ids = fruit_ids(scene, hits).reshape(H, Wd)
    write_png(dirs["truth/fruit_ids"] / name, (ids + 1).astype(np.uint16))
    boxes = fruit_boxes(ids, config.min_box_pixels)
    record.boxes.append(boxes)
    (dirs["truth/boxes_yolo"] / name.replace(".png", ".txt")).write_text(W.yolo_lines(boxes, Wd, H))


def write_thermal_frame(setup: CaptureSetup, dirs: Dict[str, Path], name: str, t: float) -> None:
    """The thermal frame triggered with the RGB frame at ``t``: its own pose, supersampled temperatures -> counts."""
    cam_th = setup.rig.cams["thermal"]
    T_th = setup.rig.pose(t + THERMAL_DELAY, "thermal")
    hth = cast(setup.scene.prims, cam_th.scaled(THERMAL_SUPERSAMPLE), T_th)
    temp = temperature(setup.scene, hth).reshape(cam_th.height * THERMAL_SUPERSAMPLE, -1)
    write_png(dirs["thermal"] / name, setup.thermal.counts(temp, THERMAL_SUPERSAMPLE, setup.rng_th))


def write_path_frames(
    setup: CaptureSetup, dirs: Dict[str, Path], tmp: Path, prog: Optional[WorkProgress]
) -> PathRecord:
    """Every RGB and thermal frame along the path with its truth, their timestamps, the poses and the odometry."""
    config, times = setup.config, setup.times
    cam_rgb = setup.rig.cams["rgb"]
    names = [W.frame_name(i) for i in range(config.views)]
    record = PathRecord()
    for i, t in enumerate(times):
        write_rgb_frame(setup, dirs, names[i], float(t), record)
        if prog is not None:
            prog.advance()
        write_thermal_frame(setup, dirs, names[i], float(t))
        if prog is not None:
            prog.advance()

    exposure = setup.exposure
    W.write_timestamps(dirs["rgb"] / "timestamps.txt", names, times)
    W.write_exposures(dirs["rgb"] / "exposures.txt", names, times - exposure / 2, times + exposure / 2)
    W.write_timestamps(dirs["thermal"] / "timestamps.txt", names, times + THERMAL_DELAY)
    W.write_tum(tmp / "truth" / "poses.txt", times, record.poses)
    W.write_tum(tmp / "odometry.txt", times, odometry(record.poses, config.seed))
    W.write_json(tmp / "truth" / "boxes_coco.json", W.coco(record.boxes, names, cam_rgb.width, cam_rgb.height))
    return record


def write_heldout_views(setup: CaptureSetup, dirs: Dict[str, Path], tmp: Path, prog: Optional[WorkProgress]) -> None:
    """The held-out truth views off the path: sharp frame, surface temperature, fruit boxes, poses."""
    config, scene, light = setup.config, setup.scene, setup.light
    cam_rgb = setup.rig.cams["rgb"]
    H, Wd = cam_rgb.height, cam_rgb.width
    s = config.rgb_supersample
    ho_times, ho_poses, ho_boxes = [], [], []
    ho_names = [W.frame_name(k) for k in range(config.num_heldout)]
    for k, (t, T) in enumerate(heldout_poses(setup.rig, config)):
        rad, hits = render_radiance(scene, cam_rgb, T, light, s)
        np.save(
            dirs["truth/heldout/temperature"] / ho_names[k].replace(".png", ".npy"),
            truth_temperature(scene, hits, cam_rgb, s),
        )
        if s > 1:
            hits = cast(scene.prims, cam_rgb, T)
        write_png(tmp / "truth" / "heldout" / ho_names[k], clean_rgb(rad, setup.truth_gain))
        boxes = fruit_boxes(fruit_ids(scene, hits).reshape(H, Wd), config.min_box_pixels)
        ho_boxes.append(boxes)
        (dirs["truth/heldout/boxes_yolo"] / ho_names[k].replace(".png", ".txt")).write_text(W.yolo_lines(boxes, Wd, H))
        ho_times.append(t)
        ho_poses.append(T)
        if prog is not None:
            prog.advance()
    W.write_tum(tmp / "truth" / "heldout" / "poses.txt", ho_times, ho_poses)
    W.write_json(tmp / "truth" / "heldout" / "boxes_coco.json", W.coco(ho_boxes, ho_names, Wd, H))


def scene_record(setup: CaptureSetup, path: PathRecord, num_events: int) -> dict:
    """truth/scene.json: the config, the scene's temperatures, the sensors' calibration and sampling."""
    config = setup.config
    return {
        "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(config).items()},
        "temperatures_c": {k: round(v, 4) for k, v in setup.scene.temps.items()},
        "thermal_counts": {
            "offset_at_0c": RADIOMETRIC_CALIBRATION["counts_at_0c"],
            "per_kelvin": RADIOMETRIC_CALIBRATION["counts_per_kelvin"],
        },
        "rgb_gain": setup.gain,
        "truth_gain": setup.truth_gain,
        "num_events": num_events,
        "event_sampling": {"substeps_per_frame": setup.ev_substeps, "step_px_p95": round(setup.ev_step_px, 4)},
        "rgb_motion_blur": blur_summary(config.motion_blur, setup.exposure, path.subframes, path.blur_px),
        "pixel_convention": "OpenCV: the centre of pixel column i is at u = i",
        "world": "x along the row, y across it away from the rig, z up; metres",
    }


def generate_capture(config: SynthConfig, out: Union[str, Path], progress: bool = False) -> Path:
    """Write the raw capture of ``config`` to ``out`` (absent or empty) atomically; returns ``out``.

    Raises :class:`~agrinerf_ns.synth.config.SynthConfigError` for invalid arguments, before writing anything.
    """
    config.validate()
    out = Path(out)
    check_output_dir(out)
    setup = capture_setup(config)
    n_steps = 2 * config.views + config.num_heldout + len(event_times(config, setup.ev_substeps))

    label = f"synth {config.scene}/{config.lighting} ({config.views} frames, then events)"
    ctx = work_progress(label, n_steps) if progress else nullcontext()
    with ctx as prog, W.atomic_folder(out) as tmp:
        dirs = {d: tmp / d for d in CAPTURE_DIRS}
        for d in dirs.values():
            d.mkdir(parents=True, exist_ok=True)
        path = write_path_frames(setup, dirs, tmp, prog)
        write_heldout_views(setup, dirs, tmp, prog)

        ex, ey, et, ep = simulate_events(config, setup.scene, setup.rig, setup.light, setup.ev_substeps, prog)
        ecam = setup.rig.cams["event"]
        W.write_events(dirs["events"] / "events.h5", ex, ey, et, ep, ecam.width, ecam.height)

        W.write_yaml(tmp / "calib.yaml", W.camchain(setup.rig.cams, setup.rig.T_c_c0, RADIOMETRIC_CALIBRATION))
        W.write_json(tmp / "truth" / "fruits.json", setup.scene.fruits)
        W.write_json(tmp / "truth" / "scene.json", scene_record(setup, path, int(et.size)))
    return out
