"""Every threshold of bimgraph, in one typed configuration.

The defaults live in this package, next to their documentation, one module per part of
bimgraph (IFC import, sensing, simulator, backend, what is made of a run); `bimgraph config
--default` prints them all as YAML with each field's description as a comment, and `--config
FILE` overrides any subset.
"""

from __future__ import annotations

from pathlib import Path

import yaml
from pydantic import BaseModel

from bimgraph.config.backend import (BackendConfig, BimAssociationConfig, Isam2Config, NoiseConfig, OfflineConfig,
                                     SlamAssociationConfig)
from bimgraph.config.bim import BimImportConfig
from bimgraph.config.results import BaselineConfig, DeviationConfig, ViewerConfig
from bimgraph.config.section import Section
from bimgraph.config.sensing import DepthNoiseConfig, ExtractionConfig, PlaneNoiseConfig
from bimgraph.config.sim import AsBuiltConfig, FrontEndConfig, ObserveConfig, SimConfig, TrajectoryConfig
from bimgraph.errors import ConfigError, InputError
from bimgraph.files import read_yaml
from bimgraph.validation import parse_model

__all__ = ["AsBuiltConfig", "BackendConfig", "BaselineConfig", "BimAssociationConfig", "BimImportConfig", "Config",
           "DepthNoiseConfig", "DeviationConfig", "ExtractionConfig", "FrontEndConfig", "Isam2Config", "NoiseConfig",
           "ObserveConfig", "OfflineConfig", "PlaneNoiseConfig", "Section", "SimConfig", "SlamAssociationConfig",
           "TrajectoryConfig", "ViewerConfig", "default_yaml", "load_config"]


class Config(Section):
    bim: BimImportConfig = BimImportConfig()
    sim: SimConfig = SimConfig()
    depth_noise: DepthNoiseConfig = DepthNoiseConfig()
    planes: ExtractionConfig = ExtractionConfig()
    deviations: DeviationConfig = DeviationConfig()
    backend: BackendConfig = BackendConfig()
    viewer: ViewerConfig = ViewerConfig()
    baselines: BaselineConfig = BaselineConfig()


def load_config(path: Path | None) -> Config:
    """The defaults, overridden by the YAML file at `path` if given. Anything wrong with that
    file, from missing or not YAML to a value out of range, is a ConfigError (exit code 4)."""
    if path is None:
        return Config()
    try:
        data = read_yaml(path)
    except InputError as err:  # (a FormatError too) the file --config names is configuration
        raise ConfigError(str(err)) from None
    return parse_model(Config, _onto(Config().model_dump(), {} if data is None else data), str(path), error=ConfigError)


def _onto(defaults, overrides):
    """The file's `overrides` merged onto the `defaults` section by section: a section the file
    names keeps the defaults of the keys it leaves out. (Validated as they stand, a file setting
    only `sim.as_built_site.offset_fraction` gave the site scenario `AsBuiltConfig`'s own
    defaults for the rest: half its clutter, no boards, no partitions.)"""
    if not isinstance(overrides, dict):
        return overrides
    merged = dict(defaults)
    for key, value in overrides.items():
        merged[key] = _onto(defaults[key], value) if isinstance(defaults.get(key), dict) else value
    return merged


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
