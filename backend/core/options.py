"""Model variants: the ablations of spec section 4, as the golden cases' ``flags`` name them.

    ================  ===============  =====================================================
    diffuse           bool (true)      the diffuse term
    glow              bool (true)      the out-of-focus back light seen through the gaps
    multiple_lobe     'asggx'          the multiple-scattering lobe: 'asggx' (the paper's)
                                       or 'sggx' (the single-scattering lobe's shape)
    layers            2                2, or 1 (the front layer only)
    tension           bool (true)      tension-aware yarn thickness (spec 3.4)
    vignette          bool (true)      the vignetting mask
    ================  ===============  =====================================================
"""
from __future__ import annotations

from dataclasses import dataclass, fields


class OptionsError(ValueError):
    """An option or flag is unknown or out of range; the message names it."""


@dataclass(frozen=True)
class RenderOptions:
    """Which parts of the model a render includes (the module docstring's table); the defaults are
    the full model."""

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
