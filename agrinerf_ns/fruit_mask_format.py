"""The fruit-mask values of a dataset, shared by the processing that writes masks and the dataparser that reads them.

A frame's ``fruit_mask_file_path`` (``transforms.json``; its keys and folder: :mod:`agrinerf_ns.dataset_format`) names a single-channel 8-bit image in the RGB camera's plane,
at the RGB frame's resolution: :data:`BACKGROUND` (0), :data:`UNKNOWN` (128: nobody knows, not supervised), any other
value fruit (so 0/255 and 0/1 masks, as segmenters and FruitNeRF's ``semantics/`` write them, read as they are).
A frame's optional ``fruit_mask_camera`` says whose view the mask holds: ``rgb`` (the default) or ``thermal``, a mask
made on the thermal frame warped into the RGB plane, which holds what the thermal camera saw along its own rays (a
few centimetres of baseline put its fruit many pixels from the RGB frame's): the model supervises such a mask along
the thermal camera's rays.
"""

from __future__ import annotations

from typing import Tuple

import numpy as np
from jaxtyping import Bool, UInt8

BACKGROUND = 0
UNKNOWN = 128
FRUIT = 255
"""The value masks made here give fruit (any value but 0 and 128 reads as fruit)."""


def fruit_and_known(values: UInt8[np.ndarray, "h w"]) -> Tuple[Bool[np.ndarray, "h w"], Bool[np.ndarray, "h w"]]:
    """(fruit, known) of a mask's values."""
    known = values != UNKNOWN
    return known & (values != BACKGROUND), known
