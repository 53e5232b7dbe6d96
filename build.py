"""Builds the installable Blender extension zips: the add-on with the backend and the shader inside,
and for an artist's platform the backend's Python packages too.

    python build.py [--out DIR]                       # the plain zip (no wheels; any platform)
    python build.py --platform linux-x64|windows-x64|macos-arm64|macos-x64|all
                    [--out DIR] [--wheels DIR] [--refresh]

Layout of a zip (what Blender's "Install from Disk" expects of an extension)::

    blender_manifest.toml  __init__.py  ...the add-on's modules...
    backend/               the Python package the add-on runs as a subprocess
    shaders/               woven_fabric.osl
    wheels/                (platform zips) the backend's runtime dependencies and pip

The plain zip is ``<id>-<version>.zip`` and needs a Python with PyTorch set in the add-on's
preferences. A platform zip is ``<id>-<version>-<platform>.zip``: its manifest adds
``platforms = [<platform>]`` and ``wheels = [...]``, and Blender installs those wheels into the
extensions' site-packages, where the add-on's bundled backend finds them (backend_setup.py).
The wheels are backend/core/dependencies.py's ``RUNTIME`` requirements (PyTorch's CPU build:
for Linux ``+cpu``, never the CUDA build; PyPI's Windows and macOS builds are CPU/MPS ones) and
``INSTALLER`` (pip, for the add-on's GPU route), with their own dependencies for Blender's Python
3.11 on that platform: the environment markers are evaluated for the target, not this machine.

Wheels are cached outside the repository (``--wheels``, else ``$WOVEN_FABRIC_WHEELS``, else
``~/.cache/woven_fabric/wheels``); a wheel already there that satisfies a requirement is used
without asking an index (``--refresh`` asks again). Missing ones come from pip's configured
indexes and find-links (``pip download``), and Linux's CPU PyTorch, if not found there, from
PyTorch's CPU index.

Whole folders are bundled: the add-on, ``backend/`` and ``shaders/``; the developer tools live in
``devtools/`` beside them and never ship. Caches, compiled files and tests are left out. Entries
are sorted and time-stamped alike so that two builds of the same tree (and wheels) are identical.

(No ``from __future__ import annotations``: the tests load this file without registering it as a
module, and dataclasses with string annotations need that.)
"""
import argparse
import os
import subprocess
import sys
import tomllib
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent
ADDON = ROOT / "blender_addon"
BUNDLED = ("backend", "shaders")
SKIPPED_DIRS = {"__pycache__", ".pytest_cache", "tests"}
SKIPPED_SUFFIXES = {".pyc", ".pyo", ".blend1"}
# Without these the add-on installs but cannot make materials: the build warns (a test fails).
EXPECTED = ("shaders/woven_fabric.osl", "scene/node_group.py")
FIXED_TIME = (2024, 1, 1, 0, 0, 0)
WHEELS_FOLDER = "wheels"
PYTHON = (3, 11)           # Blender 4.2 to 5.0 bundle Python 3.11
PYTHON_FULL = "3.11.13"    # for python_full_version markers (Blender 5.0's)
TORCH_CPU_INDEX = "https://download.pytorch.org/whl/cpu"


class BuildError(Exception):
    """A platform zip cannot be built; the message says why (no traceback for the user)."""


@dataclass(frozen=True)
class Target:
    """A platform Blender installs extensions for, as pip and the wheels' markers see it."""

    name: str                       # Blender's manifest value: linux-x64, windows-x64, ...
    wheel_platforms: tuple[str, ...]  # pip's --platform values (wheel platform tags), best first
    markers: dict = field(hash=False)  # PEP 508 environment markers that differ between platforms
    torch_local: str = ""           # PyTorch's local version label of the CPU build ("cpu"), if any
    unavailable: str = ""           # why no zip can be built, if none can

    def environment(self, extra: str = "") -> dict:
        return {"python_version": "%d.%d" % PYTHON, "python_full_version": PYTHON_FULL,
                "implementation_name": "cpython", "platform_python_implementation": "CPython",
                "implementation_version": PYTHON_FULL, "platform_release": "", "platform_version": "",
                "extra": extra, **self.markers}

    @property
    def zip_suffix(self) -> str:
        return self.name.replace("-", "_")


_LINUX = {"sys_platform": "linux", "platform_system": "Linux", "os_name": "posix", "platform_machine": "x86_64"}
_MACOS = {"sys_platform": "darwin", "platform_system": "Darwin", "os_name": "posix"}
TARGETS = {
    # Blender 4.2+ needs glibc 2.28 (the VFX reference platform): manylinux_2_28 and older tags.
    "linux-x64": Target("linux-x64", tuple(f"manylinux_2_{minor}_x86_64" for minor in range(28, 16, -1))
                        + ("manylinux2014_x86_64",), _LINUX, torch_local="cpu"),
    "windows-x64": Target("windows-x64", ("win_amd64",),
                          {"sys_platform": "win32", "platform_system": "Windows", "os_name": "nt",
                           "platform_machine": "AMD64"}),
    # PyTorch 2.13's macOS wheels are tagged macosx_14_0_arm64: they need macOS 14 (Sonoma) or newer.
    "macos-arm64": Target("macos-arm64", tuple(f"macosx_{major}_0_arm64" for major in range(14, 10, -1)),
                          {**_MACOS, "platform_machine": "arm64"}),
    "macos-x64": Target("macos-x64", tuple(f"macosx_{major}_0_x86_64" for major in range(14, 10, -1))
                        + tuple(f"macosx_10_{minor}_x86_64" for minor in range(16, 8, -1)),
                        {**_MACOS, "platform_machine": "x86_64"},
                        unavailable="PyTorch publishes no wheel of 2.13 for Intel Macs (its last x86_64 macOS "
                                    "wheels are 2.2.x, which this backend is not tested with); install the plain "
                                    "zip and set an external Python with PyTorch in the add-on's preferences"),
}
ALL = "all"


def manifest() -> dict:
    with open(ADDON / "blender_manifest.toml", "rb") as fh:
        return tomllib.load(fh)


def _files(folder: Path):
    for path in sorted(folder.rglob("*")):
        relative = path.relative_to(folder)
        if path.is_file() and not SKIPPED_DIRS.intersection(relative.parts[:-1]) \
                and path.suffix not in SKIPPED_SUFFIXES and path.name not in SKIPPED_DIRS:
            yield path, relative


def entries() -> list[tuple[Path, str]]:
    """(source file, name in the zip) for everything the extension contains."""
    found = [(path, relative.as_posix()) for path, relative in _files(ADDON)]
    for name in BUNDLED:
        folder = ROOT / name
        if folder.is_dir():
            found += [(path, f"{name}/{relative.as_posix()}") for path, relative in _files(folder)]
    if not any(name == "backend/__init__.py" for _, name in found):
        raise SystemExit(f"build.py: {ROOT / 'backend'} is missing")
    names = {name for _, name in found}
    for name in EXPECTED:
        if name not in names:
            print(f"build.py: warning: {name} is missing; the extension cannot make materials without it",
                  file=sys.stderr)
    return found


def build(out_dir: Path, target: Target | None = None, wheels: list[Path] = ()) -> Path:
    """Writes the zip: the plain one (``target`` None), else ``target``'s with ``wheels`` inside."""
    info = manifest()
    backend_version = _backend_version()
    if backend_version and backend_version != info["version"]:
        print(f"build.py: note: manifest version {info['version']} differs from backend {backend_version}",
              file=sys.stderr)
    out_dir.mkdir(parents=True, exist_ok=True)
    suffix = f"-{target.zip_suffix}" if target is not None else ""
    target_path = out_dir / f"{info['id']}-{info['version']}{suffix}.zip"
    temporary = target_path.with_suffix(".zip.part")
    files = entries()
    generated = {}
    if target is not None:
        wheel_names = [f"{WHEELS_FOLDER}/{wheel.name}" for wheel in sorted(wheels, key=lambda p: p.name)]
        generated["blender_manifest.toml"] = platform_manifest(target.name, wheel_names).encode()
        files += [(wheel, f"{WHEELS_FOLDER}/{wheel.name}") for wheel in wheels]
    with zipfile.ZipFile(temporary, "w") as archive:
        for path, name in sorted(files, key=lambda item: item[1]):
            entry = zipfile.ZipInfo(name, FIXED_TIME)
            # A wheel is a zip already: storing it costs nothing in size and saves the compression time.
            entry.compress_type = zipfile.ZIP_STORED if name.endswith(".whl") else zipfile.ZIP_DEFLATED
            entry.external_attr = 0o644 << 16
            archive.writestr(entry, generated.get(name) or path.read_bytes())
    temporary.replace(target_path)
    return target_path


def platform_manifest(platform: str, wheel_names: list[str]) -> str:
    """The source manifest with ``platforms`` and ``wheels`` added (top-level keys: before any table)."""
    text = (ADDON / "blender_manifest.toml").read_text()
    lines = text.splitlines(keepends=True)
    first_table = next((i for i, line in enumerate(lines) if line.lstrip().startswith("[")), len(lines))
    added = [f'platforms = ["{platform}"]\n', "# Installed by Blender into the extensions' site-packages; "
             "the bundled backend imports them from there.\n", "wheels = [\n",
             *(f'    "./{name}",\n' for name in wheel_names), "]\n\n"]
    result = "".join(lines[:first_table] + added + lines[first_table:])
    parsed = tomllib.loads(result)
    if parsed.get("platforms") != [platform] or len(parsed.get("wheels", ())) != len(wheel_names):
        raise BuildError(f"{ADDON / 'blender_manifest.toml'}: platforms and wheels could not be added")
    return result


def _backend_version() -> str:
    for line in (ROOT / "backend" / "__init__.py").read_text().splitlines():
        if line.startswith("__version__"):
            return line.split("=", 1)[1].strip().strip("\"'")
    return ""


# -- the wheels of a platform ---------------------------------------------------------------------

def default_wheel_cache() -> Path:
    return Path(os.environ.get("WOVEN_FABRIC_WHEELS") or Path.home() / ".cache" / "woven_fabric" / "wheels")


def requirements(target: Target) -> list[str]:
    """What a platform zip bundles: the backend's runtime dependencies and pip (dependencies.py)."""
    sys.path.insert(0, str(ROOT))
    try:
        from backend.core.dependencies import INSTALLER, RUNTIME, TORCH
    finally:
        sys.path.remove(str(ROOT))
    wanted = []
    for dependency in (*RUNTIME, INSTALLER):
        requirement = dependency.requirement
        if dependency is TORCH and target.torch_local:
            requirement = f"{requirement}+{target.torch_local}"  # the CPU build, never the CUDA one
        wanted.append(requirement)
    return wanted


class WheelSet:
    """The wheels of one platform: the closure of :func:`requirements` under the wheels' own
    ``Requires-Dist`` with the target's markers, one wheel per project, found in ``cache`` or
    downloaded into it. The resolution is greedy (the newest wheel that satisfies every
    requirement seen so far, chosen again when a later one excludes it), enough for these pins."""

    def __init__(self, target: Target, cache: Path, refresh: bool = False, log=print):
        from packaging import tags  # the build's own tool (the test extra); the add-on never needs it
        self.target, self.cache, self.refresh, self.log = target, cache, refresh, log
        self.supported = set(tags.cpython_tags(PYTHON, abis=[f"cp{PYTHON[0]}{PYTHON[1]}", "abi3", "none"],
                                               platforms=target.wheel_platforms))
        self.supported |= set(tags.compatible_tags(PYTHON, f"cp{PYTHON[0]}{PYTHON[1]}", target.wheel_platforms))
        self.downloads: list[str] = []

    def resolve(self) -> list[Path]:
        from packaging.requirements import Requirement
        from packaging.specifiers import SpecifierSet
        from packaging.utils import canonicalize_name

        if self.target.unavailable:
            raise BuildError(f"{self.target.name}: no zip: {self.target.unavailable}")
        pending = [Requirement(text) for text in requirements(self.target)]
        specifiers: dict[str, SpecifierSet] = {}
        extras: dict[str, set[str]] = {}
        chosen: dict[str, Path] = {}
        while pending:
            requirement = pending.pop(0)
            name = canonicalize_name(requirement.name)
            specifiers[name] = specifiers.get(name, SpecifierSet()) & requirement.specifier
            new_extras = set(requirement.extras) - extras.setdefault(name, set())
            extras[name] |= new_extras
            current = chosen.get(name)
            if current is not None and not new_extras and \
                    specifiers[name].contains(self._version(current), prereleases=True):
                continue
            wheel = self._find(name, specifiers[name])
            chosen[name] = wheel
            pending += self._dependencies(wheel, extras[name])
        return [chosen[name] for name in sorted(chosen)]

    # -- one project ------------------------------------------------------------------------------
    def _candidates(self, name: str, specifier) -> list[tuple]:
        from packaging.utils import InvalidWheelFilename, canonicalize_name, parse_wheel_filename

        found = []
        for path in self.cache.glob("*.whl") if self.cache.is_dir() else ():
            try:
                project, version, _, wheel_tags = parse_wheel_filename(path.name)
            except InvalidWheelFilename:
                continue
            if canonicalize_name(project) == name and wheel_tags & self.supported \
                    and specifier.contains(version, prereleases=True):
                found.append((version, path.name, path))
        return sorted(found)

    def _find(self, name: str, specifier) -> Path:
        cached = [] if self.refresh else self._candidates(name, specifier)
        if not cached:
            self._download(name, specifier)
            cached = self._candidates(name, specifier)
        if not cached:
            raise BuildError(f"{self.target.name}: no wheel of {name}{specifier} for Python 3.11 on "
                             f"{self.target.name} (tried pip's indexes and find-links: pip download said "
                             f"{self._last_error.strip().splitlines()[-1:] or 'nothing'})")
        return cached[-1][2]

    _last_error = ""

    def _download(self, name: str, specifier) -> None:
        self.cache.mkdir(parents=True, exist_ok=True)
        command = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary", ":all:",
                   "--python-version", "%d.%d" % PYTHON, "--implementation", "cp", "--dest", str(self.cache),
                   "--progress-bar", "off", "--disable-pip-version-check"]
        for platform in self.target.wheel_platforms:
            command += ["--platform", platform]
        indexes = [[]]
        if name == "torch" and self.target.torch_local:
            indexes.append(["--index-url", TORCH_CPU_INDEX])  # only when pip's own sources lack the CPU build
        for index in indexes:
            self.log(f"build.py: {self.target.name}: downloading {name}{specifier}"
                     + (f" from {index[1]}" if index else ""))
            done = subprocess.run([*command, *index, f"{name}{specifier}"], capture_output=True, text=True)
            self.downloads.append(f"{name}{specifier}")
            if done.returncode == 0:
                return
            self._last_error = done.stderr or done.stdout

    def _version(self, wheel: Path):
        from packaging.utils import parse_wheel_filename
        return parse_wheel_filename(wheel.name)[1]

    def _dependencies(self, wheel: Path, extras: set[str]) -> list:
        """The wheel's ``Requires-Dist`` that apply on the target (markers evaluated for it)."""
        from packaging.requirements import Requirement

        with zipfile.ZipFile(wheel) as archive:
            name = next(n for n in archive.namelist() if n.count("/") == 1 and n.endswith(".dist-info/METADATA"))
            metadata = archive.read(name).decode("utf-8", "replace")
        wanted = []
        for line in metadata.split("\n\n", 1)[0].splitlines():
            if not line.startswith("Requires-Dist:"):
                continue
            requirement = Requirement(line.split(":", 1)[1].strip())
            if requirement.marker is None or any(requirement.marker.evaluate(self.target.environment(extra))
                                                 for extra in ("", *sorted(extras))):
                requirement.marker = None
                wanted.append(requirement)
        return wanted


def build_platform(name: str, out_dir: Path, cache: Path | None = None, refresh: bool = False,
                   log=print) -> Path:
    """The zip of one platform (wheels found or downloaded first); BuildError if it cannot be built."""
    if name not in TARGETS:
        raise BuildError(f"unknown platform {name!r}; expected one of {', '.join(TARGETS)} or {ALL}")
    target = TARGETS[name]
    wheels = WheelSet(target, cache or default_wheel_cache(), refresh, log).resolve()
    return build(out_dir, target, wheels)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Build the Woven Fabric Capture extension zip(s).")
    parser.add_argument("--out", type=Path, default=ROOT / "dist", help="output folder (default: dist/)")
    parser.add_argument("--platform", choices=(*TARGETS, ALL),
                        help="build the zip of a platform with the backend's packages inside (default: the plain "
                             "zip without them)")
    parser.add_argument("--wheels", type=Path, help="the wheel cache (default: $WOVEN_FABRIC_WHEELS, else "
                                                    "~/.cache/woven_fabric/wheels)")
    parser.add_argument("--refresh", action="store_true", help="ask the indexes again instead of using cached wheels")
    args = parser.parse_args(argv)
    out = args.out.resolve()
    if args.platform is None:
        print(build(out))
        return 0
    names = list(TARGETS) if args.platform == ALL else [args.platform]
    failed = 0
    for name in names:
        try:
            path = build_platform(name, out, args.wheels, args.refresh, log=lambda text: print(text, file=sys.stderr))
        except BuildError as exc:
            print(f"build.py: {exc}", file=sys.stderr)
            # "all" builds what exists: a platform without PyTorch wheels is reported, not an error.
            failed += not (args.platform == ALL and TARGETS[name].unavailable)
            continue
        print(f"{path}\t{path.stat().st_size / 2**20:.1f} MiB")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
