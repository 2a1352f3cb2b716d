"""The sweep's terminal output: progress lines and the summary table (no solver needed)."""

from __future__ import annotations

import io
from pathlib import Path

from sweep.record import PointRecord
from sweep.report import SweepProgress, summary_table
from sweep.runner import SweepOutcome


def _record(e0, status, wall, da=None, message=""):
    return PointRecord(key=f"k{e0}", status=status, message=message, wall_s=wall, computed=True,
                       params={"E0": e0, "IOP": 16.0, "thickness": 0.5, "pmax": 10.0},
                       metrics={"IOPg": None, "CH": None, "DA": da})


def test_progress_counts_failures_and_estimates_the_rest():
    out = io.StringIO()
    bar = SweepProgress(stream=out, tty=False)
    counts = {"total": 4, "done": 1, "failed": 0, "computed": 0, "reused": 1, "workers": None}
    bar(None, counts)
    counts.update(done=2, computed=1, workers=2)
    bar(_record(0.4, "ok", 10.0, 0.9), counts)
    counts.update(done=3, computed=2, failed=1)
    bar(_record(0.5, "failed", 2.0, message="blew up at t = 3 ms"), counts)
    lines = out.getvalue().splitlines()
    assert len(lines) == 3
    assert "1/4 points, 0 failed, 1 stored" in lines[0]
    assert "2/4 points" in lines[1]
    # mean run time 6 s, 1 point left for 2 workers -> one more round of 6 s
    assert "3/4 points, 1 failed" in lines[2] and "eta 00:06" in lines[2]
    assert "failed: E0=0.5 IOP=16 thickness=0.5 pmax=10: blew up at t = 3 ms" in lines[2]


def test_summary_table_lists_failures_first_and_totals():
    recs = [_record(0.4, "ok", 10.0, 0.91234), _record(0.5, "failed", 2.0, message="no convergence")]
    outcome = SweepOutcome(n_points=2, computed=2, reused=0, failed=1, path=Path("x/sweep.nc"),
                           out_dir=Path("x"), wall_s=65.0, warmup_s=1.5, records=recs)
    text = summary_table(outcome)
    rows = text.splitlines()
    assert "E0 [MPa]" in rows[0] and "DA [mm]" in rows[0]
    assert "failed" in rows[2] and "no convergence" in rows[2]
    assert "ok" in rows[3] and "0.912" in rows[3]
    assert "2 points: 1 ok, 1 failed; 2 computed now, 0 already stored; wall 01:05" in text
    assert text.rstrip().endswith("wrote x/sweep.nc")
