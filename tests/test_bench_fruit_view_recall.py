"""benchmarks/fruit_view_recall.py: which true fruit of each training view the fruit channel's regions find, by size."""

from pathlib import Path

import imageio.v3 as iio
import numpy as np
from helpers.bench_script import load_bench_script

from agrinerf_ns.count.render import RenderedView, RenderSet, WorldFrame, save_renders

SIZE, FOCAL = 128, 256.0
"""At depth 1 and focal 256 px, a 0.1-unit fruit is 25.6 px across (the region filter keeps 0.03-0.16 units)."""


def _capture(root: Path, found_small: bool) -> Path:
    """One training view with a 26 px fruit (id 1, about 530 px) and an 11 px one (id 2, about 95 px); the fruit
    channel shows the large one, and the small one only when `found_small`."""
    y, x = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    ids = np.zeros((SIZE, SIZE), np.uint16)
    ids[(y - 40) ** 2 + (x - 40) ** 2 <= 13.0**2] = 1
    ids[(y - 90) ** 2 + (x - 90) ** 2 <= 5.5**2] = 2
    (root / "raw" / "truth" / "fruit_ids").mkdir(parents=True)
    iio.imwrite(root / "raw" / "truth" / "fruit_ids" / "0.png", ids)
    fruit = np.where(ids == 1, 0.9, 0.02).astype(np.float32)
    if found_small:
        fruit[ids == 2] = 0.9
    directions = np.zeros((SIZE, SIZE, 3), np.float32)
    directions[..., 2] = -1.0
    view = RenderedView(name="0", split="train", file_path="0.png", rgb=None, depth=np.ones((SIZE, SIZE)),
                        accumulation=np.ones((SIZE, SIZE)), origins=np.zeros((SIZE, SIZE, 3), np.float32),
                        directions=directions, focal=FOCAL, fruit=fruit)  # fmt: skip
    save_renders(RenderSet([view], WorldFrame(np.eye(4)[:3], 1.0), None, None, "agrinerf-lite"), root / "renders")
    return root


def test_the_fruit_views_found_are_counted_by_size(tmp_path: Path) -> None:
    recall = load_bench_script("fruit_view_recall")
    large_only = _capture(tmp_path / "a", found_small=False)
    text = recall.main(recall.Args(renders=large_only / "renders", raw=large_only / "raw"))
    assert "found: 1 of 2 (0.50)" in text
    assert "fruit views of 20-100 px: 1, found 0.00" in text and "fruit views of 300-1000 px: 1, found 1.00" in text
    both = _capture(tmp_path / "b", found_small=True)
    text = recall.main(recall.Args(renders=both / "renders", raw=both / "raw", min_pixels=20))
    assert "found: 2 of 2 (1.00)" in text and "fruit views of 20-100 px: 1, found 1.00" in text
