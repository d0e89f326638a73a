"""What the model asks of each of its parts: their renders in training, their loss terms, their parameter groups and
their metrics (`ModelPart`), and what a loss term is given to compute its raw value (`TermInputs`).

The model loops over its parts (`parts.PARTS`) for all four; which terms it computes is the plan's `measured` and
which part computes each the term table's (`loss_routing.TERMS`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Dict, List, Optional

import torch
from nerfstudio.cameras.rays import RayBundle
from torch import Tensor
from torch.nn import Parameter

from agrinerf_ns.model.rig import RenderRays


@dataclass
class TermInputs:
    """A step's outputs and batch, as every loss term reads them."""

    outputs: Dict[str, Tensor]
    batch: Dict[str, Any]
    device: torch.device
    training: bool
    """The model is training: the regularisers count (the parts' side renders are in `outputs` where they ran)."""
    step: int
    raw: Dict[str, Tensor]
    """The raw terms computed so far (a term's weighting may read another's: the event term's `noise` weighting)."""

    def target(self, key: str) -> Optional[Tensor]:
        """The batch's `key` on the device (None where the batch has none)."""
        value = self.batch.get(key)
        return None if value is None else value.to(self.device)


class ModelPart:
    """A part of the model: each method's default is "nothing", so a part implements only what it has."""

    def outputs(self, render: RenderRays, bundle: RayBundle, frame: Dict[str, Tensor], step: int) -> Dict[str, Tensor]:
        """Training only, in the side stream: renders of `bundle`'s pixels at other times or from other cameras
        (`render`: the model's render of a side bundle; `frame`: the outputs of the training rays themselves)."""
        return {}

    def loss(self, term: str, inputs: TermInputs) -> Optional[Tensor]:
        """The raw value of `term` (one of this part's rows in `loss_routing.TERMS`); None where this step has no
        sample of it (a warm-up, an evaluation batch without the part's side renders)."""
        raise KeyError(f"{type(self).__name__} computes no loss term {term!r}")

    def weigh(self, term: str, weighted: Tensor, inputs: TermInputs) -> Tensor:
        """`term`'s loss after its coefficient: any further weighting this part gives it (default: none)."""
        return weighted

    def param_groups(self) -> Dict[str, List[Parameter]]:
        """This part's Parameters by optimizer group (merged into the model's groups, in the parts' order)."""
        return {}

    def metrics(self, training: bool) -> Dict[str, Any]:
        """Metrics of this part's own state (tensors, read by the host only when logged)."""
        return {}
