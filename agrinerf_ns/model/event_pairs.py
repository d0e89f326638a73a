"""EvDeblurNeRF's event supervision: event-to-event samples drawn from the stream.

One sample is one event that has a successor at its pixel: the pixel is rendered at the event's time and at its
successor's, and the change of log luminance between the two is compared with the contrast threshold times the
successor's polarity (always +C_on or -C_off: between two consecutive events of a pixel its log intensity moved by
one threshold, in the direction of the second). Samples are drawn uniformly over all events that have a successor
(EvDeblurNeRF's ``data/loader_events.py``, ``utils/events.py``: ``compute_successor``, ``egm_loss``). Unlike the
windowed supervision (``event_stream.sample_windows``), no sample is a pixel without events, and every target has
the size of one threshold.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Optional, Tuple, Union

import numpy as np
import torch
from jaxtyping import Bool, Float, Int, Integer
from torch import Tensor

from agrinerf_ns.dataparsers.event_stream import read_stream_h5


class EventPairs:
    """Every event of a ``width`` x ``height`` stream that has a successor at its pixel, with that successor's time
    and polarity.

    Args:
        x, y: pixel coordinates of each event.
        t_us: time of each event (integer microseconds, the frames' clock).
        p: polarity, 1 = ON, 0 = OFF.
        width, height: the event camera's resolution.
    """

    def __init__(
        self,
        x: Integer[np.ndarray, " n"],
        y: Integer[np.ndarray, " n"],
        t_us: Integer[np.ndarray, " n"],
        p: Integer[np.ndarray, " n"],
        width: int,
        height: int,
    ) -> None:
        self.width, self.height = int(width), int(height)
        pixel = np.asarray(y, dtype=np.int64) * self.width + np.asarray(x, dtype=np.int64)
        t = np.asarray(t_us, dtype=np.int64)
        order = np.lexsort((t, pixel))  # by pixel, then time; stable, so equal times keep the stream's order
        same = pixel[order[1:]] == pixel[order[:-1]]
        first, second = order[:-1][same], order[1:][same]
        # host: the pairs live in host memory (sampled there, the batch then moved)
        self.pixel = torch.from_numpy(pixel[first])  # host: see above
        self.t_start_us = torch.from_numpy(t[first])  # host: see above
        self.t_end_us = torch.from_numpy(t[second])  # host: see above
        self.polarity = torch.from_numpy(np.where(np.asarray(p)[second] > 0, 1, -1).astype(np.int8))  # host: see above

    @classmethod
    def from_h5(cls, path: Path, width: int, height: int) -> "EventPairs":
        """The pairs of a dataset's ``events/stream.h5``."""
        return cls(*read_stream_h5(path, width, height), width, height)

    def at_pixels(self, keep: Bool[Tensor, " pixels"]) -> "EventPairs":
        """The pairs at the pixels `keep` marks (per pixel ``y * width + x``), drawn uniformly over these alone: how
        the event gate's held-out pixels stay out of training."""
        kept = copy.copy(self)
        select = keep.to(self.pixel.device)[self.pixel]
        kept.pixel, kept.t_start_us = self.pixel[select], self.t_start_us[select]
        kept.t_end_us, kept.polarity = self.t_end_us[select], self.polarity[select]
        return kept

    def to(self, device: torch.device) -> "EventPairs":
        """These pairs on `device`: `sample` then draws there (from that device's random stream)."""
        moved = copy.copy(self)
        moved.pixel, moved.t_start_us = self.pixel.to(device), self.t_start_us.to(device)
        moved.t_end_us, moved.polarity = self.t_end_us.to(device), self.polarity.to(device)
        return moved

    def __len__(self) -> int:
        return int(self.pixel.shape[0])

    def sample(
        self, m: int, generator: Optional[torch.Generator] = None
    ) -> Tuple[Int[Tensor, " m"], Int[Tensor, " m"], Int[Tensor, " m"], Int[Tensor, " m"]]:
        """`m` pairs drawn uniformly (with replacement) over all pairs: pixel, event time, successor time (us) and the
        successor's polarity (+1 / -1), on the pairs' device. Empty tensors when the stream has no pair."""
        if len(self) == 0 or m <= 0:
            empty = torch.zeros(0, dtype=torch.long, device=self.pixel.device)
            return empty, empty, empty, empty
        index = torch.randint(0, len(self), (m,), generator=generator, device=self.pixel.device)  # where the pairs are
        return self.pixel[index], self.t_start_us[index], self.t_end_us[index], self.polarity[index].long()


def pair_targets(
    polarity: Int[Tensor, " m"], c_on: Union[float, Float[Tensor, ""]], c_off: Union[float, Float[Tensor, ""]]
) -> Float[Tensor, "m 1"]:
    """The log-luminance change each pair stands for: +C_on for an ON successor, -C_off for an OFF one; on the
    thresholds' device where they are tensors (learnt thresholds live with the model, the pairs on the CPU)."""
    device = c_on.device if isinstance(c_on, Tensor) else polarity.device
    on = (polarity.to(device) > 0).float()[:, None]
    return on * c_on - (1.0 - on) * c_off


def polarity_features(polarity: Int[Tensor, " m"]) -> Float[Tensor, "m 2"]:
    """The successor's (negative, positive) polarity sums, EvDeblurNeRF's extra inputs of its event CRF
    (``tone_mapping_events_add_bii = pos-neg``): (-1, 0) for an OFF successor, (0, 1) for an ON one."""
    p = polarity.float()
    return torch.stack([p.clamp(max=0.0), p.clamp(min=0.0)], dim=-1)
