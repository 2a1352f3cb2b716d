"""The statuses of a sweep job and of its points: the one list (database, API schema, runner).

A job moves ``queued -> running -> done | failed``; ``queued`` or ``running`` may become
``cancelled`` (DELETE /sweeps/{id}); an ended job is removed, with its dataset, by a DELETE.  A server that stops leaves ``running`` jobs behind; the
next runner on the same data folder puts them back to ``queued`` (their finished points are
reused).  A point of a job is ``pending`` until its result is known: ``ok`` or ``failed``, or
``cancelled`` with its job.  The transitions are made by ``api.runner`` and, for the
cancellation, by the API (``api.db.cancel_job``).
"""

from __future__ import annotations

from typing import Literal, get_args

JobStatusName = Literal["queued", "running", "done", "failed", "cancelled"]
PointStatusName = Literal["pending", "ok", "failed", "cancelled"]

JOB_STATUSES: tuple[str, ...] = get_args(JobStatusName)
POINT_STATUSES: tuple[str, ...] = get_args(PointStatusName)
# Jobs that still need their points (may be cancelled); the others have ended.
ACTIVE_JOB_STATUSES = ("queued", "running")
ENDED_JOB_STATUSES = tuple(s for s in JOB_STATUSES if s not in ACTIVE_JOB_STATUSES)
# Final results of a point (a points row, shared by jobs, is "pending" until then).
POINT_RESULTS = ("ok", "failed")


def sql_list(values: tuple[str, ...]) -> str:
    """``('a', 'b')`` as the SQL list ``'a', 'b'`` (for CHECK and IN clauses of fixed names)."""
    return ", ".join(f"'{v}'" for v in values)
