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
        # name -> (tensor, its version, its values as a flat list): host copies of the values read last
        self._host: dict[str, tuple[torch.Tensor, int, list[float]]] = {}

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

    def host(self, names: Iterable[str] | None = None) -> dict[str, list[float]]:
        """The values of some parameters (None: all) as flat lists of Python floats.

        On a GPU every read of a value is a wait for the device, so a value is copied to the host
        only where its tensor changed since it was last read here (its version counter moves with
        every in-place change: an optimiser step, a ``copy_``, an item set), and the values that
        did change come over in one copy. A render reads the discrete parameters (tiles, gap scale,
        twist, noise) on the host at every step; they change only at a discrete search."""
        names = list(self.values) if names is None else list(names)
        stale = []
        for name in names:
            t = self.values[name]
            kept = self._host.get(name)
            if kept is None or kept[0] is not t or kept[1] != t._version:
                stale.append(name)
        if stale:
            tensors = [self.values[n].detach() for n in stale]
            flat = torch.cat([t.reshape(-1) for t in tensors]).cpu().tolist()
            start = 0
            for name, t in zip(stale, tensors):
                self._host[name] = (self.values[name], self.values[name]._version, flat[start:start + t.numel()])
                start += t.numel()
        return {name: self._host[name][2] for name in names}

    def scalar(self, name: str) -> tuple[float, ...] | float:
        """Detached Python value(s) of a parameter (for the non-differentiable lookups)."""
        values = self.host((name,))[name]
        return tuple(values) if self.values[name].ndim else values[0]

    def to_params(self) -> FabricParams:
        """Back to a validated FabricParams (clamped into range)."""
        flat = self.host()
        values = {name: _shaped(flat[name], t.shape) for name, t in self.values.items()}
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


def _shaped(flat: list[float], shape: torch.Size):
    """A flat list of values back in a tensor's shape, as ``tolist()`` gives it (a float for a 0-d one;
    float64 holds the float32 values exactly)."""
    return torch.tensor(flat, dtype=torch.float64).reshape(shape).tolist()
