"""What a person sees of a sweep in the terminal: a progress bar while it runs, a table at the end."""

from __future__ import annotations

import math
import sys
import time

from airpuff_core.params import PARAMETERS, SWEPT

# Metrics shown in the summary table (all of them are in sweep.nc).
TABLE_METRICS = (("IOPg", "mmHg"), ("CH", "mmHg"), ("DA", "mm"))


def _clock(seconds: float) -> str:
    if seconds is None or not math.isfinite(seconds):
        return "--:--"
    seconds = int(round(seconds))
    h, rem = divmod(seconds, 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m:02d}:{s:02d}"


class SweepProgress:
    """Progress of a sweep on stderr: points done / total, failures, elapsed time and ETA.

    On a terminal one line is redrawn in place; otherwise (logs, CI) one line is printed per
    finished point.  The ETA is the mean run time of the points computed so far times the rounds
    of points left for the workers (stored points finish instantly and are left out).  Use it as the
    ``progress`` callback of ``run_sweep``.
    """

    WIDTH = 28

    def __init__(self, stream=None, tty: bool | None = None):
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty() if tty is None else tty
        self.t0 = time.monotonic()
        self.started = False
        self.walls: list[float] = []  # run time [s] of each point computed so far

    def __call__(self, record, counts: dict) -> None:
        total, done, failed = counts["total"], counts["done"], counts["failed"]
        computed, reused = counts["computed"], counts["reused"]
        elapsed = time.monotonic() - self.t0
        remaining = total - done
        if record is not None and record.computed and record.wall_s is not None:
            self.walls.append(float(record.wall_s))
        eta = self._eta(elapsed, computed, remaining, counts.get("workers"))
        frac = done / total if total else 1.0
        fill = int(round(self.WIDTH * frac))
        bar = "#" * fill + "-" * (self.WIDTH - fill)
        line = (f"sweep [{bar}] {done}/{total} points, {failed} failed"
                f"{f', {reused} stored' if reused else ''}, elapsed {_clock(elapsed)}, eta {_clock(eta)}")
        self.started = True
        if self.tty:
            self.stream.write("\r" + line + "\x1b[K")
        else:
            if record is not None and record.failed:
                line += f"  [failed: {_point_label(record)}: {record.message}]"
            self.stream.write(line + "\n")
        self.stream.flush()

    def _eta(self, elapsed, computed, remaining, workers) -> float:
        if remaining == 0:
            return 0.0
        if self.walls and workers:
            # mean run time per point, the remaining points shared by the workers; better than
            # elapsed/computed early on, when the first points of all workers finish together
            walls = [w for w in self.walls if math.isfinite(w)]
            if walls:
                return sum(walls) / len(walls) * math.ceil(remaining / workers)
        return elapsed / computed * remaining if computed else float("nan")

    def close(self) -> None:
        if self.tty and self.started:
            self.stream.write("\n")
            self.stream.flush()


def _point_label(record) -> str:
    p = record.params or {}
    return " ".join(f"{n}={p.get(n, float('nan')):g}" for n in SWEPT)


def _fmt(v, width: int = 8, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return f"{'--':>{width}}"
    return f"{v:{width}.{digits}f}"


def summary_table(outcome, max_rows: int = 40) -> str:
    """A plain-text table of the points (parameters, status, IOPg, CH, DA, wall time) and totals.

    At most ``max_rows`` rows are printed (failed points first); the rest is in ``sweep.nc``.
    """
    head = "  ".join(f"{n + ' [' + PARAMETERS[n].unit + ']':>14s}" for n in SWEPT)
    head += "  status " + "".join(f"{m + ' [' + u + ']':>13s}" for m, u in TABLE_METRICS)
    head += f"{'wall [s]':>10s}  note"
    lines = [head, "-" * len(head)]
    records = [r for r in outcome.records if r is not None]
    ordered = [r for r in records if r.failed] + [r for r in records if not r.failed]
    for rec in ordered[:max_rows]:
        p = rec.params or {}
        row = "  ".join(f"{p.get(n, float('nan')):14.4g}" for n in SWEPT)
        row += f"  {rec.status:6s} "
        metrics = rec.metrics or {}
        row += "".join(f"{_fmt(metrics.get(m), 13)}" for m, _ in TABLE_METRICS)
        row += f"{_fmt(rec.wall_s, 10, 1)}"
        note = "" if rec.computed else "(stored) "
        note += rec.message or ""
        if len(note) > 90:
            note = note[:87] + "..."
        lines.append(row + "  " + note)
    if len(ordered) > max_rows:
        lines.append(f"... {len(ordered) - max_rows} more points in {outcome.path}")
    lines.append("")
    lines.append(f"{outcome.n_points} points: {outcome.ok} ok, {outcome.failed} failed; "
                 f"{outcome.computed} computed now, {outcome.reused} already stored; "
                 f"wall {_clock(outcome.wall_s)}"
                 + (f" (Numba warm-up {outcome.warmup_s:.1f} s)" if outcome.warmup_s is not None else ""))
    lines.append(f"model version {outcome.model_version} (stored points of other versions are "
                 "not reused)")
    lines.append(f"wrote {outcome.path}")
    return "\n".join(lines)
