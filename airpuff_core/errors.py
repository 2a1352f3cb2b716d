"""Errors raised by the solver and by the validation of its parameters."""

from __future__ import annotations

from typing import Any


class ParameterError(ValueError):
    """An invalid run parameter.  ``str(err)`` is one line naming the parameter and its range."""

    def __init__(self, name: str, value: Any, accepted: str):
        self.name = name
        self.value = value
        self.accepted = accepted
        super().__init__(f"invalid {name}={value!r}: accepted {accepted}")


class SimulationError(RuntimeError):
    """A run that could not be completed honestly: blow-up, non-convergent coupling, or an
    ill-conditioned MFPM moment matrix.  The message names the time (ms) and the quantity."""

    def __init__(self, message: str, time_ms: float | None = None, reason: str = "error"):
        self.time_ms = time_ms
        self.reason = reason
        super().__init__(message)
