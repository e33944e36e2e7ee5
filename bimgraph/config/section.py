"""The base of every configuration section: unknown keys are errors, not silently ignored, and
so are NaN and infinities (every threshold is a finite number)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class Section(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    def ordered(self, *pairs: tuple[str, str]):
        """For a section's `model_validator`: each (low, high) pair of its fields must not be
        the wrong way round (a sensor seeing from 6 m to 5 m sees nothing, silently)."""
        for low, high in pairs:
            if getattr(self, low) > getattr(self, high):
                raise ValueError(f"{low} ({getattr(self, low)}) is above {high} ({getattr(self, high)})")
        return self
