"""Files in and out, whole: a JSON file read with errors that name the file and the problem (one rule
for every input), an output folder made or refused in one line, and every output written through a
temporary file renamed over it (one rule for every output), so that a reader never finds half a
file, even when the writer is killed midway."""
from __future__ import annotations

import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def read_json(path: str | Path, error: type[Exception]):
    """The parsed content of ``path``; ``error("<path>: cannot read (...)" | "<path>: not valid JSON
    (...)" | "<path>: not usable JSON (...)")`` when it cannot be read or parsed, or holds more than
    Python reads (arrays nested thousands deep, integers of thousands of digits)."""
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise error(f"{path}: not valid JSON (not UTF-8 text)") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise error(f"{path}: not valid JSON ({exc})") from None
    except RecursionError:
        raise error(f"{path}: not usable JSON (arrays or objects nested too deep)") from None
    except ValueError as exc:  # Python's limit on the digits of an integer
        raise error(f"{path}: not usable JSON ({str(exc).split(';')[0]})") from None


def shown(value, limit: int = 60) -> str:
    """``repr(value)`` for an error message, cut to about ``limit`` characters: a value read from a
    file may be a megabyte long, and the message must stay one readable line."""
    text = repr(value)
    if len(text) <= limit:
        return text
    size = f" ({type(value).__name__} of {len(value)})" if hasattr(value, "__len__") else ""
    return f"{text[:limit]}...{size}"


def make_folder(path: Path, error: type[Exception]) -> Path:
    """``path``, created with its parents where missing; ``error("<path>: cannot create the folder
    (...)")`` where it cannot be (a file in the way, no permission, a place that takes no folders)."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise error(f"{path}: cannot create the folder ({exc.strerror or exc})") from None
    return path


def listed(names, limit: int = 5) -> str:
    """The first ``limit`` of ``names`` (sorted, each :func:`shown` if long) and how many more: a file
    may hold thousands of unknown keys, and the message must stay one readable line."""
    names = sorted(str(name) for name in names)
    words = [name if len(name) <= 40 else shown(name, 40) for name in names[:limit]]
    return ", ".join(words) + (f" and {len(names) - limit} more" if len(names) > limit else "")


@contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write the new file to: renamed over ``path`` once the block
    ends (``os.replace``, atomic within a file system), deleted where the block raises. So ``path``
    holds the old file whole or the new one whole, never a part. The temporary keeps the suffix
    (image writers choose the format by it) and is hidden: ``.<stem>.writing<suffix>``."""
    path = Path(path)
    temporary = path.with_name(f".{path.stem}.writing{path.suffix}")
    try:
        yield temporary
        with open(temporary, "rb+") as written:  # on the disk before the rename: a crash keeps one whole file
            os.fsync(written.fileno())
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)


def write_whole(path: str | Path, content: str | bytes) -> Path:
    """Writes ``content`` (text as UTF-8, line ends as given) to ``path`` through :func:`replacing`."""
    with replacing(path) as temporary:
        if isinstance(content, str):
            temporary.write_text(content, encoding="utf-8", newline="")
        else:
            temporary.write_bytes(content)
    return Path(path)
