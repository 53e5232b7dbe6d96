"""Model variants (the ablations of spec section 4 and the golden cases' ``flags``)."""
from __future__ import annotations

from dataclasses import dataclass, fields


class OptionsError(ValueError):
    pass


@dataclass(frozen=True)
class RenderOptions:
    """diffuse: the diffuse term; glow: the out-of-focus back light through gaps;
    multiple_lobe: 'asggx' (the paper's) or 'sggx' (ablation); layers: 2 or 1 (front only);
    tension: tension-aware thickness; vignette: the vignetting mask."""

    diffuse: bool = True
    glow: bool = True
    multiple_lobe: str = "asggx"
    layers: int = 2
    tension: bool = True
    vignette: bool = True

    def __post_init__(self):
        if self.multiple_lobe not in ("asggx", "sggx"):
            raise OptionsError(f"multiple_lobe: expected 'asggx' or 'sggx', got {self.multiple_lobe!r}")
        if self.layers not in (1, 2):
            raise OptionsError(f"layers: expected 1 or 2, got {self.layers!r}")
        for name in ("diffuse", "glow", "tension", "vignette"):
            if not isinstance(getattr(self, name), bool):
                raise OptionsError(f"{name}: expected true or false, got {getattr(self, name)!r}")

    @classmethod
    def from_flags(cls, flags: dict | None) -> "RenderOptions":
        """Options from a golden case's ``flags`` (absent keys keep the full model)."""
        flags = flags or {}
        known = {f.name for f in fields(cls)}
        unknown = set(flags) - known
        if unknown:
            raise OptionsError(f"unknown flag(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(known))}")
        return cls(**flags)
