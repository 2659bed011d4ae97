"""hw_sim's errors: one root, and a ValueError branch for bad input (the CLI exits 2)."""
from __future__ import annotations

from typing import Any


class SimError(Exception):
    """Root of every error hw_sim raises on purpose."""


class BadValue(SimError, ValueError):
    """A value given to hw_sim is unusable (the CLI exits 2)."""


class ConfigError(BadValue):
    """A SimConfig value is out of range; `.field` names the field."""

    def __init__(self, name: str, value: Any, why: str):
        self.field = name
        self.value = value
        self.why = why
        super().__init__(f"{name}={value!r} {why}")

    def __reduce__(self):
        # rebuilt from its three parts: a render in a process pool raises it back to the parent
        return type(self), (self.field, self.value, self.why)
