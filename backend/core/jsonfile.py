"""Reading a JSON file with errors that name the file and the problem (one rule for every input)."""
from __future__ import annotations

import json
from pathlib import Path


def read_json(path: str | Path, error: type[Exception]):
    """The parsed content of ``path``; ``error("<path>: cannot read (...)" | "<path>: not valid JSON
    (...)")`` when it cannot be read or parsed."""
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
