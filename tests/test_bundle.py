"""The platform zips (build.py --platform) and the bundled backend they install.

The proof of the issue's item 3: the linux-x64 zip, with PyTorch's CPU build and the other runtime
wheels inside, is built, accepted by Blender's validator and installed into bpy with a temporary
``BLENDER_USER_RESOURCES``; then, with no setting touched and no ``WOVEN_FABRIC_*`` variable, the
panel's Fit runs the backend as a subprocess of "Blender's Python" (here the test environment's
interpreter) started isolated (``-S -P``, only the extension and its installed site-packages on
the path): the probe below shows it cannot import pytest or bpy, which this environment has; the
fit's params.json reaches the node group. The same installed extension then runs the GPU route's
install code against the registry, with the CPU build of PyTorch instead of a CUDA one.

The wheels come from the cache (``$WOVEN_FABRIC_WHEELS`` or ``~/.cache/woven_fabric/wheels``); on a
clean machine the first build downloads them through pip's configured indexes and find-links
(about 260 MB; about a minute here), later builds use the cache and ask no index.
"""
from __future__ import annotations

import ast
import importlib.util
import json
import os
import subprocess
import sys
import textwrap
import tomllib
import zipfile
from pathlib import Path

import numpy as np
import pytest
from addon_support import require_bpy, validate_extension
from conftest import ROOT

from backend.core import dependencies
from backend.core.params import FabricParams
from backend.image.png import write_png
from backend.model.render import render_pair

EXTENSION = "bl_ext.user_default.woven_fabric"
PLATFORM = "linux-x64"
TIMEOUT_S = 900  # a liveness bound for a bpy script that fits or installs PyTorch, not a timing


# -- what is declared, and what build.py makes of it ---------------------------------------------------

def test_the_runtime_dependencies_are_pyprojects():
    """One list: backend/core/dependencies.py is what pyproject.toml installs, in the same order."""
    with open(ROOT / "pyproject.toml", "rb") as fh:
        declared = tomllib.load(fh)["project"]["dependencies"]
    assert [d.requirement for d in dependencies.RUNTIME] == declared
    assert [d.project for d in dependencies.RUNTIME] == ["torch", "numpy", "opencv-python-headless", "rawpy",
                                                         "flip-evaluator"]
    assert dependencies.TORCH.requirement == "torch==2.13.0"  # pinned: the GPU route installs the same release
    for dependency in dependencies.RUNTIME:  # each module is what the backend imports
        assert importlib.util.find_spec(dependency.module) is not None, dependency


def _wheel(folder: Path, name: str, version: str, tag: str, requires: list[str]) -> Path:
    path = folder / f"{name}-{version}-{tag}.whl"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr(f"{name}-{version}.dist-info/METADATA", "Metadata-Version: 2.1\nName: {}\nVersion: {}\n{}\n\n"
                         "A description that mentions Requires-Dist: nothing\n".format(
                             name, version, "".join(f"Requires-Dist: {r}\n" for r in requires)))
    return path


def test_wheels_are_resolved_with_the_targets_markers(build_module, tmp_path, monkeypatch):
    """pip's --platform does not change the markers it evaluates; the build evaluates them for the target:
    Linux-only CUDA packages never reach the Windows zip, a Windows-only one never the Linux zip."""
    requires = ['nvidia-cudnn==9.0; platform_system == "Linux"', 'colorama; sys_platform == "win32"', "sympy>=1.13",
                'pyyaml; extra == "yaml"']
    _wheel(tmp_path, "torch", "2.13.0", "cp311-cp311-win_amd64", requires)
    _wheel(tmp_path, "torch", "2.13.0+cpu", "cp311-cp311-manylinux_2_28_x86_64", requires)
    _wheel(tmp_path, "torch", "2.13.0", "cp311-cp311-manylinux_2_28_x86_64", requires)  # PyPI's CUDA build
    _wheel(tmp_path, "sympy", "1.12", "py3-none-any", [])      # too old for torch's requirement
    _wheel(tmp_path, "sympy", "1.14.0", "py3-none-any", ["mpmath<1.4"])
    _wheel(tmp_path, "mpmath", "1.3.0", "py3-none-any", [])
    _wheel(tmp_path, "colorama", "0.4.6", "py2.py3-none-any", [])
    _wheel(tmp_path, "nvidia_cudnn", "9.0", "py3-none-manylinux_2_28_x86_64", [])
    monkeypatch.setattr(build_module, "requirements", lambda target: [
        "torch==2.13.0+cpu" if target.torch_local else "torch==2.13.0"])
    downloads = []
    monkeypatch.setattr(build_module.WheelSet, "_download", lambda self, name, spec: downloads.append(name))
    names = {}
    for platform in ("windows-x64", "linux-x64"):
        wheels = build_module.WheelSet(build_module.TARGETS[platform], tmp_path).resolve()
        names[platform] = [w.name for w in wheels]
    assert names["windows-x64"] == ["colorama-0.4.6-py2.py3-none-any.whl", "mpmath-1.3.0-py3-none-any.whl",
                                    "sympy-1.14.0-py3-none-any.whl", "torch-2.13.0-cp311-cp311-win_amd64.whl"]
    assert names["linux-x64"] == ["mpmath-1.3.0-py3-none-any.whl",
                                  "nvidia_cudnn-9.0-py3-none-manylinux_2_28_x86_64.whl",
                                  "sympy-1.14.0-py3-none-any.whl",
                                  "torch-2.13.0+cpu-cp311-cp311-manylinux_2_28_x86_64.whl"]
    assert downloads == []  # everything was in the cache: no index was asked
    with pytest.raises(build_module.BuildError, match="macos-x64: no zip: PyTorch publishes no wheel of 2.13"):
        build_module.WheelSet(build_module.TARGETS["macos-x64"], tmp_path).resolve()
    with pytest.raises(build_module.BuildError, match="no wheel of torch==2.13.0 for Python 3.11 on macos-arm64"):
        build_module.WheelSet(build_module.TARGETS["macos-arm64"], tmp_path).resolve()
    assert downloads == ["torch"]  # nothing for macOS was cached: it asked pip (here: a stand-in that finds none)


def test_linux_bundles_the_cpu_build_of_torch(build_module):
    for name, target in build_module.TARGETS.items():
        torch = next(r for r in build_module.requirements(target) if r.startswith("torch"))
        assert torch == ("torch==2.13.0+cpu" if name == "linux-x64" else "torch==2.13.0"), name
        assert "pip>=24.1" in build_module.requirements(target)  # the GPU route's installer


def test_the_platform_manifest_adds_platforms_and_wheels_as_top_level_keys(build_module):
    text = build_module.platform_manifest("windows-x64", ["wheels/a-1.0-py3-none-any.whl"])
    manifest = tomllib.loads(text)
    assert manifest["platforms"] == ["windows-x64"] and manifest["wheels"] == ["./wheels/a-1.0-py3-none-any.whl"]
    assert manifest["permissions"] == build_module.manifest()["permissions"]
    assert set(manifest["permissions"]) == {"files", "network"}  # the network: only for the GPU route


# -- every platform: nothing POSIX-only on the fit path -------------------------------------------------

POSIX_ONLY = {"resource", "fcntl", "termios", "tty", "pty", "pwd", "grp", "crypt", "spwd", "syslog", "posix",
              "_posixsubprocess", "readline", "curses", "nis", "ossaudiodev"}


def _guarded(tree: ast.AST, node: ast.AST) -> bool:
    """Whether ``node`` sits in a ``try`` whose handlers catch ImportError (or a parent of it)."""
    for parent in ast.walk(tree):
        if isinstance(parent, ast.Try) and any(node in ast.walk(statement) for statement in parent.body):
            for handler in parent.handlers:
                caught = handler.type if handler.type is not None else ast.Name("BaseException")
                names = [n.id for n in ast.walk(caught) if isinstance(n, ast.Name)]
                if set(names) & {"ImportError", "ModuleNotFoundError", "Exception", "BaseException"}:
                    return True
    return False


def test_the_bundled_backend_imports_no_posix_only_module_unguarded(build_module):
    """What the zips bundle must run on Windows too: a POSIX-only module is imported only inside a try
    that falls back (backend/model/memory.py's ``resource``)."""
    found = []
    for path, name in build_module.entries():
        if not name.endswith(".py"):
            continue
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            modules = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module] if isinstance(node, ast.ImportFrom) and node.module and not node.level else []
            for module in modules:
                if module.split(".")[0] in POSIX_ONLY:
                    found.append((name, module, _guarded(tree, node)))
    assert ("backend/model/memory.py", "resource", True) in found  # the check sees the one there is
    assert [f for f in found if not f[2]] == []


# -- the linux-x64 zip, installed into bpy ---------------------------------------------------------------

def _bpy(script: str, resources: Path, cwd: Path, **env) -> str:
    """Runs a bpy script in a fresh interpreter with the test's user resources and without any
    WOVEN_FABRIC_* variable (nothing set by hand); returns its output, fails on a non-zero exit."""
    require_bpy()
    path = cwd / "script.py"
    path.write_text(textwrap.dedent(script))
    environment = {k: v for k, v in os.environ.items() if not k.startswith("WOVEN_FABRIC_")}
    environment.update(BLENDER_USER_RESOURCES=str(resources), PYTHONUNBUFFERED="1", WFC_COMPILE="0", **env)
    done = subprocess.run([sys.executable, str(path)], capture_output=True, text=True, timeout=TIMEOUT_S,
                          env=environment, cwd=cwd)
    output = done.stdout + done.stderr
    assert done.returncode == 0, f"bpy script failed (exit {done.returncode}):\n{output[-6000:]}"
    return output


def _printed(output: str, key: str):
    return json.loads(next(line for line in output.splitlines() if line.startswith(key + " "))[len(key) + 1:])


@pytest.fixture(scope="module")
def installed(build_module, tmp_path_factory) -> Path:
    """The linux-x64 zip, validated and installed ("Install from Disk") into a temporary user folder."""
    zip_path = build_module.build_platform(PLATFORM, tmp_path_factory.mktemp("dist"))
    names = zipfile.ZipFile(zip_path).namelist()
    manifest = tomllib.loads(zipfile.ZipFile(zip_path).read("blender_manifest.toml").decode())
    assert manifest["platforms"] == [PLATFORM]
    assert sorted(name[2:] for name in manifest["wheels"]) == sorted(n for n in names if n.endswith(".whl"))
    wheels = [Path(name).name for name in names if name.endswith(".whl")]
    assert any(w.startswith("torch-2.13.0+cpu-cp311") for w in wheels) and not any("nvidia" in w for w in wheels)
    for dependency in (*dependencies.RUNTIME, dependencies.INSTALLER):
        project = dependency.project.replace("-", "_")
        assert any(w.lower().startswith(project + "-") for w in wheels), dependency
    validate_extension(zip_path)
    resources = tmp_path_factory.mktemp("blender_user")
    _bpy(f"""
        import bpy
        assert bpy.ops.extensions.package_install_files(filepath={str(zip_path)!r}, repo="user_default",
                                                        enable_on_install=True) == {{"FINISHED"}}
    """, resources, resources)
    return resources


# Run by the bundled backend's interpreter, with its flags and path: what can it see?
ISOLATION_PROBE = """
import importlib.util, json, sys
import torch
print(json.dumps({"path": sys.path, "torch": torch.__file__, "version": torch.__version__,
                  "visible": {m: importlib.util.find_spec(m) is not None for m in ("pytest", "bpy", "cv2")}}))
"""


@pytest.mark.slow
def test_the_installed_zip_fits_with_blenders_python_and_its_own_packages_only(installed, tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    truth = FabricParams.from_interchange(
        "twill1_R_0.6,0.5_S_1.3,1.6_T_2.4,2.9_N_0.0_UV_92.0,131.0_Kd_0.32,0.18,0.11,0.26,0.14,0.08"
        "_G_0.88,0.9_Rm_0.7,0.45_Tm_2.2,2.6_W_0.6,0.9_Ks_0.62,0.38,0.25,0.55,0.33,0.22_Psi_-30.0,-30.0")
    pair = render_pair(truth, size=256, spp=2, seed=1)
    write_png(photos / "cotton_R.png", pair.reflection.numpy())
    write_png(photos / "cotton_T.png", pair.transmission.numpy())
    output = _bpy(f"""
        import importlib, json, subprocess, sys
        from pathlib import Path
        import bpy
        bpy.ops.preferences.addon_enable(module={EXTENSION!r})  # installed by the fixture
        ext = importlib.import_module({EXTENSION!r})
        prefs = bpy.context.preferences.addons[{EXTENSION!r}].preferences
        assert (prefs.python_path, prefs.backend_script, prefs.device) == ("", "", "AUTO")  # nothing touched

        backend = ext.ui.preferences.selected_backend()
        site = Path(bpy.utils.user_resource("EXTENSIONS"), ".local", "lib", "python3.11", "site-packages")
        assert backend.python == sys.executable and backend.packages == (str(site),), backend
        seen = subprocess.run(backend.python_command(["-c", {ISOLATION_PROBE!r}]), env=backend.environment(),
                              capture_output=True, text=True)
        assert seen.returncode == 0, seen.stderr
        print("SEEN", json.dumps({{**json.loads(seen.stdout), "site": str(site), "base": sys.base_prefix,
                                   "extension": str(Path(ext.__file__).parent)}}))

        assert bpy.ops.fabric.check_backend() == {{"FINISHED"}}  # background mode: checks now
        check = ext.core.check_job.backend_check.last
        items = ext.core.checklist.first_run_checklist(check, False, None, ext.scene.cycles_osl.osl_problem())
        print("CHECK", json.dumps({{"label": check.label, "torch": check.torch_version, "file": check.torch_file,
                                    "device": check.device, "items": [[i.state, i.text] for i in items]}}))

        drawn = []  # the preferences drawn into a layout that records labels and checks props and operators
        class Layout:
            def __getattr__(self, name):
                def call(*args, **kw):
                    if name == "prop":
                        assert args[1] in args[0].bl_rna.properties, args[1]
                    if name == "operator":
                        assert hasattr(getattr(bpy.ops, args[0].split(".")[0]), args[0].split(".")[1]), args[0]
                    drawn.append(kw.get("text") if name == "label" else args[-1] if args else name)
                    return Layout()
                return call
        class PreferencesView:
            layout = Layout()
            def __getattr__(self, name):
                return getattr(prefs, name)
        type(prefs).draw(PreferencesView(), bpy.context)
        print("DRAWN", json.dumps([d for d in drawn if isinstance(d, str)]))

        settings = bpy.context.scene.woven_fabric
        settings.reflection_path = {str(photos / "cotton_R.png")!r}
        settings.transmission_path = {str(photos / "cotton_T.png")!r}
        settings.pattern, settings.iterations, settings.size = "twill1", 2, 64
        settings.rig.film_size = 256  # the photos' size: the quickest fit that still finds the weave
        prefs.results_folder = {str(tmp_path / "fits")!r}
        assert bpy.ops.fabric.fit() == {{"FINISHED"}}
        material = bpy.data.materials[settings.last_material]
        print("FITTED", json.dumps({{"folder": settings.last_result_folder,
                                     "values": ext.scene.node_group.read_params(material)}}))
    """, installed, tmp_path)

    seen = _printed(output, "SEEN")
    allowed = (seen["extension"], seen["site"])
    others = [p for p in seen["path"] if p not in allowed and not p.startswith(seen["base"])]
    assert others == [] and seen["path"][:2] == list(allowed), seen["path"]  # nothing of the test environment
    assert not [p for p in seen["path"] if "site-packages" in p and p != seen["site"]]
    assert seen["visible"] == {"pytest": False, "bpy": False, "cv2": True}, seen["visible"]
    assert Path(seen["torch"]).is_relative_to(seen["site"]) and seen["version"] == "2.13.0+cpu"

    check = _printed(output, "CHECK")
    assert check["label"] == "Blender's Python with the extension's packages"
    assert check["torch"] == "2.13.0+cpu" and Path(check["file"]).is_relative_to(seen["site"])
    assert check["device"] == "CPU"
    assert [state for state, _ in check["items"]] == ["ok", "ok", "ok", "ok"], check["items"]
    assert check["items"][1][1] == "PyTorch 2.13.0+cpu" and check["items"][2][1] == "Device: CPU"

    drawn = _printed(output, "DRAWN")  # the checklist, and the GPU route (offline: it says what to allow)
    assert "First-Run Checklist" in drawn and "PyTorch 2.13.0+cpu" in drawn and "Device: CPU" in drawn
    assert "fabric.install_gpu_torch" in drawn and "cuda_index" in drawn
    assert "Needs online access: turn on Allow Online Access in Edit > Preferences > System > Network." in \
        " ".join(drawn)

    fitted = _printed(output, "FITTED")
    written = json.loads((Path(fitted["folder"]) / "params.json").read_text())
    assert written["pattern"] == fitted["values"]["pattern"] == "twill1"
    for name, value in FabricParams.from_dict(written).to_dict().items():
        if name != "pattern":
            assert np.ravel(fitted["values"][name]) == pytest.approx(np.ravel(value), rel=1e-4, abs=1e-5), name
    log = (Path(fitted["folder"]) / "backend.log").read_text()
    assert "Traceback" not in log


def test_the_gpu_route_installs_torch_beside_the_extension_and_refuses_offline(installed, tmp_path):
    """The GPU route's install, as the button runs it, against the registry: the requirement is the CPU
    build from pip's configuration (this machine has no CUDA and no PyTorch index) and the target a
    temporary folder; then the backend runs with that folder before the extension's packages."""
    output = _bpy(f"""
        import importlib, json, sys
        from pathlib import Path
        import bpy
        bpy.ops.preferences.addon_enable(module={EXTENSION!r})
        ext = importlib.import_module({EXTENSION!r})
        gpu_env = ext.core.gpu_env
        assert not bpy.app.online_access  # Blender's default: no network
        try:
            bpy.ops.fabric.install_gpu_torch()
            raise AssertionError("the install started offline")
        except RuntimeError as exc:
            assert "Allow Online Access" in str(exc), exc
        assert not gpu_env.installed(ext.ui.preferences.gpu_folder())

        site = ext.ui.preferences.extensions_site_packages()
        bundled = ext.core.backend_setup.bundled_backend(sys.executable, site)
        folder = Path({str(tmp_path / "gpu_torch")!r})
        job = gpu_env.TorchInstall(bundled, folder, "torch==2.13.0", index_url=None)  # pip's own sources
        job.start(online=True)
        assert job.wait(timeout=600) == gpu_env.SUCCEEDED, (job.error, list(job.output)[-20:])
        assert gpu_env.installed(folder) and not job.partial.exists()
        with_gpu = ext.core.backend_setup.bundled_backend(sys.executable, site, folder)
        check = ext.core.backend_setup.check_backend(with_gpu)
        print("GPU", json.dumps({{"ok": check.ok, "file": check.torch_file, "label": check.label,
                                  "status": job.status, "problems": check.problems}}))
    """, installed, tmp_path)
    gpu = _printed(output, "GPU")
    assert gpu["ok"], gpu["problems"]
    assert Path(gpu["file"]).is_relative_to(tmp_path / "gpu_torch")  # the installed folder comes first
    assert gpu["label"] == "Blender's Python with the GPU (CUDA) PyTorch and the extension's packages"
    assert gpu["status"].startswith("Installed torch==2.13.0 in")
