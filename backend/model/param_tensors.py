"""Fabric parameters as torch tensors, for rendering and optimisation.

Shapes follow the declaration in :mod:`backend.core.params`: a per-yarn value is a tensor of shape (2,)
(warp, weft), an RGB value (3,), a per-yarn RGB value (2, 3), a scalar (). Clamping uses the
declared ranges, so the optimiser, the JSON form and the Blender sockets agree by construction.
"""
from __future__ import annotations

from typing import Iterable

import torch

from ..core.params import PARAMETERS, SPECS, FabricParams, ParamError


def as_float(value: float | torch.Tensor) -> float:
    """A number that may be a 0-d tensor (one that carries a graph included: detached first), as a float."""
    return float(value.detach()) if isinstance(value, torch.Tensor) else float(value)


class ParamTensors:
    """The tensors of one FabricParams plus its (non-tensor) weave."""

    def __init__(self, pattern: str, weave, values: dict[str, torch.Tensor]):
        self.pattern = pattern
        self.weave = weave
        self.values = values

    @classmethod
    def from_params(cls, params: FabricParams, device="cpu", dtype=torch.float32,
                    requires_grad: Iterable[str] = ()) -> "ParamTensors":
        wanted = set(requires_grad)
        unknown = wanted - set(SPECS)
        if unknown:
            raise ParamError(f"unknown parameter(s) to optimise: {', '.join(sorted(unknown))}")
        values = {}
        for spec in PARAMETERS:
            t = torch.tensor(getattr(params, spec.name), dtype=dtype, device=device)
            values[spec.name] = t.requires_grad_(spec.name in wanted)
        return cls(params.pattern, params.weave, values)

    def __getattr__(self, name: str) -> torch.Tensor:
        values = self.__dict__.get("values")
        if values is not None and name in values:
            return values[name]
        raise AttributeError(name)

    def scalar(self, name: str) -> tuple[float, ...] | float:
        """Detached Python value(s) of a parameter (for the non-differentiable lookups)."""
        t = self.values[name].detach().cpu()
        return tuple(t.tolist()) if t.ndim else float(t)

    def to_params(self) -> FabricParams:
        """Back to a validated FabricParams (clamped into range)."""
        values = {name: t.detach().cpu().tolist() for name, t in self.values.items()}
        return FabricParams.clamped_from(pattern=self.pattern, weave=self.weave, **values)

    @torch.no_grad()
    def clamp_(self) -> "ParamTensors":
        """Clamps every tensor into its declared range, in place (after an optimiser step)."""
        for name, t in self.values.items():
            spec = SPECS[name]
            t.clamp_(spec.lo, spec.hi)
        return self

    def parameters(self, names: Iterable[str]) -> list[torch.Tensor]:
        return [self.values[n] for n in names]

    def with_values(self, **changes) -> "ParamTensors":
        """A shallow copy with some tensors replaced (others shared)."""
        values = dict(self.values)
        for name, value in changes.items():
            if name not in SPECS:
                raise ParamError(f"{name}: unknown parameter")
            values[name] = value
        return ParamTensors(self.pattern, self.weave, values)
