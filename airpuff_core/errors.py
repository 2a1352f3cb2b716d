"""Errors raised by the solver."""


class SimulationError(RuntimeError):
    """A run that could not be completed honestly: blow-up, non-convergent coupling, or an
    ill-conditioned MFPM moment matrix.  The message names the time (ms) and the quantity."""

    def __init__(self, message: str, time_ms: float | None = None, reason: str = "error"):
        self.time_ms = time_ms
        self.reason = reason
        super().__init__(message)
