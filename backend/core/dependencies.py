"""The backend's runtime dependencies, declared once (plain Python: the add-on and build.py read it).

:data:`RUNTIME` is what the fit command imports at run time, in the order of pyproject.toml's
``[project] dependencies`` (tests/test_bundle.py keeps the two equal). Three readers:

- ``build.py --platform`` bundles these requirements (and their own dependencies) as wheels
  into the extension zip of a platform;
- the add-on's *Check Backend* imports every ``module`` in the backend's interpreter and says,
  with the ``label`` and ``role``, what is missing;
- the add-on's GPU route installs :data:`RUNTIME`'s PyTorch version from a CUDA package index.

:data:`INSTALLER` is not the backend's: the bundled zips carry pip so that the GPU route can
install a CUDA build of PyTorch with Blender's own Python, which need not have pip.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Dependency:
    requirement: str  # PEP 508, exactly as pyproject.toml has it
    module: str       # the name the backend imports
    label: str        # the name people know it by
    role: str         # what the backend needs it for, as a clause after "it"

    @property
    def project(self) -> str:
        """The distribution's name: ``opencv-python-headless>=4.8`` -> ``opencv-python-headless``."""
        for index, char in enumerate(self.requirement):
            if not (char.isalnum() or char in "-_."):
                return self.requirement[:index]
        return self.requirement


RUNTIME = (
    Dependency("torch==2.13.0", "torch", "PyTorch", "renders and fits the fabric model"),
    Dependency("numpy>=1.26,<2", "numpy", "NumPy", "holds the photos and renders"),
    Dependency("opencv-python-headless>=4.8,<4.11", "cv2", "OpenCV", "reads, resizes and writes the images"),
    Dependency("rawpy>=0.19", "rawpy", "rawpy", "reads camera RAW photos"),
    Dependency("flip-evaluator>=1.6", "flip_evaluator", "FLIP", "measures the fit's error for its report"),
)

TORCH = RUNTIME[0]

INSTALLER = Dependency("pip>=24.1", "pip", "pip", "installs the optional CUDA build of PyTorch")
