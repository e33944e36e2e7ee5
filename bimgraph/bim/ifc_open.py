"""Open an IFC file that may be damaged: refuse what is not IFC or is cut short, and say,
with line numbers, what the parser found wrong (a statement left open, a reference to no
entity), so that the import can skip what it lost instead of reading the model in silence."""

from __future__ import annotations

import json
import re
from pathlib import Path

import ifcopenshell
import ifcopenshell.ifcopenshell_wrapper as wrapper
import numpy as np

from bimgraph.errors import FormatError
from bimgraph.files import existing_file

_END_MARK = b"END-ISO-10303-21;"
_BOM = b"\xef\xbb\xbf"


def open_model(path) -> tuple[ifcopenshell.file, list[str]]:
    """Open an IFC file: the model, and what the parser found wrong in it (a syntax error, a
    reference to no entity: past such an error it may have lost entities, so the caller must
    not read the model in silence). A missing file is an InputError, a non-IFC or truncated
    one, or one that names two entities alike, a FormatError."""
    path = existing_file(path)
    with open(path, "rb") as stream:
        head = stream.read(64)
        stream.seek(0, 2)
        stream.seek(max(0, stream.tell() - 1024))
        tail = stream.read()
    bom = head.startswith(_BOM)
    if not head.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"ISO-10303-21;"):  # a BOM is allowed
        raise FormatError(f"{path}: not an IFC file (no ISO-10303-21 header)")
    if _END_MARK not in tail:
        raise FormatError(f"{path}: truncated IFC file (no {_END_MARK.decode()} at its end)")
    wrapper.set_log_format_json()
    wrapper.get_log()  # (reading the parser's log empties it: what it holds next is this file's)
    try:
        # (the parser itself refuses a byte order mark, which editors on Windows write)
        model = ifcopenshell.file.from_string(path.read_bytes()[len(_BOM):].decode("utf-8", "replace")) if bom \
            else ifcopenshell.open(str(path))
    except Exception as err:  # ifcopenshell raises several unrelated types on bad files
        # (its message says "check logs": the log says what and where)
        logged = _with_lines(_parse_problems(wrapper.get_log()), path)
        why = logged[0] if logged else (str(err).splitlines()[0] if str(err) else type(err).__name__)
        raise FormatError(f"{path}: cannot parse IFC ({why})") from None
    problems = _with_lines(_parse_problems(wrapper.get_log()), path)
    duplicates = [message for message in problems if message.startswith("Overwriting instance")]
    if duplicates:  # (the geometry kernel crashes on such a file)
        raise FormatError(f"{path}: two entities with one name ({duplicates[0]})")
    return model, problems


_STEP_TOKENS = re.compile(rb"'(?:[^']|'')*'|/\*.*?\*/|[();\n]", re.DOTALL)


def unbalanced_statement(path) -> int | None:
    """The line of the first statement of an IFC file whose parentheses do not balance, or
    None. (One "(" too many makes the parser swallow the rest of the file, and its first
    complaint is about ENDSEC, megabytes on: this names the line to fix.)"""
    line, start, depth = 1, 1, 0
    for token in _STEP_TOKENS.finditer(Path(path).read_bytes()):
        text = token.group()
        if text == b"\n":
            line += 1
        elif text == b"(":
            start = line if depth == 0 else start  # (a statement's first parenthesis)
            depth += 1
        elif text == b")":
            depth -= 1
            if depth < 0:
                return line
        elif text == b";":
            if depth:
                return start
        else:  # a string or a comment: its own newlines count
            line += text.count(b"\n")
    return None


_OFFSET = re.compile(r"at offset (\d+)")


def _with_lines(messages: list[str], path: Path) -> list[str]:
    """The parser's messages with each byte offset named as the file's line."""
    if not any(_OFFSET.search(m) for m in messages):
        return messages
    # (a parenthesis too many gives a message per entity swallowed, tens of thousands: the
    # newlines are found once, not counted again for each)
    newlines = np.flatnonzero(np.frombuffer(path.read_bytes(), dtype=np.uint8) == ord("\n"))

    def line(found: re.Match) -> str:
        return f"on line {np.searchsorted(newlines, int(found.group(1))) + 1}"

    return [_OFFSET.sub(line, m) for m in messages]


_MISSING_REFERENCE = re.compile(r"used by instance #(\d+) at attribute index (\d+)")


def missing_references(problems: list[str]) -> dict[int, set[int]]:
    """Instance id -> the indices of its attributes that name an entity the file lacks, from
    the parser's messages ("Instance reference #9 used by instance #15042 at attribute index 5
    not found"). The parser reads such an attribute as unset: a wall whose placement is gone
    stands at the origin, one whose placement's parent is gone storeys below."""
    out: dict[int, set[int]] = {}
    for message in problems:
        if found := _MISSING_REFERENCE.search(message):
            out.setdefault(int(found.group(1)), set()).add(int(found.group(2)))
    return out


# (the parser's message where "(" opened a list where one value was due: it names mangled C++ types, no line)
_MIXED_LIST = "Inconsistent aggregate valuation"


def _parse_problems(log_text: str) -> list[str]:
    """The messages of errors and of duplicate entities in ifcopenshell's JSON log, those of
    lists of mixed types as one, where the first was."""
    out = []
    for line in log_text.splitlines():
        try:
            record = json.loads(line)
        except ValueError:
            continue
        message = str(record.get("message", "")).strip()
        if record.get("level") == "error" or message.startswith("Overwriting instance"):
            out.append(message)
    if mixed := [i for i, message in enumerate(out) if message.startswith(_MIXED_LIST)]:
        out[mixed[0]] = f"{len(mixed)} lists of values of mixed types (a parenthesis out of place, most likely)"
        out = [message for message in out if not message.startswith(_MIXED_LIST)]
    return out
