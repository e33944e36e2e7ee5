"""The base of every configuration section: unknown keys are errors, not silently ignored, and
so are NaN and infinities (every threshold is a finite number) and values of the wrong type
(strict: YAML's `true` or `"0.05"` for a tolerance in metres is a mistake, not 1.0 or 0.05)."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, BeforeValidator, ConfigDict

# A (low, high) pair: YAML writes it as a list, which strict validation would refuse as a tuple
Range = Annotated[tuple[float, float], BeforeValidator(lambda v: tuple(v) if isinstance(v, list) else v)]


class Section(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)

    def ordered(self, *pairs: tuple[str, str]):
        """For a section's `model_validator`: each (low, high) pair of its fields must not be
        the wrong way round (a sensor seeing from 6 m to 5 m sees nothing, silently)."""
        for low, high in pairs:
            if getattr(self, low) > getattr(self, high):
                raise ValueError(f"{low} ({getattr(self, low)}) is above {high} ({getattr(self, high)})")
        return self
