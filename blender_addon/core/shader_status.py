"""Which shader renders a Woven Fabric material with the scene's render settings (no bpy).

The node group switches by itself (scene/node_group.py): the fitted OSL shader where Open Shading
Language runs, which is Cycles on the CPU and Cycles on OptiX GPUs with the scene's "Open Shading
Language" option on; the approximate standard-node fallback everywhere else (EEVEE, Cycles with OSL
off, Cycles on CUDA, HIP, Metal or oneAPI GPUs). The panel shows :func:`shader_status`'s text and,
where turning OSL on would give the fitted shader, a button that does it.
"""
from __future__ import annotations

from dataclasses import dataclass

OSL_GPU_BACKENDS = ("OPTIX",)  # GPU backends of Cycles that run OSL


@dataclass(frozen=True)
class ShaderStatus:
    osl: bool            # the fitted OSL shader renders
    text: str            # one line for the panel
    can_enable_osl: bool  # turning the scene's OSL option on would give the fitted shader


def shader_status(engine: str, osl_enabled: bool = False, device: str = "CPU",
                  gpu_backend: str = "NONE") -> ShaderStatus:
    """``engine``: scene.render.engine; ``osl_enabled``: scene.cycles.shading_system; ``device``:
    scene.cycles.device (CPU or GPU); ``gpu_backend``: Cycles' compute device type (NONE, CUDA,
    OPTIX, HIP, METAL, ONEAPI)."""
    if engine != "CYCLES":
        name = "EEVEE" if engine.startswith("BLENDER_EEVEE") else engine.replace("BLENDER_", "").title()
        return ShaderStatus(False, f"{name} renders the approximate fallback (standard nodes); "
                                   "Cycles with OSL renders the fitted shader", False)
    on_gpu = device == "GPU" and gpu_backend not in ("", "NONE")
    where = f"{gpu_backend.title() if gpu_backend != 'OPTIX' else 'OptiX'} GPU" if on_gpu else "CPU"
    if on_gpu and gpu_backend not in OSL_GPU_BACKENDS:
        return ShaderStatus(False, f"Cycles on a {where} renders the approximate fallback: OSL runs only "
                                   "on the CPU and OptiX", False)
    if not osl_enabled:
        return ShaderStatus(False, f"Cycles ({where}) renders the approximate fallback: Open Shading "
                                   "Language is off", True)
    return ShaderStatus(True, f"Cycles ({where}, OSL) renders the fitted OSL shader", False)
