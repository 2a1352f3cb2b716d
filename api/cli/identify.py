"""``airpuff identify``: estimate IOP and E0 from a measurement, using a stored sweep.nc.

Measured values are given as ``--P1 VALUE`` or ``--P1 VALUE+-SIGMA`` (one token, e.g.
``--DA 1.05+-0.03``); without a sigma the default uncertainty of
``sweep.identification.DEFAULT_SIGMA``
is used.  Bad input and measurements outside the sweep exit with code 2 and one line.
"""

from __future__ import annotations

import json
import re
import sys

from airpuff_core.params import CHOICES, parse_decimal, parse_whole
from sweep.identification import (DEFAULT_SIGMA, MEASURABLE, SCALE, UNITS, IdentifyError,
                                  SweepTable, identify, measurement_scale, refine)

_VALUE_RE = re.compile(r"^\s*([^+±]+?)\s*(?:(?:\+-|\+/-|±)\s*(\S+))?\s*$")


def parse_measured(name: str, text: str) -> tuple[float, float]:
    m = _VALUE_RE.match(str(text))
    try:
        if not m:
            raise ValueError
        value = parse_decimal(m.group(1))
        sigma = parse_decimal(m.group(2)) if m.group(2) is not None else DEFAULT_SIGMA[name]
    except ValueError:
        raise IdentifyError(name, f"invalid --{name} {text!r}: accepted VALUE or VALUE+-SIGMA "
                                  f"in {UNITS[name]} (e.g. --{name} "
                                  f"{'17.5+-0.3' if UNITS[name] == 'mmHg' else '1.0+-0.05'})") from None
    return value, sigma


def _number(name: str, text):
    if text is None:
        return None
    try:
        return parse_decimal(str(text))
    except ValueError:
        raise IdentifyError(name, f"invalid --{name} {text!r}: accepted a number "
                                  f"[{UNITS[name]}]") from None


def add_identify_parser(sub) -> None:
    """Register ``identify`` on the ``airpuff`` parser."""
    p = sub.add_parser("identify", help="estimate IOP and E0 from a measurement using a sweep",
                       description=(
        "Estimate the true IOP and the corneal stiffness E0 from measured pressures [mmHg] on "
        "one scale (the raw P1, P2 of the model, or the calibrated P1_cal, P2_cal, IOPg_cal, "
        "CH_cal that an instrument prints, which need the sweep's calibration), DA [mm], t_A1, "
        "t_A2 [ms] (any subset), by interpolation on a stored sweep. Reports the estimate "
        "and the 68 % joint confidence region (chi2 <= min + 2.30). A measurement outside what "
        "the sweep covers exits with code 2 (no extrapolation)."))
    p.add_argument("--sweep", required=True, metavar="SWEEP_NC",
                   help="the combined sweep.nc of `airpuff sweep` (dims E0, IOP, thickness, pmax)")
    p.add_argument("--thickness", default=None, metavar="mm",
                   help="corneal thickness [mm]; needed if the sweep has several; between two "
                        "grid values the metrics are interpolated linearly")
    p.add_argument("--pmax", default=None, metavar="kPa",
                   help="peak jet pressure [kPa]; needed if the sweep has several")
    p.add_argument("--instrument", default=None, metavar="|".join(CHOICES["instrument"]),
                   help="the instrument the measurement was taken with; it must be the one "
                        "whose pulse the sweep was computed with (default: the sweep's)")
    for name in MEASURABLE:
        flags = ["--" + name] + (["--" + name.replace("_", "-")] if "_" in name else [])
        p.add_argument(*flags, dest=name, default=None, metavar="VALUE[+-SIGMA]",
                       help=f"measured {name} [{UNITS[name]}], optional 1-sigma uncertainty "
                            f"(default sigma {DEFAULT_SIGMA[name]:g} {UNITS[name]})")
    p.add_argument("--refine", action="store_true",
                   help="refine the estimate with direct solver runs at the sweep's run options "
                        "(Gauss-Newton; at most --refine-runs runs, ~10-15 s each at coarse)")
    p.add_argument("--refine-runs", default="7", metavar="N",
                   help="maximum solver runs of --refine, 4 to 9 (default 7)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=identify_command)


def _fmt_interval(a: tuple[float, float], digits: int) -> str:
    return f"[{a[0]:.{digits}f}, {a[1]:.{digits}f}]"


def identify_command(args) -> int:
    prog = "airpuff identify"
    try:
        meas = {name: parse_measured(name, getattr(args, name)) for name in MEASURABLE
                if getattr(args, name) is not None}
        if not meas:
            raise IdentifyError("measurement", "no measured quantity given; give at least one of "
                                + ", ".join("--" + n for n in MEASURABLE))
        try:
            max_runs = parse_whole(str(args.refine_runs))
        except ValueError:
            max_runs = -1
        if not 4 <= max_runs <= 9:
            raise IdentifyError("refine-runs", f"invalid --refine-runs {args.refine_runs!r}: "
                                               "accepted a whole number from 4 to 9")
        thickness = _number("thickness", args.thickness)
        pmax = _number("pmax", args.pmax)
        table = SweepTable.from_netcdf(args.sweep)
        est = identify(table, meas, thickness, pmax, args.instrument)
        if args.refine:
            progress = None if args.json else (lambda s: print(s, file=sys.stderr, flush=True))
            est = refine(table, est, max_runs=max_runs, progress=progress)
    except IdentifyError as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        return 2
    except Exception as err:  # the solver failing during --refine, etc.: one line, no traceback
        print(f"{prog}: error: {type(err).__name__}: {err}".splitlines()[0], file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(est.to_dict()))
        return 0
    d = est.to_dict()
    print(f"method: {est.method}; instrument {est.instrument}, thickness {est.thickness:g} mm, "
          f"pmax {est.pmax:g} kPa")
    print("measurement: " + ", ".join(f"{k} = {v:g} +- {s:g} {UNITS[k]}"
                                      for k, (v, s) in est.measurement.items()))
    scale = measurement_scale(est.measurement)
    if scale is not None:
        print(f"scale: {SCALE[scale]}")
    print(f"IOP = {est.IOP:.2f} mmHg   68 % interval {_fmt_interval(est.IOP_interval, 2)}"
          + ("" if est.IOP_identified else "  (not identified)"))
    print(f"E0  = {est.E0:.3f} MPa    68 % interval {_fmt_interval(est.E0_interval, 3)}"
          + ("" if est.E0_identified else "  (not identified)"))
    print(f"chi2_min = {est.chi2_min:.3g} for {len(est.measurement)} measured value(s); "
          f"sweep covers IOP {d['sweep_range']['IOP'][0]:g}-{d['sweep_range']['IOP'][1]:g} mmHg, "
          f"E0 {d['sweep_range']['E0'][0]:g}-{d['sweep_range']['E0'][1]:g} MPa")
    for note in est.notes:
        print("note: " + note)
    return 0
