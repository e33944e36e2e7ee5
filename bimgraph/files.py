"""Small file helpers shared by every reader and writer: JSON with clear errors, atomic writes."""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import shutil
import signal
import threading
from pathlib import Path

import yaml

from bimgraph.errors import FormatError, InputError


def existing_file(path: Path, stream: bool = False) -> Path:
    """`path`, if it is a file (or, with `stream`, anything readable as one: a pipe, such as
    the shell's `<(...)`, a device); else InputError saying what it is instead."""
    path = Path(path)
    if not (path.is_file() or stream and path.exists() and not path.is_dir()):
        raise InputError(f"{path}: " + ("a folder, not a file" if path.is_dir() else
                                        "not a regular file" if path.exists() else "no such file"))
    return path


def read_text(path: Path) -> str:
    """A text file's content (or a pipe's). Missing or unreadable: InputError; not UTF-8 text
    (a binary file given by mistake): FormatError. Never a traceback."""
    path = existing_file(path, stream=True)
    try:
        # (utf-8-sig: Windows editors start a file with a byte-order mark, which json refuses)
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise FormatError(f"{path}: not a text file") from None
    except OSError as err:
        raise InputError(f"{path}: cannot read ({err.strerror or err})") from None


def read_json(path: Path):
    return parse_json(read_text(path), str(path), lines=True)


def parse_json(text: str, where: str, lines: bool = False):
    """JSON data of `text`; what is not JSON, or what Python will not read as such (nesting
    deeper than its stack, integers of thousands of digits) is a FormatError at `where` (and
    the line, with `lines`, for a whole file)."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        raise FormatError(f"{where}: {f'line {err.lineno}: ' if lines else ''}invalid JSON ({err.msg})") from None
    except RecursionError:
        raise FormatError(f"{where}: invalid JSON (nested too deeply)") from None
    except ValueError as err:  # (e.g. an integer beyond Python's 4300 digits)
        raise FormatError(f"{where}: invalid JSON ({str(err).splitlines()[0]})") from None


class _Yaml12Floats(yaml.SafeLoader):
    """YAML 1.1 reads `1e-3` (no dot, or an exponent without its sign) as a string; 1.2, and
    whoever writes a sigma so, as a number. A key given twice in one mapping is an error:
    PyYAML keeps the last silently, so that an edit below a forgotten one went unnoticed."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            first = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":  # (`<<: *base` may be overridden)
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    if key in first:
                        raise yaml.constructor.ConstructorError(
                            None, None, f"key {key!r} given twice, first on line {first[key]}", key_node.start_mark)
                    first[key] = key_node.start_mark.line + 1
                except TypeError:  # (an unhashable key: PyYAML's own error says so)
                    continue
        return super().construct_mapping(node, deep=deep)


_Yaml12Floats.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?(?:[eE][-+]?[0-9]+)?
                   |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                   |[-+]?\.(?:inf|Inf|INF)
                   |\.(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789."))


def read_yaml(path: Path):
    """A YAML file's data (None if it is empty); a syntax error is a FormatError in one line
    naming the line (PyYAML's own message spans five, with a drawing of the place)."""
    try:
        return yaml.load(read_text(path), Loader=_Yaml12Floats)  # noqa: S506 (a SafeLoader)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f"line {mark.line + 1}: " if mark is not None else ""
        # (a MarkedYAMLError has a `problem`; a ReaderError, for control characters, a `reason`)
        problem = getattr(err, "problem", None) or getattr(err, "reason", None) or "not YAML"
        raise FormatError(f"{path}: {where}invalid YAML ({problem})") from None
    except RecursionError:
        raise FormatError(f"{path}: invalid YAML (nested too deeply)") from None
    except ValueError as err:  # (e.g. an integer beyond Python's 4300 digits)
        raise FormatError(f"{path}: invalid YAML ({str(err).splitlines()[0]})") from None


def ensure_folder(path: Path, target: Path | None = None) -> Path:
    """Make the output folder `path` (and its parents); one that cannot be (a file in the way,
    no permission) is an InputError naming `target` (default: the folder)."""
    path = Path(path)
    target = path if target is None else target
    blocking = next((p for p in (path, *path.parents) if p.exists() and not p.is_dir()), None)
    if blocking is not None:
        raise InputError(f"{target}: is a file, not a folder" if blocking == Path(target)
                         else f"{target}: {blocking} is a file, not a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"{target}: cannot make the folder ({err.strerror or err})") from None
    return path


@contextlib.contextmanager
def new_folder(path: Path):
    """Make the output folder `path` (as `ensure_folder`) for the block; if the block fails,
    remove what this made, the folder with whatever the block wrote into it and any parents
    made for it, so that a failed command leaves no half-made output behind. A folder that
    existed before is left (the block must not have spoilt it before it failed)."""
    path = Path(path)
    made = next((p for p in reversed((path, *path.parents)) if not p.exists()), None)
    ensure_folder(path)
    try:
        yield path
    except BaseException:  # (Ctrl-C too)
        if made is not None:
            shutil.rmtree(made, ignore_errors=True)
        raise


def write_atomic(path: Path, text: str) -> None:
    """Write through a temporary file and rename, so that a crash never leaves a half file.
    A path that cannot be written (a folder, a device, under a file, no permission) is an
    InputError naming it, and leaves nothing behind."""
    path = Path(path)
    if path.exists() and not path.is_file():
        raise InputError(f"{path}: exists and is not a regular file")
    ensure_folder(path.parent, path)
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    except OSError as err:
        if tmp.is_file():
            tmp.unlink()
        raise InputError(f"{path}: cannot write ({err.strerror or err})") from None


def _finite(data):
    """NaN and infinities as null: JSON has no such numbers (a graph gone singular mid-run
    leaves them in the covariance written last)."""
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, dict):
        return {k: _finite(v) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return [_finite(v) for v in data]
    return data


def write_json(path: Path, data) -> None:
    write_atomic(path, json.dumps(_finite(data), indent=1, allow_nan=False) + "\n")


@contextlib.contextmanager
def uninterrupted():
    """Hold Ctrl-C and SIGTERM until the block is done, then act on them as their handlers
    would have: what the block writes to several files is then all written or none of it (a
    signal in between left a trajectory one line longer than its summary said). Their handlers
    are swapped, not the signals masked: gtsam's worker threads would take a masked signal and
    Python would still run its handler at once. Off the main thread, which cannot swap them,
    the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    # (a handler set outside Python reads None and could not be put back: left as it is)
    handlers = {s: h for s in (signal.SIGINT, signal.SIGTERM) if (h := signal.getsignal(s)) is not None}
    for s in handlers:
        signal.signal(s, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        for s, handler in handlers.items():
            signal.signal(s, handler)
        for s in caught:
            signal.raise_signal(s)
