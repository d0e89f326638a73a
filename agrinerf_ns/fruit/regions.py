"""Fruit in a view's rendered fruit probability (the fruit head, learnt from the frames' fruit masks): the regions
above a probability, touching fruit split at the necks of their distance transform (scikit-image's watershed, seeded
by the transform's peaks), each kept where its size is a fruit's."""

from __future__ import annotations

from typing import List

import numpy as np
from jaxtyping import Bool
from scipy import ndimage
from skimage.segmentation import watershed

from agrinerf_ns.fruit.blobs import BlobConfig, Detection, blob_diameter, elongation, valid_pixels
from agrinerf_ns.fruit.view import View


def fruit_regions(view: View, scale: float, config: BlobConfig = BlobConfig()) -> List[Detection]:
    """The fruit of ``view`` from its ``fruit`` output; ``scale`` is the dataparser scale (Nerfstudio units per
    dataset unit), so that sizes are compared in the dataset's units (``config``'s diameters and elongation; its
    ``fruit_probability`` makes a pixel fruit)."""
    fruit = view.optional_output("fruit").astype(np.float32)
    valid = valid_pixels(view, fruit)
    above = (fruit >= config.fruit_probability) & valid
    labels, count = ndimage.label(above, structure=np.ones((3, 3), bool))
    detections: List[Detection] = []
    for index, box in enumerate(ndimage.find_objects(labels), start=1):
        if box is None:
            continue
        region = labels[box] == index
        for part in split_touching(region, _radius_px(view, box, region, scale, config.min_diameter)):
            mask = np.zeros(above.shape, bool)
            mask[box] = part
            if mask.sum() < config.min_pixels or elongation(mask) > config.max_elongation:
                continue
            diameter = blob_diameter(mask, view, scale)
            if diameter is None or not config.min_diameter <= diameter <= config.max_diameter:
                continue
            detections.append(Detection(mask, float(fruit[mask].mean())))
    return detections


def _radius_px(view: View, box: tuple, region: Bool[np.ndarray, "h w"], scale: float, diameter: float) -> float:
    """The radius in pixels of a fruit of ``diameter`` (dataset units) at the region's median depth."""
    depths = view.depth[box][region]
    depth = float(np.median(depths[np.isfinite(depths) & (depths > 0)])) if region.any() else 0.0
    return 0.5 * diameter * scale * view.focal / max(depth, 1e-9)


def split_touching(region: Bool[np.ndarray, "h w"], min_radius_px: float) -> List[Bool[np.ndarray, "h w"]]:
    """A region cut into one part per fruit: the peaks of its distance transform at least ``min_radius_px`` apart
    (at least one pixel) seed a watershed of the inverted distance, so touching discs part at their neck."""
    distance = ndimage.distance_transform_edt(region)
    size = max(3, 2 * int(round(min_radius_px)) + 1)
    peaks = (distance == ndimage.maximum_filter(distance, size=size)) & region & (distance >= 1.0)
    markers, count = ndimage.label(peaks, structure=np.ones((3, 3), bool))
    if count <= 1:
        return [region]
    flooded = watershed(-distance, markers, mask=region)
    return [flooded == label for label in range(1, count + 1)]
