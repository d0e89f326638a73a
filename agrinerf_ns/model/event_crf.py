"""EvDeblurNeRF's learnt event camera response (its ``networks/tonemapping.py``, ``CRF`` with ``map_type learn``).

The event loss reads the log luma of the render after a learnt response: each linear colour channel x becomes
sigmoid(x + 0.1 MLP([x, f])), with f the sample's successor polarities (``event_pairs.polarity_features``), then BT.601
luma and log(luma + 1e-5). The MLP (16 wide, 3 hidden ReLU layers) is first fit to the identity on x uniform in
[0, 1] with f = 0 (3000 Adam steps, lr 1e-2, 64 x 3 values a step, as published), and the response is the identity
until its start step (1200 in EvDeblurNeRF's configs), when it starts learning with the field.

The sigmoid form cannot be the identity near black (its logit diverges), so after the fit the response keeps a
small floor there: EvDeblurNeRF's scenes are lit; in the dark this floor acts as a larger log offset.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Dict, Optional, Tuple

import torch
from jaxtyping import Float
from torch import Tensor, nn

from agrinerf_ns.model.losses import LUMA_WEIGHTS

IDENTITY_FIT_STEPS = 3000
"""Adam steps of the identity fit (EvDeblurNeRF's ``init_identity``)."""
IDENTITY_FIT_SEED = 42
"""Seed of the identity fit's inputs and of the MLP's initial weights (a stream of its own: building the response
leaves the global random stream as it was)."""


class EventCRF(nn.Module):
    """The learnt event response: linear RGB [n, k, 3] and per-sample features [n, f] -> responded RGB [n, k, 3]."""

    def __init__(self, extra_features: int = 2, width: int = 16) -> None:
        super().__init__()
        self.extra_features = extra_features
        self.mlp = nn.Sequential(
            nn.Linear(1 + extra_features, width),
            nn.ReLU(),
            nn.Linear(width, width),
            nn.ReLU(),
            nn.Linear(width, width),
            nn.ReLU(),
            nn.Linear(width, 1),
        )
        self.mlp.load_state_dict(_identity_fit(extra_features, width))

    def forward(
        self, linear: Float[Tensor, "n k 3"], features: Optional[Float[Tensor, "n f"]] = None
    ) -> Float[Tensor, "n k 3"]:
        n, k, c = linear.shape
        x = linear.float().reshape(n, k * c, 1)
        feats = linear.new_zeros(n, self.extra_features) if features is None else features.to(linear)
        inputs = torch.cat([x, feats[:, None, :].expand(n, k * c, self.extra_features)], dim=-1)
        return torch.sigmoid(x + 0.1 * self.mlp(inputs)).reshape(n, k, c)


@lru_cache(maxsize=4)
def _identity_fit_cached(extra_features: int, width: int) -> Tuple[Tuple[str, Tensor], ...]:
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(IDENTITY_FIT_SEED)
        mlp = nn.Sequential(
            nn.Linear(1 + extra_features, width),
            nn.ReLU(),
            nn.Linear(width, width),
            nn.ReLU(),
            nn.Linear(width, width),
            nn.ReLU(),
            nn.Linear(width, 1),
        )
        optimizer = torch.optim.Adam(mlp.parameters(), lr=1e-2)
        zeros = torch.zeros(64 * 3, extra_features)  # cpu: fitted once at construction, before the model moves
        for _ in range(IDENTITY_FIT_STEPS):
            x = torch.rand(64 * 3, 1)  # cpu: as above
            y = torch.sigmoid(x + 0.1 * mlp(torch.cat([x, zeros], dim=-1)))
            loss = (y - x).pow(2).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    return tuple((name, value.detach().clone()) for name, value in mlp.state_dict().items())


def _identity_fit(extra_features: int, width: int) -> Dict[str, Tensor]:
    """The MLP's weights after the identity fit (computed once per process: deterministic)."""
    return {name: value.clone() for name, value in _identity_fit_cached(extra_features, width)}


def event_log_luma(
    linear: Float[Tensor, "n k 3"],
    eps: float,
    crf: Optional[EventCRF] = None,
    features: Optional[Float[Tensor, "n f"]] = None,
) -> Float[Tensor, "n k 1"]:
    """EvDeblurNeRF's event-camera response of linear RGB: log(BT.601 luma of crf(linear) + eps) (no `crf`: of the
    linear colour itself, the response before its start step)."""
    responded = linear.float() if crf is None else crf(linear, features)
    weights = torch.tensor(LUMA_WEIGHTS, dtype=torch.float32, device=linear.device)
    return torch.log((responded * weights).sum(dim=-1, keepdim=True) + eps)
