"""Woven fabric capture backend: forward model, fitting and tools (never imports bpy)."""

__version__ = "0.1.0"
