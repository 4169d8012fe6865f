"""The one min-max scaler (MATLAB ``mapminmax``): each column onto [-1, 1] over the fit data."""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class MinMax:
    """Column-wise ``x -> 2 (x - lo) / (hi - lo) - 1``. A constant column (``hi - lo`` below
    ``1e-12``, e.g. a locked joint) maps to exactly 0 and back to its value: no division by zero."""

    lo: torch.Tensor
    hi: torch.Tensor

    @classmethod
    def fit(cls, data: torch.Tensor) -> MinMax:
        return cls(data.min(dim=0).values, data.max(dim=0).values)

    @property
    def flat(self) -> torch.Tensor:
        return (self.hi - self.lo) < 1e-12

    @property
    def span(self) -> torch.Tensor:
        return torch.where(self.flat, torch.ones_like(self.hi), self.hi - self.lo)

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        return self.forward(x)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = 2 * (x - self.lo) / self.span - 1
        return torch.where(self.flat, torch.zeros_like(y), y)

    def inverse(self, y: torch.Tensor) -> torch.Tensor:
        x = self.lo + (y + 1) * self.span / 2
        return torch.where(self.flat, self.lo.expand_as(x), x)
