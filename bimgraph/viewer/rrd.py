"""Read a saved Rerun recording back: verify it with the `rerun` tool, and count, per entity
path and component, the rows and instances logged (with rerun's own reader,
`rerun.chunk.RrdReader`). Used by the tests and the benchmark, and by anyone who wants to
check what a recording holds without opening the viewer."""

from __future__ import annotations

import shlex
import shutil
import subprocess
import sys
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

from bimgraph.errors import InputError
from bimgraph.files import existing_file


@dataclass
class Counts:
    """Rows (log calls or time points) and instances (e.g. line strips) of one component."""

    rows: int = 0
    instances: int = 0


def rerun_binary() -> Path:
    """The `rerun` executable of this Python environment (the rerun-sdk wheel installs it)."""
    here = Path(sys.executable).parent / "rerun"
    if here.is_file():
        return here
    found = shutil.which("rerun")
    if found is None:
        raise InputError("the `rerun` command is not installed: pip install rerun-sdk")
    return Path(found)


def open_command(rrd: Path) -> str:
    """The command that opens the recording `rrd`: `rerun FILE`, with the executable's full
    path where the environment is not activated (its `rerun` not on PATH). A hint: where no
    `rerun` is found at all, still `rerun FILE`, the recording being written either way."""
    try:
        command = "rerun" if shutil.which("rerun") else str(rerun_binary())
    except InputError:
        command = "rerun"
    return f"{shlex.quote(command)} {shlex.quote(str(rrd))}"


def verify(path: Path) -> None:
    """Raise InputError unless `rerun rrd verify` accepts the file."""
    done = subprocess.run([str(rerun_binary()), "rrd", "verify", str(path)], capture_output=True, text=True)
    if done.returncode != 0:
        raise InputError(f"{path}: rerun rrd verify failed: {done.stderr.strip()}")


def component_counts(path: Path, store: str = "recording") -> dict[str, dict[str, Counts]]:
    """`{entity_path: {"Archetype:field": Counts}}` summed over the chunks of the file's first
    "recording" store (or "blueprint" store, the layout); static rows count like any other."""
    import pyarrow.compute as pc
    from rerun.chunk import RrdReader

    path = existing_file(path)
    reader = RrdReader(str(path))
    stores = reader.recordings() if store == "recording" else reader.blueprints()
    if not stores:
        raise InputError(f"{path}: no {store} in the file")
    counts: dict[str, dict[str, Counts]] = defaultdict(lambda: defaultdict(Counts))
    for chunk in reader.store(store=stores[0]).stream():
        batch = chunk.to_record_batch()
        for name, column in zip(batch.schema.names, batch.columns):
            if ":" not in name:  # row ids and time columns
                continue
            c = counts[chunk.entity_path][name]
            c.rows += chunk.num_rows
            c.instances += int(pc.sum(pc.list_value_length(column)).as_py() or 0)
    return {entity: dict(c) for entity, c in counts.items()}


def row_counts(path: Path, store: str = "recording") -> dict[str, dict[str, int]]:
    """`{entity_path: {"Archetype:field": rows}}`, see `component_counts`."""
    return {e: {k: c.rows for k, c in cs.items()} for e, cs in component_counts(path, store).items()}
