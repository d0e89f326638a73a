"""Which loss term pulls which parameters: per-term gradient norms on the AgriNeRF field's parameter groups.

Used by the loss-routing tests (which term may move which group) and by ``benchmarks/bench_loss_gradients.py`` (how
hard each term pulls the shared density over training).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Dict, List, Mapping

import torch
from torch import Tensor
from torch.nn import Parameter

if TYPE_CHECKING:
    from agrinerf_ns.model.model import AgriNeRFModel


def parameter_groups(model: "AgriNeRFModel") -> Dict[str, List[Parameter]]:
    """The field's parameters by role: the shared ``density`` volume, each head's ``<head>_volume`` (appearance
    TensoRF) and ``<head>_mlp`` (basis and MLP); heads the model did not build are absent."""
    field = model.field
    groups: Dict[str, List[Parameter]] = {"density": list(field.density_encoding.parameters())}
    for name, head in (("rgb", field.rgb_head), ("thermal", field.thermal_head)):
        if head is not None:
            groups[f"{name}_volume"] = list(head.encoding.parameters())
            groups[f"{name}_mlp"] = head.mlp_parameters()
    return groups


def term_gradient_norms(
    terms: Mapping[str, Tensor], groups: Mapping[str, List[Parameter]]
) -> Dict[str, Dict[str, float]]:
    """L2 norm of each (weighted) loss term's gradient on each parameter group: ``{term: {group: norm}}``.

    Each term is differentiated on its own (the graph is kept for the next); a group the term does not reach has norm
    0.0. Non-finite gradients give NaN, so they show in a table instead of disappearing.
    """
    flat = [p for params in groups.values() for p in params]
    norms: Dict[str, Dict[str, float]] = {}
    for term, value in terms.items():
        if not value.requires_grad:
            norms[term] = {group: 0.0 for group in groups}
            continue
        grads = torch.autograd.grad(value, flat, retain_graph=True, allow_unused=True)
        by_param = dict(zip(map(id, flat), grads, strict=True))
        norms[term] = {}
        for group, params in groups.items():
            squares = [by_param[id(p)].double().pow(2).sum() for p in params if by_param[id(p)] is not None]
            total = float(torch.stack(squares).sum().sqrt()) if squares else 0.0
            norms[term][group] = total if math.isfinite(total) else math.nan
    return norms
