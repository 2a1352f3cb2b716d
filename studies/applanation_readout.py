"""Applanation read-outs of the clinical preset against the artificial sound speed and the IOP.

The paper's read-out finds the applanations as sign changes of the apex curvature (an even quartic
fit over r <= 0.6 mm; docs/model.md section 7).  Where the apex creeps through flat, P2 moves by
several mmHg for 0.01/mm of curvature (docs/validation.md, "What moves P2 with c").  This study
records, after every solver step, the cornea's nodes within ``PROFILE_RADIUS_MM`` of the axis and
evaluates post hoc the read-outs of ``airpuff_core.readout`` (docs/model.md section 7):

- ``kappa``: the paper's (the run's own P1, P2);
- ``ora``: the peaks of the ORA's reflection signal (the fraction of the light reflected from the
  central zone that reaches the detector), each zone radius and acceptance of ``--ora``;
- ``corvis``: the minima of the central cornea's departure from flat over the applanation length
  (the Scheimpflug section), each length of ``--corvis``.

For each run and read-out: t_A1, t_A2, P1, P2 (the pulse's apex pressure at those times); per
IOP the largest change from the first c0; and, over the IOPs, the residual of the linear
calibration IOPg_cal = a + b IOPg (``calibration.py``'s map; meaningful over an IOP sweep such as
``--IOP 10,12.5,...,30`` with ``--c0 10``).

    python -m studies.applanation_readout --out <folder>
    python -m studies.applanation_readout --out <folder> --resolution coarse \\
        --c0 10 --IOP 10,12.5,15,17.5,20,22.5,25,27.5,30 --set instrument=ora --set thickness=0.52

Every run's step record is kept as <out>/<name>.npz (``--reuse`` reads it back when its
parameters match); the tables go to <out>/table.md and the rows to <out>/rows.json.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from airpuff_core import RunParams, SimulationError
from airpuff_core.solver import simulate
from airpuff_core.calibration import apply_coefficients, fit_coefficients
from airpuff_core.params import MMHG_PA
from airpuff_core.readout import corvis_departure, ora_signal, signal_applanations
from studies.clinical_sound_speed import sound_speed_parser, sound_speed_points

PROFILE_RADIUS_MM = 2.5  # mm: the nodes recorded (reference x), beyond any zone evaluated here


class ProfileRecorder:
    """After every committed step: the time [ms] and the positions x, y [mm] of the cornea's
    nodes whose reference x is within PROFILE_RADIUS_MM of the axis."""

    def __init__(self, model):
        self.model = model
        self.n = int(np.searchsorted(model.X, PROFILE_RADIUS_MM * 1e-3, side="right")) + 1
        self.t, self.x, self.y = [], [], []
        self.committed(model, 0.0)

    def coupled(self, model, dt):
        pass

    def committed(self, model, dt):
        self.t.append(model.t * 1e3)
        self.x.append(model.X[:self.n] * 1e3)
        self.y.append(model.Y[:self.n] * 1e3)


def record(params: RunParams, npz: Path, reuse: bool) -> dict:
    """The run's step record (from ``npz`` when ``reuse`` and its parameters match)."""
    if reuse and npz.exists():
        data = np.load(npz, allow_pickle=False)
        if json.loads(str(data["params"])) == params.to_dict():
            return {k: data[k] for k in data.files}
    holder = []

    def make(model):
        holder.append(ProfileRecorder(model))
        return holder[-1]

    t0 = time.perf_counter()
    result = simulate(params, observers=(make,))
    rec = holder[0]
    t = np.array(rec.t)
    jet = np.array([rec.model.jet.at_apex(ti * 1e-3) for ti in t]) / MMHG_PA
    m = result.metrics
    data = {"params": json.dumps(params.to_dict()), "t": t, "x": np.array(rec.x),
            "y": np.array(rec.y), "jet": jet,
            "kappa": np.array([m["t_A1"], m["t_A2"], m["P1"], m["P2"]]),
            "t_HC": np.array(m["t_HC"]), "wall_s": np.array(time.perf_counter() - t0)}
    np.savez(npz, **data)
    return data


def readouts(data, ora_settings, corvis_lengths) -> dict:
    """{read-out name: (t_A1, t_A2, P1, P2)} of one run's step record."""
    t, x, y, jet = data["t"], data["x"], data["y"], data["jet"]
    out = {"kappa": tuple(float(v) for v in data["kappa"])}
    t_hc = float(data["t_HC"])

    def at(ti):
        return float(np.interp(ti, t, jet)) if math.isfinite(ti) else math.nan

    for r_zone, acceptance in ora_settings:
        s = np.array([ora_signal(x[k], y[k], r_zone, acceptance) for k in range(t.shape[0])])
        t1, t2 = signal_applanations(t, s, t_hc)
        out[f"ora r{r_zone:g} a{acceptance:g}"] = (t1, t2, at(t1), at(t2))
    for length in corvis_lengths:
        s = -np.array([corvis_departure(x[k], y[k], length) for k in range(t.shape[0])])
        t1, t2 = signal_applanations(t, s, t_hc, passages=False)
        out[f"corvis L{length:g}"] = (t1, t2, at(t1), at(t2))
    return out


def calibration_residual(iops, p1, p2):
    """Largest |IOPg_cal - IOP| over the sweep with the calibration's linear map fitted on it
    (``calibration.fit_coefficients``); NaN with fewer than three points of both P1 and P2."""
    iops, p1, p2 = (np.asarray(v, float) for v in (iops, p1, p2))
    ok = np.isfinite(p1) & np.isfinite(p2)
    if ok.sum() < 3:
        return math.nan
    coef = fit_coefficients(iops[ok], p1[ok], p2[ok])
    return float(np.max(np.abs(apply_coefficients(coef, p1[ok], p2[ok])["IOPg_cal"] - iops[ok])))


def main(argv=None):
    ap = sound_speed_parser(__doc__.splitlines()[0], "coarse")
    ap.add_argument("--ora", default="1.53:0.02,1:0.02,1:0.05,1.53:0.05",
                    help="ORA zone radius [mm]:acceptance [rad] pairs")
    ap.add_argument("--corvis", default="1.82,1.34", help="Corvis applanation lengths [mm]")
    args = ap.parse_args(argv)
    c0s = [float(v) for v in args.c0.split(",")]
    iops = [float(v) for v in args.IOP.split(",")]
    ora_settings = [tuple(float(v) for v in s.split(":")) for s in args.ora.split(",")]
    corvis_lengths = [float(v) for v in args.corvis.split(",")]
    extra = dict(s.split("=", 1) for s in args.set)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = {}
    for name, params in sound_speed_points(iops, c0s, args.resolution, extra):
        try:
            data = record(params, args.out / f"{name}.npz", args.reuse)
        except SimulationError as err:
            rows[name] = {"status": "failed", "message": str(err)}
            print(name, rows[name], flush=True)
            continue
        rows[name] = {"status": "ok", "wall_s": float(data["wall_s"]),
                      **{k: list(v) for k, v in readouts(data, ora_settings,
                                                         corvis_lengths).items()}}
        print(name, json.dumps(rows[name]), flush=True)
        (args.out / "rows.json").write_text(json.dumps(rows, indent=1))
    text = table(rows, c0s, iops)
    (args.out / "table.md").write_text(text)
    print(text)


def table(rows, c0s, iops) -> str:
    names = next((list(k for k in r if k not in ("status", "wall_s")) for r in rows.values()
                  if r["status"] == "ok"), [])
    lines = ["| read-out | IOP | " + " | ".join(f"P1, P2 (c0 {c:g})" for c in c0s)
             + " | P1 change | P2 change |", "|" + "---|" * (len(c0s) + 4)]
    for name in names:
        for iop in iops:
            rs = [rows[f"IOP{iop:g}_c{c:g}"] for c in c0s]
            if any(r["status"] != "ok" for r in rs):
                lines.append(f"| {name} | {iop:g} | " + " | ".join(
                    r.get("message", "")[:40] for r in rs) + " | | |")
                continue
            vals = [r[name] for r in rs]
            d1 = max(abs(v[2] - vals[0][2]) for v in vals)
            d2 = max(abs(v[3] - vals[0][3]) for v in vals)
            lines.append(f"| {name} | {iop:g} | " + " | ".join(
                f"{v[2]:.2f}, {v[3]:.2f} ({v[0]:.2f}, {v[1]:.2f} ms)" for v in vals)
                + f" | {d1:.3f} | {d2:.3f} |")
    lines += ["", "Calibration residual over the IOPs (max |a + b IOPg - IOP|, mmHg):", "",
              "| read-out | " + " | ".join(f"c0 {c:g}" for c in c0s) + " |",
              "|" + "---|" * (len(c0s) + 1)]
    for name in names:
        res = []
        for c in c0s:
            rs = [rows[f"IOP{iop:g}_c{c:g}"] for iop in iops]
            if any(r["status"] != "ok" for r in rs):
                res.append("failed")
                continue
            res.append("%.3f" % calibration_residual(iops, [r[name][2] for r in rs],
                                                     [r[name][3] for r in rs]))
        lines.append(f"| {name} | " + " | ".join(res) + " |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
