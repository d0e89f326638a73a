"""A picture of held-out views: true boxes (green) and detections (red, score >= threshold) per method."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List

import numpy as np
from jaxtyping import Float


@dataclass(frozen=True)
class PanelBoxes:
    """What one panel shows: an image and its true and detected boxes (pixel xyxy)."""

    image: Path
    true_boxes: Float[np.ndarray, "m 4"]
    pred_boxes: Float[np.ndarray, "n 4"]
    scores: Float[np.ndarray, " n"]


def detection_figure(
    panels: Dict[str, Dict[str, PanelBoxes]], out: Path, conf_threshold: float = 0.25, max_views: int = 3
) -> Path:
    """Grid: one row per view (up to ``max_views``), one column per method. ``panels[method][frame]``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle
    from PIL import Image

    methods = list(panels)
    if not methods:
        raise ValueError(f"{out}: nothing to draw")
    frames: List[str] = sorted(set.intersection(*(set(p) for p in panels.values())))[:max_views]
    if not frames:
        raise ValueError(f"{out}: the methods share no rendered view to draw")
    fig, axes = plt.subplots(len(frames), len(methods), figsize=(3.2 * len(methods), 2.6 * len(frames)), squeeze=False)
    for r, frame in enumerate(frames):
        for c, method in enumerate(methods):
            panel = panels[method][frame]
            ax = axes[r][c]
            image = np.asarray(Image.open(panel.image))
            ax.imshow(image, cmap="gray" if image.ndim == 2 else None, vmin=0, vmax=255)
            _draw(ax, Rectangle, panel.true_boxes, "lime", "-")
            keep = panel.scores >= conf_threshold
            _draw(ax, Rectangle, panel.pred_boxes[keep], "red", "--")
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(method, fontsize=9)
            if c == 0:
                ax.set_ylabel(frame, fontsize=8)
    fig.suptitle(f"true boxes (green) vs detections (red, score >= {conf_threshold})", fontsize=9)
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def _draw(ax, rectangle, boxes: Float[np.ndarray, "n 4"], colour: str, style: str) -> None:
    for x1, y1, x2, y2 in np.asarray(boxes).reshape(-1, 4):
        ax.add_patch(rectangle((x1, y1), x2 - x1, y2 - y1, fill=False, edgecolor=colour, linestyle=style, linewidth=1))
