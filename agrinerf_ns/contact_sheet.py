"""A labelled contact sheet: one row per view, one titled column per image kind, a colour scale under each false-colour
column, a title and a caption; written as PNG with its layout beside it (``<name>.json``).

Drawn with Matplotlib (titles, colormaps, colour bars); the panels are placed at pixel positions computed here so that
the picture's size and layout follow from the tile size alone (a tight bounding box would move them with the text).
"""

from __future__ import annotations

import json
import math
import os
import textwrap
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Dict, List, Optional, Sequence, Tuple

import numpy as np
import torch
from jaxtyping import Float

from agrinerf_ns.colour import linear_to_srgb, srgb_to_linear

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

Box = Tuple[float, float, float, float]
"""(x0, y0, x1, y1) in the pixels of a view's image."""

DPI = 100
FONT_PT = 9
LINE_PX = 14
"""Height of one line of 9-point text at 100 dpi, with leading."""
MARGIN_PX = 12
GAP_PX = 8
LABEL_PX = 92
"""Width of the band left of the rows that holds each row's label."""
BAR_PX = 58
"""Height of the band under the rows that holds the colour scales."""


@dataclass(frozen=True)
class ColourScale:
    """How a single-channel column is coloured: the colormap over [vmin, vmax] and the label of its scale bar."""

    label: str
    vmin: float
    vmax: float
    cmap: str = "inferno"


@dataclass
class Column:
    """One kind of image, one per view: (H, W, 3) sRGB in [0, 1], or (H, W) values in ``scale``'s units (NaN: no
    data, drawn grey)."""

    title: str
    images: Sequence[np.ndarray]
    scale: Optional[ColourScale] = None
    boxes: Optional[Sequence[Sequence[Box]]] = None
    """Boxes to draw on each view's image (e.g. the fruit a detector found), or None."""


@dataclass
class Panel:
    """Where one image of the sheet is: ``box`` = (x0, y0, x1, y1) in the PNG's pixels from its top left corner."""

    column: str
    view: str
    box: Tuple[int, int, int, int]


@dataclass
class SheetLayout:
    """The PNG's size and where each panel and colour scale is on it."""

    width: int
    height: int
    columns: List[str]
    views: List[str]
    panels: List[Panel] = field(default_factory=list)
    scales: Dict[str, Tuple[int, int, int, int]] = field(default_factory=dict)
    """Colour scale label -> box of its bar (one bar under each run of adjacent columns that share a scale)."""

    def save(self, path: Path) -> None:
        path.write_text(json.dumps(asdict(self), indent=2))

    @staticmethod
    def load(path: Path) -> "SheetLayout":
        record = json.loads(Path(path).read_text())
        panels = [Panel(p["column"], p["view"], tuple(p["box"])) for p in record.pop("panels")]
        scales = {k: tuple(v) for k, v in record.pop("scales").items()}
        return SheetLayout(**record, panels=panels, scales=scales)


def display_gain(image: Float[np.ndarray, "h w 3"], target: float = 0.5, max_gain: float = 1000.0) -> float:
    """The gain in linear light that brings the 99th percentile of ``image`` (sRGB) to ``target`` (at least 1)."""
    linear = srgb_to_linear(torch.from_numpy(np.ascontiguousarray(image, dtype=np.float32)))
    top = float(torch.quantile(linear.flatten(), 0.99))
    return float(np.clip(target / max(top, 1e-6), 1.0, max_gain))


def brighten(image: Float[np.ndarray, "h w 3"], gain: float) -> Float[np.ndarray, "h w 3"]:
    """``image`` (sRGB) times ``gain`` in linear light, clipped: a display stretch, not a correction."""
    linear = srgb_to_linear(torch.from_numpy(np.ascontiguousarray(image, dtype=np.float32)))
    return linear_to_srgb(linear * gain).numpy()


def tile_scale(width: int, min_tile_px: int = 240) -> int:
    """Integer upscaling of a view ``width`` pixels wide so that a tile is at least ``min_tile_px`` wide."""
    return max(1, math.ceil(min_tile_px / width))


def _scale_runs(columns: Sequence[Column]) -> List[Tuple[ColourScale, int, int]]:
    """(scale, first, last column index) of each run of adjacent columns with the same colour scale."""
    runs: List[Tuple[ColourScale, int, int]] = []
    for index, column in enumerate(columns):
        if column.scale is None:
            continue
        if runs and runs[-1][0] == column.scale and runs[-1][2] == index - 1:
            runs[-1] = (column.scale, runs[-1][1], index)
        else:
            runs.append((column.scale, index, index))
    return runs


@dataclass(frozen=True)
class SheetGrid:
    """Where the sheet's parts go, in pixels from the top left: figure size, tile size, and the top of the rows."""

    fig_w: int
    fig_h: int
    tile_w: int
    tile_h: int
    top: int
    """Top of the first row of tiles (under the title and the column titles)."""
    titles: List[str]
    """Each column's title, wrapped to its tile's width."""
    caption_lines: List[str]

    def column_x(self, index: int) -> int:
        """Left edge of column ``index``."""
        return MARGIN_PX + LABEL_PX + index * (self.tile_w + GAP_PX)

    def row_y(self, index: int) -> int:
        """Top edge of row ``index``."""
        return self.top + index * (self.tile_h + GAP_PX)


def sheet_grid(
    columns: Sequence[Column], views: Sequence[str], title: str, caption: str, min_tile_px: int
) -> SheetGrid:
    """The grid of a sheet of ``columns`` x ``views``: tiles at least ``min_tile_px`` wide, text bands sized to the
    wrapped titles and caption."""
    height, width = np.asarray(columns[0].images[0]).shape[:2]
    zoom = tile_scale(width, min_tile_px)
    tile_w, tile_h = width * zoom, height * zoom
    chars = max(12, int(tile_w / (0.55 * FONT_PT * DPI / 72)))
    titles = [textwrap.fill(c.title, chars) for c in columns]
    title_px = LINE_PX * max(t.count("\n") + 1 for t in titles) + 4
    header_px = (LINE_PX + 10) if title else 0
    caption_lines = (
        textwrap.fill(caption, int((len(columns) * (tile_w + GAP_PX)) / 6.3)).splitlines() if caption else []
    )
    has_scale = any(c.scale is not None for c in columns)
    fig_w = MARGIN_PX * 2 + LABEL_PX + len(columns) * tile_w + (len(columns) - 1) * GAP_PX
    fig_h = (
        MARGIN_PX * 2 + header_px + title_px + len(views) * tile_h + (len(views) - 1) * GAP_PX
        + (BAR_PX if has_scale else 0) + LINE_PX * len(caption_lines)
    )  # fmt: skip
    return SheetGrid(fig_w, fig_h, tile_w, tile_h, MARGIN_PX + header_px + title_px, titles, caption_lines)


def _axes_at(fig: Figure, grid: SheetGrid, x: int, y: int, w: int, h: int) -> Axes:
    """Axes at pixel box (x, y, w, h) measured from the top left, without axis lines."""
    ax = fig.add_axes((x / grid.fig_w, 1.0 - (y + h) / grid.fig_h, w / grid.fig_w, h / grid.fig_h))
    ax.set_axis_off()
    return ax


Placed = Tuple["Axes", str, str]
"""An axes drawn on the sheet, the name it is recorded under, and its view ("" for a colour scale)."""


def _draw_column(fig: Figure, grid: SheetGrid, index: int, column: Column, views: Sequence[str]) -> List[Placed]:
    """Column ``index``: its title and one tile per view (false colour when it has a scale), boxes on top."""
    from matplotlib import colormaps
    from matplotlib.patches import Rectangle

    x = grid.column_x(index)
    fig.text((x + grid.tile_w / 2) / grid.fig_w, 1.0 - (grid.top - 4) / grid.fig_h, grid.titles[index],
             fontsize=FONT_PT, ha="center", va="bottom", linespacing=1.15)  # fmt: skip
    cmap = None
    if column.scale is not None:
        cmap = colormaps[column.scale.cmap].with_extremes(bad="0.5")
    placed: List[Placed] = []
    for r, (view, image) in enumerate(zip(views, column.images, strict=True)):
        ax = _axes_at(fig, grid, x, grid.row_y(r), grid.tile_w, grid.tile_h)
        image = np.asarray(image, dtype=np.float32)
        if column.scale is None:
            ax.imshow(np.clip(image[..., :3], 0.0, 1.0), interpolation="nearest")
        else:
            ax.imshow(np.squeeze(image), cmap=cmap, vmin=column.scale.vmin, vmax=column.scale.vmax,
                      interpolation="nearest")  # fmt: skip
        for x0, y0, x1, y1 in column.boxes[r] if column.boxes is not None else ():
            ax.add_patch(Rectangle((x0 - 0.5, y0 - 0.5), x1 - x0, y1 - y0, fill=False, edgecolor="lime", lw=1.2))
        placed.append((ax, column.title, view))
    return placed


def _draw_scales(fig: Figure, grid: SheetGrid, columns: Sequence[Column], num_views: int) -> List[Placed]:
    """One labelled colour bar under each run of adjacent columns that share a colour scale."""
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    bar_y = grid.row_y(num_views) + 2
    placed: List[Placed] = []
    for scale, first, last in _scale_runs(columns):
        x = grid.column_x(first)
        w = (last - first + 1) * (grid.tile_w + GAP_PX) - GAP_PX
        cax = fig.add_axes((x / grid.fig_w, 1.0 - (bar_y + 10) / grid.fig_h, w / grid.fig_w, 10 / grid.fig_h))
        cmap = colormaps[scale.cmap].with_extremes(bad="0.5")
        bar = fig.colorbar(ScalarMappable(Normalize(scale.vmin, scale.vmax), cmap), cax=cax, orientation="horizontal")
        bar.set_label(scale.label, fontsize=FONT_PT - 1, labelpad=2)
        bar.ax.tick_params(labelsize=FONT_PT - 1, length=2, pad=1)
        placed.append((cax, scale.label, ""))
    return placed


def _draw_row_labels_and_caption(fig: Figure, grid: SheetGrid, views: Sequence[str], row_prefix: str) -> None:
    """Each row's label left of it (``row_prefix`` above the view's name) and the caption at the bottom."""
    for r, view in enumerate(views):
        y_mid = grid.row_y(r) + grid.tile_h / 2
        label = f"{row_prefix}\n{view}" if row_prefix else view
        fig.text(
            (MARGIN_PX + LABEL_PX - 8) / grid.fig_w, 1.0 - y_mid / grid.fig_h, label, fontsize=FONT_PT, ha="right",
            va="center",
        )  # fmt: skip
    if grid.caption_lines:
        fig.text(MARGIN_PX / grid.fig_w, (MARGIN_PX + LINE_PX * len(grid.caption_lines)) / grid.fig_h,
                 "\n".join(grid.caption_lines), fontsize=FONT_PT, va="top", linespacing=1.15)  # fmt: skip


def _measured_layout(
    grid: SheetGrid, columns: Sequence[Column], views: Sequence[str], placed: List[Placed]
) -> SheetLayout:
    """The layout of the drawn sheet: each placed axes' box as the renderer put it."""
    layout = SheetLayout(int(round(grid.fig_w)), int(round(grid.fig_h)), [c.title for c in columns], list(views))
    for ax, name, view in placed:
        x0, y0, x1, y1 = ax.get_window_extent().extents
        box = (int(round(x0)), int(round(grid.fig_h - y1)), int(round(x1)), int(round(grid.fig_h - y0)))
        if view:
            layout.panels.append(Panel(name, view, box))
        else:
            layout.scales[name] = box
    return layout


def write_contact_sheet(
    columns: Sequence[Column],
    views: Sequence[str],
    out: Path,
    title: str = "",
    caption: str = "",
    row_prefix: str = "",
    min_tile_px: int = 240,
) -> SheetLayout:
    """Draw the sheet to ``out`` (PNG, written atomically) and its layout to ``out`` with suffix ``.json``; each row
    is labelled ``row_prefix`` above its view's name."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if not columns or not views:
        raise ValueError("a contact sheet needs at least one column and one view")
    for column in columns:
        if len(column.images) != len(views):
            raise ValueError(f"column {column.title!r} has {len(column.images)} images for {len(views)} views")
    grid = sheet_grid(columns, views, title, caption, min_tile_px)
    fig = Figure(figsize=(grid.fig_w / DPI, grid.fig_h / DPI), dpi=DPI)
    FigureCanvasAgg(fig)
    if title:
        fig.text(MARGIN_PX / grid.fig_w, 1.0 - (MARGIN_PX + 2) / grid.fig_h, title, fontsize=FONT_PT + 2,
                 weight="bold", va="top")  # fmt: skip
    placed: List[Placed] = []
    for c, column in enumerate(columns):
        placed += _draw_column(fig, grid, c, column, views)
    placed += _draw_scales(fig, grid, columns, len(views))
    _draw_row_labels_and_caption(fig, grid, views, row_prefix)

    fig.canvas.draw()
    layout = _measured_layout(grid, columns, views, placed)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.stem}.tmp-{os.getpid()}.png")
    fig.savefig(tmp, dpi=DPI)
    os.replace(tmp, out)
    layout.save(out.with_suffix(".json"))
    return layout
