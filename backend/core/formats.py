"""Photo file formats the backend reads, by file suffix (plain Python: the add-on reads them too).

- :data:`ENCODED_SUFFIXES`: PNG, JPEG and TIFF (8/16-bit, display encoded; float TIFF is linear) and
  OpenEXR (linear), recognised by their content, the suffix only picks files in folders;
- :data:`RAW_SUFFIXES`: camera RAW files, recognised by suffix alone and decoded by LibRaw (rawpy);
- :data:`PHOTO_SUFFIXES`: both, the files a folder of photo pairs is searched for.
"""
from __future__ import annotations

ENCODED_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr")
RAW_SUFFIXES = (".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".orf", ".rw2", ".raf",
                ".pef", ".srw", ".3fr", ".iiq", ".erf", ".kdc", ".dcr", ".mrw", ".x3f", ".raw", ".rwl", ".mos",
                ".mef")
PHOTO_SUFFIXES = ENCODED_SUFFIXES + RAW_SUFFIXES


def is_raw(suffix: str) -> bool:
    """Whether a file suffix (with its dot, any case) names a camera RAW file."""
    return suffix.lower() in RAW_SUFFIXES
