"""Where torch.compile keeps the renderer's kernels (backend.model.compile_cache)."""
from pathlib import Path

from backend.model.compile_cache import ENV, compile_cache_dir, use_persistent_compile_cache


def test_the_compile_cache_lives_in_each_platforms_user_cache_folder():
    home = Path("/home/artist")
    assert compile_cache_dir("linux", {}, home) == home / ".cache/woven-fabric-capture/torch-compile"
    assert compile_cache_dir("linux", {"XDG_CACHE_HOME": "/data/cache"}, home) == \
        Path("/data/cache/woven-fabric-capture/torch-compile")
    assert compile_cache_dir("linux", {"XDG_CACHE_HOME": "relative"}, home) == \
        home / ".cache/woven-fabric-capture/torch-compile"  # the XDG spec ignores relative paths
    assert compile_cache_dir("darwin", {}, home) == home / "Library/Caches/woven-fabric-capture/torch-compile"
    assert compile_cache_dir("win32", {"LOCALAPPDATA": "C:/Users/artist/AppData/Local"}, home) == \
        Path("C:/Users/artist/AppData/Local/woven-fabric-capture/torch-compile")
    assert compile_cache_dir("win32", {}, home) == home / "AppData/Local/woven-fabric-capture/torch-compile"


def test_the_compile_cache_is_created_and_named_for_torch(tmp_path):
    environ = {"XDG_CACHE_HOME": str(tmp_path / "cache")}
    folder = use_persistent_compile_cache(environ, "linux", tmp_path)
    assert Path(folder) == tmp_path / "cache/woven-fabric-capture/torch-compile" and Path(folder).is_dir()
    assert environ[ENV] == folder


def test_a_users_own_compile_cache_wins_and_an_unwritable_one_leaves_torchs_default(tmp_path):
    own = {ENV: "/somewhere/else"}
    assert use_persistent_compile_cache(own) == "/somewhere/else" and own == {ENV: "/somewhere/else"}
    blocked = tmp_path / "file"
    blocked.write_text("not a folder")
    environ = {"XDG_CACHE_HOME": str(blocked)}
    assert use_persistent_compile_cache(environ, "linux", blocked) == "" and ENV not in environ
