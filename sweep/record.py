"""The record of one sweep point: what a worker reports, what is stored, what the runners collect.

One typed record (:class:`PointRecord`) for every place a point's outcome travels: the task on a
Dask worker (``sweep.worker``) returns it, the sweep engine (``sweep.engine``) stores it and hands
it to the CLI's runner and to the service's, ``sweep.storage.read_point`` reads it back.  Its
stored form is a plain JSON object (:meth:`PointRecord.stored`), the format of
``points/<key>.failed.json``; :meth:`PointRecord.from_dict` reads that format, including records
of older versions that lack ``kind`` (the error type then tells, ``failure_kind``).

A failure's ``kind`` is ``model`` (the solver's verdict on the parameters: ``SimulationError``,
``ParameterError``, or the per-point time limit; computing the point again gives the same
outcome, so it is kept unless a retry is asked for) or ``infrastructure`` (anything else: a lost
worker, a write error; computed again automatically).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Literal

# Failures that are the solver's verdict on the parameters (the exception's class name): computing
# the point again gives the same failure.  Any other failure is the infrastructure's.
MODEL_FAILURES = ("SimulationError", "ParameterError", "TimeLimitExceeded")

# Fields that describe one call (which process, Numba activity), not the point: not stored.
PER_CALL_FIELDS = ("computed", "pid", "first_in_process", "jit_compiled", "jit_loaded")

StatusName = Literal["ok", "failed"]
KindName = Literal["model", "infrastructure"]


@dataclass
class PointRecord:
    """The outcome of one point.

    ``metrics``: every metric of ``airpuff_core.result.METRICS`` as a float, None where missing
    (all None if failed); ``wall_s``: run time of the simulation [s] (of the original run when read
    back); ``params``: the point's ``RunParams.to_dict()``; ``model_version``: the solver's
    ``airpuff_core.provenance.model_version()``.  A failure has ``kind``, ``error_type`` and, for
    the solver's own verdicts, the model time ``time_ms`` [ms] and ``reason`` it gave.  The
    per-call fields say whether this call computed the point (False: read back from a file),
    which process ran it, whether it was that process's first point, and how many Numba kernels
    the call compiled or loaded from the cache.
    """

    key: str
    status: StatusName
    message: str = ""
    metrics: dict[str, float | None] = field(default_factory=dict)
    wall_s: float | None = None
    params: dict[str, Any] = field(default_factory=dict)
    model_version: str | None = None
    kind: KindName | None = None
    error_type: str | None = None
    time_ms: float | None = None
    reason: str | None = None
    software_version: str | None = None
    computed: bool = True
    pid: int | None = None
    first_in_process: bool = False
    jit_compiled: int = 0
    jit_loaded: int = 0

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def failed(self) -> bool:
        return self.status == "failed"

    def failure_kind(self) -> KindName:
        """``"model"`` or ``"infrastructure"`` (records of older versions have no ``kind``; their
        error type tells)."""
        if self.kind in ("model", "infrastructure"):
            return self.kind
        return "model" if self.error_type in MODEL_FAILURES else "infrastructure"

    def to_dict(self) -> dict[str, Any]:
        """Every field, JSON-safe (what ``airpuff sweep --json`` consumers and the tests read)."""
        return dataclasses.asdict(self)

    def stored(self) -> dict[str, Any]:
        """The stored form: the point's fields without the per-call ones; a finished point's
        record has no failure fields."""
        out = {k: v for k, v in self.to_dict().items() if k not in PER_CALL_FIELDS}
        if self.ok:
            for name in ("kind", "error_type", "time_ms", "reason", "software_version"):
                if out[name] is None:
                    out.pop(name)
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any], **changes) -> "PointRecord":
        """A record from its stored (or full) form; unknown keys of other versions are ignored,
        ``kind`` is filled in from the error type if missing."""
        names = {f.name for f in dataclasses.fields(cls)}
        values = {k: v for k, v in data.items() if k in names}
        values.update(changes)
        record = cls(**values)
        if record.failed:
            record.kind = record.failure_kind()
        return record

    def replace(self, **changes) -> "PointRecord":
        return dataclasses.replace(self, **changes)
