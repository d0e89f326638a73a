"""Contact sheet of a raw capture: per row one frame's RGB, clean RGB truth, thermal and event frame."""

from __future__ import annotations

from pathlib import Path
from typing import List, Union

import h5py
import numpy as np
from PIL import Image, ImageDraw

from agrinerf_ns.synth.sensors import event_frame
from agrinerf_ns.views import evenly_spaced


def _read_times(path: Path) -> List[float]:
    return [float(line.split()[1]) for line in path.read_text().splitlines() if line.strip()]


def _tile(img: np.ndarray, height: int) -> Image.Image:
    im = Image.fromarray(img)
    w = max(1, round(im.width * height / im.height))
    return im.resize((w, height), Image.Resampling.NEAREST)


def contact_sheet(raw: Union[str, Path], out_png: Union[str, Path], rows: int = 4, tile_height: int = 120) -> Path:
    """Write a PNG contact sheet of ``rows`` frames of the raw capture at ``raw``; returns ``out_png``."""
    raw = Path(raw)
    names = sorted(p.name for p in (raw / "rgb").glob("*.png"))
    if not names:
        raise FileNotFoundError(f"no RGB frames in {raw / 'rgb'}")
    times = _read_times(raw / "rgb" / "timestamps.txt")
    pick = evenly_spaced(len(names), rows)
    thermal = [np.asarray(Image.open(raw / "thermal" / names[i])).astype(np.float64) for i in pick]
    lo, hi = np.percentile(np.concatenate([t.ravel() for t in thermal]), [1, 99])
    with h5py.File(raw / "events" / "events.h5", "r") as f:
        g = f["events"]
        ex, ey, et, ep = g["x"][:], g["y"][:], g["t"][:], g["p"][:]
        ew, eh = int(g.attrs["width"]), int(g.attrs["height"])
    dt = (times[1] - times[0]) if len(times) > 1 else 0.1
    sheet_rows, widths = [], []
    for k, i in enumerate(pick):
        rgb = np.asarray(Image.open(raw / "rgb" / names[i]).convert("RGB"))
        clean_path = raw / "truth" / "rgb_clean" / names[i]
        clean = np.asarray(Image.open(clean_path).convert("RGB")) if clean_path.exists() else np.zeros_like(rgb)
        th = np.clip((thermal[k] - lo) / max(hi - lo, 1.0), 0, 1)
        th_rgb = (np.stack([th**0.8, th**2.0, 0.4 * (1 - th) * th + th**6], -1) * 255).astype(np.uint8)
        t_us = times[i] * 1e6
        m = (et >= t_us - 0.5 * dt * 1e6) & (et < t_us + 0.5 * dt * 1e6)
        net = event_frame(ex[m], ey[m], ep[m], ew, eh)
        ev = np.full((eh, ew, 3), 255, np.uint8)
        ev[net < 0] = (40, 80, 230)
        ev[net > 0] = (220, 40, 40)
        tiles = [_tile(a, tile_height) for a in (rgb, clean, th_rgb, ev)]
        widths = [t.width for t in tiles]
        row = Image.new("RGB", (sum(t.width for t in tiles) + 4 * (len(tiles) - 1), tile_height), (0, 0, 0))
        x = 0
        for t in tiles:
            row.paste(t, (x, 0))
            x += t.width + 4
        sheet_rows.append(row)
    header = 16
    width = max(r.width for r in sheet_rows)
    sheet = Image.new("RGB", (width, header + len(sheet_rows) * (tile_height + 4)), (0, 0, 0))
    draw = ImageDraw.Draw(sheet)
    x = 0
    for label, tile in zip(("RGB", "RGB truth", "thermal", "events (net: red ON, blue OFF)"), widths, strict=True):
        draw.text((x + 2, 2), label, fill=(255, 255, 255))
        x += tile + 4
    for r, row in enumerate(sheet_rows):
        sheet.paste(row, (0, header + r * (tile_height + 4)))
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(out_png, format="PNG", optimize=True)
    return out_png
