"""`ns-viewer` on a tiny trained AgriNeRF run, opened in a real headless Chromium (Debian's `chromium`, which
`scripts/install.sh --dev` installs as root; driven by playwright-python, which downloads no browser): the page
connects, the viewer opens on `rgb` (a lit capture), its output list holds `rgb`, `rgb_display` and `thermal`, `thermal`
renders with a colormap, and the display exposure control is there. The demo's dark run in the browser:
tests/test_demo.py.
Screenshots are written next to the test's output (its tmp_path, printed on failure)."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import time
import urllib.request
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest
from PIL import Image

pytestmark = pytest.mark.slow

ENV = {**os.environ, "PYTHONWARNINGS": "ignore"}
STARTUP_S = 300
"""How long ns-viewer may take to load the run and serve the page on a busy 2-core CI machine."""


def _chromium() -> str:
    """Path of the system Chromium; a failure in CI (install.sh --dev installs it as root), a skip elsewhere."""
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    message = "no Chromium on PATH: install Debian's with 'apt-get install chromium' (install.sh --dev does as root)"
    if os.environ.get("CI"):
        pytest.fail(message)
    pytest.skip(message)


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@contextmanager
def serve_viewer(config: Path, log_path: Path) -> Iterator[str]:
    """ns-viewer serving the run of ``config`` on a free local port (its URL); stopped (its whole process group)
    afterwards."""
    port = _free_port()
    cmd = ["ns-viewer", "--load-config", str(config), "--viewer.websocket-port", str(port)]
    cmd += ["--viewer.websocket-host", "127.0.0.1"]
    with open(log_path, "w") as log:
        process = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=ENV, start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + STARTUP_S
        while True:
            if process.poll() is not None:
                pytest.fail(f"ns-viewer exited with {process.returncode}:\n{log_path.read_text()[-3000:]}")
            try:
                urllib.request.urlopen(url, timeout=2).close()
                break
            except OSError:
                if time.monotonic() > deadline:
                    pytest.fail(f"ns-viewer served nothing at {url} in {STARTUP_S} s:\n{log_path.read_text()[-3000:]}")
                time.sleep(1)
        yield url
    finally:
        os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait(timeout=30)


@pytest.fixture
def viewer_url(tiny_run_config: Path, tmp_path: Path) -> Iterator[str]:
    """ns-viewer serving the tiny run."""
    with serve_viewer(tiny_run_config, tmp_path / "ns-viewer.log") as url:
        yield url


@contextmanager
def browser_page(url: str) -> Iterator[Any]:
    """A page of headless Chromium at ``url``, connected to the viewer and showing its first rendered frame."""
    from playwright.sync_api import expect, sync_playwright

    with sync_playwright() as playwright:
        # --no-sandbox: CI runs as root, where Chromium's sandbox refuses to start
        browser = playwright.chromium.launch(executable_path=_chromium(), headless=True, args=["--no-sandbox"])
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.goto(url)
            expect(page.get_by_text("Connected", exact=True)).to_be_visible(timeout=120_000)
            output = page.get_by_label("Output type", exact=True)
            # "not set" until the first rendered frame reaches the page with the model's output names
            expect(output).not_to_have_value("not set", timeout=120_000)
            yield page
        finally:
            browser.close()


def control_value(page: Any, label: str) -> str:
    """The value of the viewer control labelled ``label`` (a slider's number box)."""
    row = page.locator(f"xpath=//label[text()='{label}']/ancestor::div[contains(@class,'mantine-Flex-root')][1]")
    return row.locator("input").first.input_value()


def select_output(page: Any, name: str) -> None:
    """Choose ``name`` in the viewer's "Output type" list."""
    from playwright.sync_api import expect

    output = page.get_by_label("Output type", exact=True)
    output.click()
    page.get_by_role("option", name=name, exact=True).click()
    expect(output).to_have_value(name)


def _viewport(path: Path) -> np.ndarray:
    """The render area of a screenshot (left of the control panel, below the title bar)."""
    image = np.asarray(Image.open(path).convert("RGB"), dtype=float)
    return image[80:, : int(image.shape[1] * 0.7)]


def test_viewer_opens_on_rgb_and_lists_thermal(viewer_url: str, tmp_path: Path) -> None:
    from playwright.sync_api import expect

    with browser_page(viewer_url) as page:
        output = page.get_by_label("Output type", exact=True)
        assert output.input_value() == "rgb", "a lit capture opens on rgb"
        page.wait_for_timeout(3000)
        page.screenshot(path=tmp_path / "viewer_rgb.png")

        output.click()
        options = page.get_by_role("option").all_inner_texts()
        assert {"rgb", "rgb_display", "thermal", "depth", "accumulation"} <= set(options), options
        page.keyboard.press("Escape")
        select_output(page, "thermal")
        colormap = page.get_by_label("Colormap", exact=True).first
        expect(colormap).to_be_enabled()  # disabled for rgb
        expect(colormap).to_have_value("turbo")  # Nerfstudio's choice for a one-channel output
        assert float(control_value(page, "Display exposure (EV)")) == 0.0, "a lit capture is shown as it is"

        rgb = _viewport(tmp_path / "viewer_rgb.png")
        deadline = time.monotonic() + 60
        while True:  # the thermal render replaces the rgb one in the page
            page.screenshot(path=tmp_path / "viewer_thermal.png")
            if np.abs(_viewport(tmp_path / "viewer_thermal.png") - rgb).mean() > 10:
                break
            assert time.monotonic() < deadline, "the viewport still shows the rgb render 60 s after thermal"
            page.wait_for_timeout(1000)
    print(f"screenshots: {tmp_path / 'viewer_rgb.png'} {tmp_path / 'viewer_thermal.png'}")
