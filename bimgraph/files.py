"""Small file helpers shared by every reader and writer: JSON with clear errors, atomic writes."""

from __future__ import annotations

import json
import os
from pathlib import Path

from bimgraph.errors import FormatError, InputError


def read_json(path: Path):
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        return json.loads(path.read_text())
    except UnicodeDecodeError:
        raise FormatError(f"{path}: not a text file") from None
    except json.JSONDecodeError as err:
        raise FormatError(f"{path}: line {err.lineno}: invalid JSON ({err.msg})") from None


def write_atomic(path: Path, text: str) -> None:
    """Write through a temporary file and rename, so that a crash never leaves a half file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def write_json(path: Path, data) -> None:
    write_atomic(path, json.dumps(data, indent=1) + "\n")
