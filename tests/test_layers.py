"""The backend's sub-packages import one way (the add-on's rule is tests/test_addon_bridge.py's).

core <- image (a leaf beside the model) ; core <- model <- texture <- init ; fit uses all of those
(the library: values in, values out); app, the edge (cli, the fit-a-folder job, report, batch), is
the top. The shipped backend never imports the developer tools (devtools/). Read from the source
(every ``from ..x`` and ``from backend.x``), so a new module that breaks the rule fails here before
anything runs it.
"""
import ast
from pathlib import Path

from conftest import ROOT

BACKEND = ROOT / "backend"
ALLOWED = {
    "core": set(),
    "image": {"core"},
    "model": {"core"},
    "texture": {"core", "image", "model"},
    "init": {"core", "model", "texture"},
    "fit": {"core", "image", "model", "texture", "init"},
    "app": {"core", "image", "model", "texture", "init", "fit"},
}


def imported_packages(path: Path) -> set[str]:
    """The backend sub-packages a module imports (``backend/__init__`` itself only holds the version)."""
    parts = path.relative_to(BACKEND).parts
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if not isinstance(node, ast.ImportFrom):
            continue
        if node.level:
            target = ["backend", *parts[:-1]][:len(parts) - node.level + 1] + (node.module or "").split(".")
        elif (node.module or "").startswith("backend."):
            target = node.module.split(".")
        else:
            continue
        target = [t for t in target if t]
        if len(target) > 1:
            found.add(target[1])
    return found


def test_every_sub_package_is_declared():
    packages = {p.name for p in BACKEND.iterdir() if (p / "__init__.py").exists()}
    assert packages == set(ALLOWED)


def test_the_backend_layers_import_one_way():
    wrong = []
    for package, allowed in ALLOWED.items():
        for path in sorted((BACKEND / package).rglob("*.py")):
            for target in imported_packages(path) - allowed - {package}:
                wrong.append(f"{path.relative_to(ROOT)} imports backend.{target}")
    assert not wrong, "\n".join(wrong)


def test_the_rule_is_checked_on_real_imports():
    """The reader itself: a module known to import across layers is seen doing so."""
    assert imported_packages(BACKEND / "app" / "folder.py") >= {"core", "image", "model", "init"}
    assert imported_packages(BACKEND / "core" / "protocol.py") == set()  # `from .. import __version__` only


def test_the_backend_never_imports_the_developer_tools():
    wrong = []
    for path in sorted(BACKEND.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
            wrong += [f"{path.relative_to(ROOT)} imports {n}" for n in names if n.split(".")[0] == "devtools"]
    assert not wrong, "\n".join(wrong)
