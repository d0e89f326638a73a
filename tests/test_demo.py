"""`agrinerf-demo` at a tiny size, run as a user runs it: its contact sheet (size and panels, by layout), its labelled
numbers, and the printed viewer and video commands (both run). Plus the sheet's optional columns on given arrays."""

from __future__ import annotations

import csv
import json
import math
import os
import re
import shlex
import subprocess
import sys
import time
import urllib.request
from pathlib import Path
from typing import Dict, List

import numpy as np
import pytest
from PIL import Image

from agrinerf_ns.contact_sheet import SheetLayout, write_contact_sheet
from agrinerf_ns.demo import THERMAL_SCALE, HeldOutView, sheet_columns

WIDTH, HEIGHT = 64, 48
RGB_COLUMNS = (
    "captured RGB",
    "the same frame x",
    "AgriNeRF RGB render, exposure-aligned to the clean truth",
    "clean truth",
    "thermal frame",
)
FINITE = ("psnr_clean", "ssim_clean", "psnr", "ssim", "thermal_psnr", "thermal_ssim")


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> Dict:
    """The demo on its dark scene (the default is dusk: the same code), 13 views of 64x48 (two held-out views), 20
    training steps, a video of 10 frames."""
    root = tmp_path_factory.mktemp("demo")
    out = root / "demo"
    command = [
        str(Path(sys.executable).parent / "agrinerf-demo"), "--out", str(out), "--lighting", "dark", "--views", "13",
        "--width", str(WIDTH), "--steps", "20", "--sheet-views", "2", "--video-steps", "1",
    ]  # fmt: skip
    env = {**os.environ, "COLUMNS": "200"}
    blocked = _network_blocked(env, root / "network.log", root / "torch_home")  # a fresh machine, offline
    done = subprocess.run(
        command, check=False, cwd=root, env=blocked, capture_output=True, text=True, timeout=900,
        stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert done.returncode == 0, (done.stdout + done.stderr)[-4000:]
    summary = json.loads((out / "summary.json").read_text())
    return dict(out=out, root=root, env=env, stdout=done.stdout, stderr=done.stderr, summary=summary)


def _network_blocked(env: Dict[str, str], log: Path, torch_home: Path) -> Dict[str, str]:
    """``env`` with the network blocked (``helpers/no_network``: each attempt refused and written to ``log``) and an
    empty torch cache (no weights downloaded before)."""
    torch_home.mkdir(parents=True, exist_ok=True)
    guard = str(Path(__file__).parent / "helpers" / "no_network")
    path = os.pathsep.join(p for p in (guard, env.get("PYTHONPATH", "")) if p)
    return {**env, "PYTHONPATH": path, "AGRINERF_NETWORK_LOG": str(log), "TORCH_HOME": str(torch_home)}


@pytest.mark.slow
def test_the_demo_tries_no_network(demo: Dict, tmp_path: Path) -> None:
    """Run with the network blocked and an empty torch cache, the demo tried no host and printed no download; the
    same guard sees a download a process tries (so an empty log means no attempt)."""
    log = demo["root"] / "network.log"
    assert not log.exists(), log.read_text()
    assert "Downloading" not in demo["stdout"] + demo["stderr"]
    planted = _network_blocked(dict(os.environ), tmp_path / "planted.log", tmp_path / "torch_home")
    fetch = (
        "import urllib.request as u\ntry: u.urlopen('https://download.pytorch.org/', timeout=5)\nexcept OSError: pass"
    )
    subprocess.run([sys.executable, "-c", fetch], env=planted, check=True, timeout=120, stdin=subprocess.DEVNULL)
    assert "getaddrinfo 'download.pytorch.org'" in (tmp_path / "planted.log").read_text()


@pytest.mark.slow
def test_contact_sheet_size_and_panels(demo: Dict) -> None:
    sheet = Path(demo["summary"]["contact_sheet"])
    assert sheet == demo["out"] / "contact_sheet.png" and f"(the sheet alone: {sheet})" in demo["stdout"]
    layout = SheetLayout.load(sheet.with_suffix(".json"))
    with Image.open(sheet) as image:
        assert image.size == (layout.width, layout.height)
    for prefix, title in zip(RGB_COLUMNS, layout.columns, strict=False):
        assert title.startswith(prefix), (prefix, title)
    assert "for display only" in layout.columns[1]
    assert any(c.startswith("AgriNeRF cross-spectral `thermal` output") for c in layout.columns)
    assert layout.columns[-1] == "AgriNeRF temperature (degrees C)"  # the synthetic capture is radiometric
    held_out = json.loads((demo["out"] / "orchard" / "transforms.json").read_text())["test_filenames"]
    assert layout.views == [Path(name).name for name in held_out] and len(layout.views) == 2

    boxes = {(p.column, p.view): p.box for p in layout.panels}
    assert set(boxes) == {(c, v) for c in layout.columns for v in layout.views}
    for x0, y0, x1, y1 in boxes.values():
        assert 0 <= x0 < x1 <= layout.width and 0 <= y0 < y1 <= layout.height
        assert x1 - x0 >= 240, "tiles are upscaled to a readable size"
        assert abs((x1 - x0) * HEIGHT - (y1 - y0) * WIDTH) <= 2 * WIDTH, "tiles keep the view's aspect"
    for column in layout.columns:  # rows top to bottom, one column's tiles aligned
        top, bottom = (boxes[(column, v)] for v in layout.views)
        assert top[3] <= bottom[1] and top[0] == bottom[0]
    for view in layout.views:  # columns left to right, no overlap
        row = [boxes[(c, view)] for c in layout.columns]
        assert all(a[2] <= b[0] for a, b in zip(row, row[1:], strict=False))

    # one bar under the adjacent thermal columns, one under the temperature column
    assert list(layout.scales) == [THERMAL_SCALE.label, "temperature, degrees C"]
    bar = layout.scales[THERMAL_SCALE.label]
    thermal = [c for c in layout.columns if c.startswith(("thermal frame", "AgriNeRF thermal", "AgriNeRF cross"))]
    assert thermal == layout.columns[4:-1]
    assert bar[1] >= max(b[3] for b in boxes.values())
    assert abs(bar[0] - boxes[(thermal[0], layout.views[0])][0]) <= 1
    assert abs(bar[2] - boxes[(thermal[-1], layout.views[0])][2]) <= 1


@pytest.mark.slow
def test_labelled_numbers(demo: Dict) -> None:
    metrics = {m["key"]: m for m in demo["summary"]["metrics"]}
    for key in FINITE:
        assert metrics[key]["value"] is not None and math.isfinite(metrics[key]["value"]), metrics[key]
    assert metrics["psnr_clean"]["compares"].startswith("RGB render vs clean truth, exposure-aligned")
    assert metrics["psnr"]["compares"].startswith("RGB render vs captured held-out frames")
    assert metrics["thermal_psnr"]["compares"].startswith("cross-spectral `thermal` output vs rescaled thermal frames")
    lpips = metrics["lpips"]
    if lpips["value"] is None:
        assert lpips["note"].startswith("unavailable: ") and "alexnet" in lpips["note"].lower()
        assert "unavailable: " in demo["stdout"]
    else:
        assert math.isfinite(lpips["value"])
    stdout = demo["stdout"]
    assert not re.search(r"\bnan\b", stdout, re.IGNORECASE), "no metric is shown as nan"
    for text in ("vs clean truth, exposure-aligned", "vs captured held-out frames", "rescaled thermal frames"):
        assert text in stdout, text
    stages = demo["summary"]["stage_seconds"]
    assert list(stages) == [
        "agrinerf-synth", "agrinerf-process", "ns-train agrinerf-lite", "evaluation (held-out views)",
        "agrinerf-count", "contact sheet (render + draw)", "total",
    ]  # fmt: skip
    assert all(s is not None and s > 0 for s in stages.values()), stages
    assert stages["total"] >= sum(s for k, s in stages.items() if k != "total")
    assert "wall time per stage" in stdout


@pytest.mark.slow
def test_counts_the_fruit_and_draws_the_fruit_map_beside_the_twin(demo: Dict) -> None:
    """The fruit head is trained from the built-in maker's masks, agrinerf-count counts and scores the run, and the
    picture puts the contact sheet beside the count's fruit map, captioned with the count and its score."""
    count, out = demo["summary"]["count"], demo["out"]
    dataset = json.loads((out / "orchard" / "transforms.json").read_text())
    assert dataset["agrinerf"]["fruit_masks"], "the dataset has the maker's fruit masks"
    report = json.loads((out / "count" / "count.json").read_text())
    assert count["counted"] == report["fruit"] and count["visible"] == report["score"]["visible"] > 0
    assert 0.0 <= count["f1"] <= 1.0 and count["temperature_c"] is None or len(count["temperature_c"]) == 3
    assert f"agrinerf-count found {count['counted']} fruit" in demo["stdout"]
    assert "agrinerf-count --config" in _printed_command(demo["stdout"], "count the fruit of your own run")
    with Image.open(demo["summary"]["picture"]) as picture, Image.open(out / "contact_sheet.png") as sheet:
        with Image.open(out / "count" / "fruit_map.png") as fruit_map:
            assert picture.width > sheet.width and picture.width > fruit_map.width
            assert picture.height >= max(sheet.height, fruit_map.height)
    config = demo["summary"]["config"]
    assert "fruit_loss" in (Path(config).parent / "config.yml").read_text(), "the run trained the fruit head"


def colder_than_the_scene(out: Path) -> List[float]:
    """The demo's counted fruit temperatures (``count/fruits.csv``) colder than every leaf and fruit of its scene: below
    the truth's coldest fruit and below its leaves' temperature less 2 C (a leaf cluster's offset has sd 0.4 C, its
    texture +-0.4 C)."""
    truth = out / "raw" / "truth"
    leaf = json.loads((truth / "scene.json").read_text())["temperatures_c"]["leaf"]
    fruit = [float(f["temperature_c"]) for f in json.loads((truth / "fruits.json").read_text())]
    coldest = min(*fruit, leaf - 2.0)
    assert json.loads((out / "count" / "count.json").read_text())["path"] == "bodies", "the dark count ran"
    with open(out / "count" / "fruits.csv", newline="") as handle:
        counted = [float(row["temperature_c"]) for row in csv.DictReader(handle) if row["temperature_c"]]
    return [t for t in counted if t < coldest]


@pytest.mark.slow
def test_no_counted_fruit_is_colder_than_every_leaf_and_fruit(demo: Dict) -> None:
    """Issue #61's acceptance on the dark demo's count: a counted fruit is a fruit, not the sky or a void, so none is
    colder than every leaf and fruit the scene holds (before the bodies rule refused discs holding sky-cold pixels,
    this demo counted gaps of sky at the canopy's top edge at 11.7 and 13.3 C; at this size it now counts none, and
    ``test_thermal_bodies.py::test_a_blurred_gap_of_sky_is_no_fruit`` holds the rule where fruit do show)."""
    assert colder_than_the_scene(demo["out"]) == []


def _printed_command(stdout: str, header: str) -> str:
    lines = stdout.splitlines()
    index = next(i for i, line in enumerate(lines) if line.startswith(header))
    return lines[index + 1].strip()


@pytest.mark.slow
def test_printed_commands_open_the_viewer_and_render_a_video(demo: Dict) -> None:
    config = demo["summary"]["config"]
    viewer = _printed_command(demo["stdout"], "open this run in the viewer")
    video = _printed_command(demo["stdout"], "render a video of it")
    assert demo["summary"]["commands"] == {"viewer": viewer, "video": video}
    assert shlex.split(viewer)[0].endswith("ns-viewer") and shlex.split(video)[:2][1] == "interpolate"
    assert f"--load-config {config}" in viewer and f"--load-config {config}" in video

    subprocess.run(shlex.split(video), cwd=demo["root"], env=demo["env"], check=True, capture_output=True,
                   timeout=600, stdin=subprocess.DEVNULL)  # fmt: skip
    mp4 = demo["out"] / "video.mp4"
    assert mp4.stat().st_size > 1000 and mp4.read_bytes()[4:8] == b"ftyp"
    import av  # PyAV, a Nerfstudio dependency

    train = json.loads((demo["out"] / "orchard" / "transforms.json").read_text())["train_filenames"]
    with av.open(str(mp4)) as container:
        stream = container.streams.video[0]
        assert stream.frames == len(train) - 1  # --video-steps 1: one frame per pair of consecutive training cameras
        assert stream.width >= 2 * WIDTH - 2  # rgb and thermal side by side

    log_path = demo["root"] / "viewer.log"
    with open(log_path, "w") as log:
        proc = subprocess.Popen(shlex.split(viewer), cwd=demo["root"], env=demo["env"], stdout=log,
                                stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)  # fmt: skip
    try:
        port, deadline = None, time.monotonic() + 300
        while port is None and time.monotonic() < deadline and proc.poll() is None:
            found = re.search(r"HTTP\s*\S\s*http://[0-9.]+:(\d+)", log_path.read_text(errors="replace"))
            port = int(found.group(1)) if found else None
            time.sleep(1)
        assert port is not None, log_path.read_text(errors="replace")[-3000:]
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=30) as page:
            assert page.status == 200 and b"<html" in page.read(2000).lower()
    finally:
        proc.terminate()
        proc.wait(timeout=60)


def test_sheet_draws_the_outputs_a_model_has(tmp_path: Path) -> None:
    """Optional columns follow the model's outputs: temperature gets its own degrees-C bar, found fruit is boxed."""
    rng = np.random.default_rng(0)

    def view(name: str, with_thermal: bool) -> HeldOutView:
        outputs = {"rgb": rng.uniform(0, 0.1, (HEIGHT, WIDTH, 3)).astype(np.float32)}
        outputs["temperature"] = rng.uniform(10, 30, (HEIGHT, WIDTH)).astype(np.float32)
        frame = rng.uniform(0, 1, (HEIGHT, WIDTH)).astype(np.float32) if with_thermal else None
        if with_thermal:
            outputs["thermal"] = frame
        dark = rng.uniform(0, 0.03, (HEIGHT, WIDTH, 3)).astype(np.float32)
        return HeldOutView(name, dark, rng.uniform(0, 1, (HEIGHT, WIDTH, 3)).astype(np.float32), outputs, frame)

    views = [view("a.png", True), view("b.png", True)]
    columns = sheet_columns(views, found={"a.png": [(2.0, 3.0, 20.0, 18.0)]})
    titles = [c.title for c in columns]
    assert titles[-1] == "AgriNeRF temperature (degrees C)" and "AgriNeRF thermal-camera output" not in " ".join(titles)
    assert float(re.search(r"x(\d+)", titles[1]).group(1)) > 1  # a dark frame is brightened
    rendered = next(c for c in columns if c.title.startswith("AgriNeRF RGB render"))
    assert rendered.boxes == [[(2.0, 3.0, 20.0, 18.0)], []]
    temperature = columns[-1].scale
    assert temperature is not None and 10 <= temperature.vmin < temperature.vmax <= 30

    layout = write_contact_sheet(columns, [v.name for v in views], tmp_path / "sheet.png", title="t", caption="c")
    with Image.open(tmp_path / "sheet.png") as image:
        assert image.size == (layout.width, layout.height)
    assert list(layout.scales) == [THERMAL_SCALE.label, "temperature, degrees C"]
    assert SheetLayout.load(tmp_path / "sheet.json") == layout

    no_thermal = sheet_columns([view("c.png", False)])
    assert not any(c.title.startswith(("thermal frame", "AgriNeRF cross")) for c in no_thermal)


def _luminance(path: Path) -> float:
    """Mean Rec. 709 luma of an image file's sRGB values in [0, 1]."""
    with Image.open(path) as image:
        rgb = np.asarray(image.convert("RGB"), dtype=np.float64) / 255.0
    return float((rgb @ np.array([0.2126, 0.7152, 0.0722])).mean())


@pytest.mark.slow
def test_dark_run_shown_at_a_lit_exposure_in_the_viewer_and_ns_render(demo: Dict, tmp_path: Path) -> None:
    """The demo's dark run: the viewer (headless Chromium) opens on `rgb_display`, whose frame is within a factor 2 of
    the lit truth's mean luminance, and shows the temperature legend; `ns-render --display-ev` at the viewer's
    exposure writes `rgb` at that gain, each held-out view within a factor 2 of its lit truth."""
    import torch
    from playwright.sync_api import expect
    from test_viewer import _viewport, browser_page, control_value, select_output, serve_viewer

    from agrinerf_ns.colour import srgb_to_linear

    config, truth = demo["summary"]["config"], demo["out"] / "raw" / "truth" / "rgb_clean"
    lit = float(np.mean([_luminance(p) for p in truth.glob("*.png")]))
    with serve_viewer(Path(config), tmp_path / "ns-viewer.log") as url, browser_page(url) as page:
        assert page.get_by_label("Output type", exact=True).input_value() == "rgb_display", "a dark capture"
        ev = float(control_value(page, "Display exposure (EV)"))
        assert ev > 3
        page.wait_for_timeout(3000)
        page.screenshot(path=tmp_path / "viewer_rgb_display.png")
        shown = _viewport(tmp_path / "viewer_rgb_display.png") / 255.0
        luma = float((shown @ np.array([0.2126, 0.7152, 0.0722])).mean())
        assert lit / 2 < luma < 2 * lit, (luma, lit)
        select_output(page, "temperature_display")
        expect(page.get_by_role("img", name="colour scale")).to_be_visible()
        expect(page.get_by_text("(left, middle, right)")).to_be_visible()
        assert "°C" in page.get_by_text("(left, middle, right)").inner_text()
        page.screenshot(path=tmp_path / "viewer_temperature.png")

    out = tmp_path / "render"
    subprocess.run(["ns-render", "dataset", "--load-config", config, "--split", "test", "--image-format", "png",
                    "--rendered-output-names", "rgb", "rgb_display", "--display-ev", str(ev),
                    "--output-path", str(out)],
                   cwd=demo["root"], env=demo["env"], check=True, capture_output=True, timeout=600,
                   stdin=subprocess.DEVNULL)  # fmt: skip
    views = sorted((out / "test" / "rgb_display").glob("*.png"))
    assert len(views) == 2
    for path in views:
        with Image.open(out / "test" / "rgb" / path.name) as rgb, Image.open(path) as display:
            rgb_linear = srgb_to_linear(torch.from_numpy(np.asarray(rgb.convert("RGB"), dtype=np.float32) / 255.0))
            display_linear = srgb_to_linear(
                torch.from_numpy(np.asarray(display.convert("RGB"), dtype=np.float32) / 255)
            )
        unclipped = display_linear < 0.95  # the 8-bit dark render is coarse per pixel; its mean carries the gain
        gain = float(display_linear[unclipped].mean() / rgb_linear[unclipped].mean())
        assert gain == pytest.approx(2.0**ev, rel=0.1), "the option's exposure, in linear light"
        luma, truth_luma = _luminance(path), _luminance(truth / path.name)
        assert truth_luma / 2 < luma < 2 * truth_luma, (path.name, luma, truth_luma)
