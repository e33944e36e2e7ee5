"""Turning pydantic's validation errors into one line that names the file, line and field."""

from __future__ import annotations

from typing import Annotated, TypeVar

import numpy as np

from pydantic import AfterValidator, BaseModel, ValidationError

from bimgraph.errors import BimgraphError, FormatError

M = TypeVar("M", bound=BaseModel)


def _field(loc: tuple) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def describe(err: ValidationError) -> str:
    first = err.errors()[0]
    more = f" (and {err.error_count() - 1} more)" if err.error_count() > 1 else ""
    # (our own validators' messages, without pydantic's "Value error, " before them)
    message = first["msg"].removeprefix("Value error, ") if first["type"] == "value_error" else first["msg"]
    return f"{_field(first['loc'])}: {message}{more}"


def parse_model(model: type[M], data, where: str, error: type[BimgraphError] = FormatError) -> M:
    """Validate `data` as `model`; on failure raise `error` (a file's: FormatError; options':
    ConfigError) starting with `where`."""
    try:
        return model.model_validate(data)
    except ValidationError as err:
        raise error(f"{where}: {describe(err)}") from None


def require_unit(values, what: str, tol: float = 1e-3):
    """A pydantic validator body: `values` must have norm 1 (within `tol`)."""
    norm = float(np.linalg.norm(values))
    if abs(norm - 1.0) > tol:
        raise ValueError(f"{what} has norm {norm:.4f}, must be unit")
    return values


def _unit_quaternion(pose):
    require_unit(pose[3:], "quaternion")
    return pose


# A pose `[tx, ty, tz, qx, qy, qz, qw]` (TUM order) as files hold it: 7 numbers, unit quaternion.
Pose7 = Annotated[tuple[float, float, float, float, float, float, float], AfterValidator(_unit_quaternion)]
