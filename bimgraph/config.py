"""Every threshold of bimgraph, in one typed configuration.

The defaults live here, next to their documentation; `bimgraph config --default` prints them
as YAML with each field's description as a comment, and `--config FILE` overrides any subset.
"""

from __future__ import annotations

from pathlib import Path

import yaml
from pydantic import BaseModel, ConfigDict, Field

from bimgraph.errors import ConfigError
from bimgraph.validation import describe


class Section(BaseModel):
    model_config = ConfigDict(extra="forbid")


class BimImportConfig(Section):
    """IFC import."""

    min_face_area_m2: float = Field(0.05, description="side faces smaller than this are dropped (wall ends, slivers)")
    include_slabs: bool = Field(False, description="also export slab top and bottom faces as horizontal planes")


class Config(Section):
    bim: BimImportConfig = BimImportConfig()


def load_config(path: Path | None) -> Config:
    """The defaults, overridden by the YAML file at `path` if given."""
    if path is None:
        return Config()
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such configuration file")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        raise ConfigError(f"{path}: invalid YAML ({err})") from None
    try:
        return Config.model_validate(data)
    except Exception as err:  # pydantic.ValidationError
        msg = describe(err) if hasattr(err, "errors") else str(err)
        raise ConfigError(f"{path}: {msg}") from None


def default_yaml() -> str:
    """The default configuration as commented YAML."""
    lines = ["# bimgraph configuration: every threshold, with its default.",
             "# Pass an edited copy (any subset of it) with --config FILE."]

    def emit(model: BaseModel, indent: int):
        for name, field in type(model).model_fields.items():
            value = getattr(model, name)
            pad = "  " * indent
            if isinstance(value, BaseModel):
                lines.append("")
                lines.append(f"{pad}# {type(value).__doc__.strip().splitlines()[0]}")
                lines.append(f"{pad}{name}:")
                emit(value, indent + 1)
            else:
                if field.description:
                    lines.append(f"{pad}# {field.description}")
                dumped = yaml.safe_dump({name: value}, default_flow_style=True, width=1000).strip()
                lines.append(f"{pad}{dumped[1:-1]}")

    emit(Config(), 0)
    return "\n".join(lines) + "\n"
