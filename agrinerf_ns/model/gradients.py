"""Which loss term pulls which parameters: per-term gradient norms on the AgriNeRF field's parameter groups.

Used by the loss-routing tests (which term may move which group) and by ``benchmarks/bench_loss_gradients.py`` (how
hard each term pulls the shared density over training).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Dict, List, Mapping, Optional

import torch
from jaxtyping import Float
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


def term_gradients(
    terms: Mapping[str, Tensor], groups: Mapping[str, List[Parameter]]
) -> Dict[str, Dict[str, Optional[Float[Tensor, " n"]]]]:
    """Each (weighted) loss term's gradient on each parameter group, flattened: ``{term: {group: grad or None}}``.

    Each term is differentiated on its own (the graph is kept for the next); None where the term does not reach the
    group at all.
    """
    flat = [p for params in groups.values() for p in params]
    out: Dict[str, Dict[str, Optional[Tensor]]] = {}
    for term, value in terms.items():
        if not value.requires_grad:
            out[term] = {group: None for group in groups}
            continue
        grads = torch.autograd.grad(value, flat, retain_graph=True, allow_unused=True)
        by_param = dict(zip(map(id, flat), grads, strict=True))
        out[term] = {}
        for group, params in groups.items():
            parts = [by_param[id(p)].reshape(-1) for p in params if by_param[id(p)] is not None]
            out[term][group] = torch.cat(parts) if parts else None
    return out


def term_gradient_norms(
    terms: Mapping[str, Tensor], groups: Mapping[str, List[Parameter]]
) -> Dict[str, Dict[str, float]]:
    """L2 norm of each (weighted) loss term's gradient on each parameter group: ``{term: {group: norm}}``.

    A group the term does not reach has norm 0.0; non-finite gradients give NaN, so they show in a table instead of
    disappearing.
    """
    return {
        term: {group: _norm(grad) for group, grad in by_group.items()}
        for term, by_group in term_gradients(terms, groups).items()
    }


def _norm(grad: Optional[Tensor]) -> float:
    if grad is None:
        return 0.0
    value = float(grad.double().norm())
    return value if math.isfinite(value) else math.nan
