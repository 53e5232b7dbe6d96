"""Builds the installable Blender extension zip: the add-on with the backend and the shader inside.

    python build.py [--out DIR]        # default DIR: dist/; prints the zip's path

Layout of the zip (what Blender's "Install from Disk" expects of an extension)::

    blender_manifest.toml  __init__.py  ...the add-on's modules...
    backend/               the Python package the add-on runs as a subprocess
    shaders/               woven_fabric.osl

Only what runs in the add-on is bundled: the backend's development tools (benchmarks, the network's
dataset and training, their commands; :data:`DEVELOPMENT_ONLY`) are left out, and so are caches,
compiled files and tests. The zip is named ``<id>-<version>.zip`` from the manifest; entries are
sorted and time-stamped alike so that two builds of the same tree are identical.
"""
from __future__ import annotations

import argparse
import sys
import tomllib
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent
ADDON = ROOT / "blender_addon"
BUNDLED = ("backend", "shaders")
SKIPPED_DIRS = {"__pycache__", ".pytest_cache", "tests"}
SKIPPED_SUFFIXES = {".pyc", ".pyo", ".blend1"}
# Development tools of the backend (paths in the zip; a folder ends with "/"): the command line lists
# a development command only where its module is present (backend/cli/main.py).
DEVELOPMENT_ONLY = ("backend/bench/", "backend/init/dataset.py", "backend/init/train.py",
                    "backend/cli/bench.py", "backend/cli/dataset.py", "backend/cli/train.py",
                    "backend/cli/evaluate_init.py",
                    "backend/batch/", "backend/cli/batch.py")  # the batch runs on Ray, which the add-on lacks
# Without these the add-on installs but cannot make materials: the build warns (a test fails).
EXPECTED = ("shaders/woven_fabric.osl", "scene/node_group.py")
FIXED_TIME = (2024, 1, 1, 0, 0, 0)


def manifest() -> dict:
    with open(ADDON / "blender_manifest.toml", "rb") as fh:
        return tomllib.load(fh)


def _files(folder: Path):
    for path in sorted(folder.rglob("*")):
        relative = path.relative_to(folder)
        if path.is_file() and not SKIPPED_DIRS.intersection(relative.parts[:-1]) \
                and path.suffix not in SKIPPED_SUFFIXES and path.name not in SKIPPED_DIRS:
            yield path, relative


def _development_only(name: str) -> bool:
    return any(name.startswith(entry) if entry.endswith("/") else name == entry for entry in DEVELOPMENT_ONLY)


def entries() -> list[tuple[Path, str]]:
    """(source file, name in the zip) for everything the extension contains."""
    found = [(path, relative.as_posix()) for path, relative in _files(ADDON)]
    for name in BUNDLED:
        folder = ROOT / name
        if folder.is_dir():
            found += [(path, f"{name}/{relative.as_posix()}") for path, relative in _files(folder)
                      if not _development_only(f"{name}/{relative.as_posix()}")]
    if not any(name == "backend/__init__.py" for _, name in found):
        raise SystemExit(f"build.py: {ROOT / 'backend'} is missing")
    names = {name for _, name in found}
    for name in EXPECTED:
        if name not in names:
            print(f"build.py: warning: {name} is missing; the extension cannot make materials without it",
                  file=sys.stderr)
    return found


def build(out_dir: Path) -> Path:
    info = manifest()
    backend_version = _backend_version()
    if backend_version and backend_version != info["version"]:
        print(f"build.py: note: manifest version {info['version']} differs from backend {backend_version}",
              file=sys.stderr)
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / f"{info['id']}-{info['version']}.zip"
    temporary = target.with_suffix(".zip.part")
    with zipfile.ZipFile(temporary, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for path, name in entries():
            entry = zipfile.ZipInfo(name, FIXED_TIME)
            entry.compress_type = zipfile.ZIP_DEFLATED
            entry.external_attr = 0o644 << 16
            archive.writestr(entry, path.read_bytes())
    temporary.replace(target)
    return target


def _backend_version() -> str:
    for line in (ROOT / "backend" / "__init__.py").read_text().splitlines():
        if line.startswith("__version__"):
            return line.split("=", 1)[1].strip().strip("\"'")
    return ""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Build the Woven Fabric Capture extension zip.")
    parser.add_argument("--out", type=Path, default=ROOT / "dist", help="output folder (default: dist/)")
    args = parser.parse_args(argv)
    print(build(args.out.resolve()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
