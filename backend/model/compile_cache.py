"""Where ``torch.compile`` keeps the renderer's kernels: a folder that survives restarts.

torch's own default is ``<temp>/torchinductor_<user>``, which a reboot empties on Linux (/tmp is
often a tmpfs), macOS's clean-up of unused temporary files empties after a few days, and Windows'
Storage Sense may empty too. Every fit after that compiles again, a C++ compile of tens of seconds
per working size.

So the kernels go to the user's cache folder instead:

    Linux     $XDG_CACHE_HOME/woven-fabric-capture/torch-compile (default ~/.cache/...)
    macOS     ~/Library/Caches/woven-fabric-capture/torch-compile
    Windows   %LOCALAPPDATA%\\woven-fabric-capture\\torch-compile

A ``TORCHINDUCTOR_CACHE_DIR`` the user has set wins, and a folder that cannot be created leaves
torch's default in place (the compile still works, only slower the next time). The cache holds a
few MB per working size; torch keys its entries by its own version, so an upgrade never reuses
stale kernels.

The compiled backward is kept there too (:func:`allow_cached_custom_gradients`): the BSDF's
phi(y) = (1 - exp(-y)) / y has a hand-written derivative (a ``torch.autograd.Function``,
:func:`backend.model.spongecake.one_minus_exp_over`), and AOTAutograd's cache skips any graph
holding one unless told otherwise, so each process would trace the forward and backward graphs
anew, seconds at every fit's start. The same phi as plain tensor operations would be cached by
default, but its compiled steps are slower.
"""
from __future__ import annotations

import hashlib
import json
import os
import sys
from pathlib import Path

APP_FOLDER = "woven-fabric-capture"
ENV = "TORCHINDUCTOR_CACHE_DIR"
# The record, in the cache folder, of the kernels made ahead of the fits (backend.app.warm_compile).
WARM_RECORD = "warm.json"


def user_cache_root(platform: str = sys.platform, environ=os.environ, home: Path | None = None) -> Path:
    """The platform's per-user cache folder (not this app's subfolder)."""
    home = Path.home() if home is None else home
    if platform.startswith("win"):
        local = environ.get("LOCALAPPDATA")
        return Path(local) if local else home / "AppData" / "Local"
    if platform == "darwin":
        return home / "Library" / "Caches"
    xdg = environ.get("XDG_CACHE_HOME")
    return Path(xdg) if xdg and Path(xdg).is_absolute() else home / ".cache"


def compile_cache_dir(platform: str = sys.platform, environ=os.environ, home: Path | None = None) -> Path:
    """This app's folder for compiled kernels in the user's cache folder."""
    return user_cache_root(platform, environ, home) / APP_FOLDER / "torch-compile"


def use_persistent_compile_cache(environ=os.environ, platform: str = sys.platform, home: Path | None = None) -> str:
    """Points torch.compile at :func:`compile_cache_dir` unless ``TORCHINDUCTOR_CACHE_DIR`` is set
    already or the folder cannot be created; returns the folder in use ('' for torch's default).
    Call before the first compile: torch reads the variable when it compiles."""
    if environ.get(ENV):
        return environ[ENV]
    folder = compile_cache_dir(platform, environ, home)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return ""
    environ[ENV] = str(folder)
    return str(folder)


def allow_cached_custom_gradients() -> None:
    """Lets AOTAutograd keep graphs that hold a ``torch.autograd.Function`` in its disk cache.

    torch leaves this off because a cache key that missed a change of the Function's code would
    replay a stale backward. Here the key holds it: dynamo traces the Function's forward and
    backward into subgraphs of the graph, and AOTAutograd's key includes every subgraph's code
    (``AOTAutogradCachePickler._reduce_graph_module_for_cache_key`` pickles the submodules with
    the graph), so an edited backward is a new key.
    """
    from torch._functorch import config  # not loaded by ``import torch``

    if hasattr(config, "autograd_cache_allow_custom_autograd_functions"):
        config.autograd_cache_allow_custom_autograd_functions = True


def cache_folder(environ=os.environ, platform: str = sys.platform, home: Path | None = None) -> Path:
    """The folder torch.compile keeps its kernels in for this app: the user's ``TORCHINDUCTOR_CACHE_DIR``
    where set, else :func:`compile_cache_dir`."""
    own = environ.get(ENV)
    return Path(own) if own else compile_cache_dir(platform, environ, home)


def kernels_key() -> str:
    """What warm kernels were compiled from: torch's version and a digest of the model's code (the
    graph the renderer compiles is traced from these modules), so an upgrade of either is cold."""
    import torch

    digest = hashlib.sha256()
    for path in sorted(Path(__file__).parent.glob("*.py")):
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return f"{torch.__version__}/{digest.hexdigest()[:20]}"


def kernels_warm(environ=os.environ, platform: str = sys.platform, home: Path | None = None) -> bool:
    """Whether the cache folder holds this torch's and this code's kernels (:func:`mark_warm` wrote
    their record there)."""
    try:
        record = json.loads((cache_folder(environ, platform, home) / WARM_RECORD).read_text())
    except (OSError, ValueError):
        return False
    return isinstance(record, dict) and record.get("key") == kernels_key()


def mark_warm(environ=os.environ, platform: str = sys.platform, home: Path | None = None) -> Path:
    """Records that the cache folder holds the kernels of :func:`kernels_key` (written whole: a
    reader never sees half a record)."""
    folder = cache_folder(environ, platform, home)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / WARM_RECORD
    partial = path.with_suffix(f".{os.getpid()}.tmp")
    partial.write_text(json.dumps({"key": kernels_key()}) + "\n")
    os.replace(partial, path)
    return path
