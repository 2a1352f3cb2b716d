"""Convergence of P1, P2, CH, DA, t_A1, t_A2 with resolution (coarse, paper, fine).

    python -m studies.convergence --out conv            # coarse, paper and fine, in sequence
    python -m studies.convergence --out conv --reuse    # read back finished runs
    python -m studies.convergence --out conv_hv02 --set hyperviscosity=0.2

Each resolution is one ``simulate(RunParams(resolution=...))`` call in this process (the fine run
takes the longest; run it once).  Writes ``<out>/convergence.csv`` and ``.json``, keeps each run's
netCDF in ``<out>`` and prints a markdown table with the observed order

    p = log(|m_coarse - m_paper| / |m_paper - m_fine|) / log(r),
    r = h_coarse/h_paper ~ h_paper/h_fine

where it is defined (the two differences have the same sign and neither is zero), and the
Richardson estimate m_fine + (m_fine - m_paper)/(r^p - 1) of the converged value where p >= 0.5
(a smaller p means the three runs are not yet in the asymptotic range).
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from airpuff_core import RunParams
from airpuff_core.geometry import build_chamber
from studies.common import PAPER, SHOWN, UNITS, fmt, run_variant, write_tables

LEVELS = ("coarse", "paper", "fine")


def spacing(params: RunParams) -> float:
    """Largest fluid node spacing h [mm] of the run's chamber (no simulation)."""
    si = params.si()
    ch = build_chamber(params.geometry, params.layout, params.resolution, si.R_m, si.r_post_m,
                       si.alpha0_rad)
    return float(ch.h.max() * 1e3)


def observed_order(mc, mp, mf, r):
    d1, d2 = mc - mp, mp - mf
    if not all(math.isfinite(v) for v in (mc, mp, mf)) or d1 == 0 or d2 == 0:
        return math.nan, math.nan, "undefined"
    if d1 * d2 < 0:
        return math.nan, math.nan, "oscillatory"
    p = math.log(abs(d1) / abs(d2)) / math.log(r)
    rich = mf + (mf - mp) / (r ** p - 1.0) if p >= 0.5 else math.nan
    return p, rich, "monotone"


def markdown(rows: list[dict], hs: dict, r: float, changed: bool = False) -> str:
    by = {row["resolution"]: row for row in rows}
    ok = all(lvl in by and by[lvl]["status"] == "ok" for lvl in LEVELS)
    head = "Parameters: the defaults with the change above; " if changed else "Default parameters; "
    lines = [head
             + ", ".join(f"{lvl} h = {hs[lvl]:.4f} mm ({by[lvl].get('n_fluid', math.nan):.0f} "
                         f"fluid nodes)" for lvl in LEVELS if lvl in by)
             + f"; refinement ratio r = {r:.3f}.", ""]
    lines.append("| metric | coarse | paper | fine | paper - fine | observed order p | "
                 "Richardson | paper (Montanino et al.) |")
    lines.append("|---|---|---|---|---|---|---|---|")
    for k in SHOWN:
        nd = 3 if k == "DA" else 2
        vals = [by[lvl][k] if lvl in by and by[lvl]["status"] == "ok" else math.nan
                for lvl in LEVELS]
        if ok:
            p, rich, kind = observed_order(*vals, r)
            ptxt = fmt(p, 2) if math.isfinite(p) else kind
            diff = f"{vals[1] - vals[2]:+.{nd + 1}f}"
        else:
            ptxt, rich, diff = "-", math.nan, "-"
        lines.append(f"| {k} [{UNITS[k]}] | " + " | ".join(fmt(v, nd) for v in vals)
                     + f" | {diff} | {ptxt} | {fmt(rich, nd)} | {fmt(PAPER[k], 2)} |")
    lines.append("")
    lines.append("| resolution | steps | mean dt [us] | wall [s] | status |")
    lines.append("|---|---|---|---|---|")
    for lvl in LEVELS:
        if lvl in by:
            row = by[lvl]
            lines.append(f"| {lvl} | {fmt(row.get('steps', math.nan), 0)} | "
                         f"{fmt(row.get('dt_mean_us', math.nan), 3)} | "
                         f"{fmt(row.get('wall_s', math.nan), 0)} | {row['status']} "
                         f"{row.get('message', '')} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="output folder (netCDF per run, CSV, JSON)")
    ap.add_argument("--levels", default=",".join(LEVELS),
                    help="comma-separated resolutions to run (default all three)")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="change a default parameter for all three runs (e.g. hyperviscosity=0.2)")
    ap.add_argument("--reuse", action="store_true",
                    help="read back runs whose netCDF exists with the same parameters")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    levels = args.levels.split(",")
    changes = {}
    for item in args.set:
        name, _, value = item.partition("=")
        try:
            changes[name] = float(value)
        except ValueError:
            changes[name] = value
    base = RunParams().replace(**changes)
    hs = {lvl: spacing(base.replace(resolution=lvl)) for lvl in LEVELS}
    r = math.sqrt(hs["coarse"] / hs["fine"])  # geometric mean of the two refinement ratios
    rows = []
    t0 = time.perf_counter()
    for lvl in levels:
        rows.append(run_variant(lvl, base.replace(resolution=lvl), out, args.reuse))
        rows[-1]["h_mm"] = hs[lvl]
        write_tables(rows, out, "convergence")
    md = markdown(rows, hs, r, bool(changes))
    if changes:
        md = "Changed from the defaults: " + ", ".join(f"{k} = {v}" for k, v in changes.items()) \
            + ".\n\n" + md
    (out / "convergence.md").write_text(md + "\n")
    print(md)
    print(f"\n{len(rows)} runs in {time.perf_counter() - t0:.0f} s; tables in {out}/convergence.*")


if __name__ == "__main__":
    main()
