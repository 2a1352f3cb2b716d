"""``airpuff correct``: a corrected IOP and a stiffness index fitted on a sweep, applied to
measurements, and the sweep's global sensitivity analysis.

    airpuff correct fit --sweep sweep.nc --instrument ora --out correction.json
    airpuff correct apply --correction correction.json --measurements eyes.csv [--json]
    airpuff correct sensitivity --sweep sweep.nc [--json]

Bad input exits with code 2 and one line naming it; ``apply`` exits 1 when some rows could not be
used (each has its message; the other rows are corrected).  docs/correction.md has the method.
"""

from __future__ import annotations

import csv
import json
import math
import sys

from sweep.correction import (FOLDS, INSTRUMENTS, MAX_DEGREE, SEED, Correction, CorrectionError,
                              accepted_columns, apply_rows, read_measurements)

PROG = "airpuff correct"


def add_correct_parser(sub) -> None:
    """Register ``correct`` (with its sub-commands fit, apply, sensitivity) on ``airpuff``."""
    p = sub.add_parser("correct", help="fit a corrected IOP on a sweep, apply it, sensitivity",
                       description=(
        "Fit the true IOP and a stiffness index (E0) as polynomials of what an instrument "
        "reads, on a stored sweep (degree by cross-validation); apply such a formula to a CSV "
        "of measurements; or compute the Sobol indices of every metric over a sweep."))
    actions = p.add_subparsers(dest="action", metavar="ACTION", parser_class=type(p))
    actions.required = True

    f = actions.add_parser("fit", help="fit a correction formula on a sweep", description=(
        "Fit the true IOP and E0 as polynomials of the instrument's readings on the points of "
        "a combined sweep.nc; the degree is chosen by k-fold cross-validation. The readings are "
        "the model's raw ones (no instrument calibration yet)."))
    f.add_argument("--sweep", required=True, metavar="SWEEP_NC", help="combined sweep.nc")
    f.add_argument("--instrument", required=True, metavar="|".join(INSTRUMENTS),
                   help="ora: P1, P2 [mmHg], CCT [um]; corvis: IOPnc [mmHg] (raw P1), CCT "
                        "[um], DA [mm]")
    f.add_argument("--out", required=True, metavar="JSON", help="the correction file to write")
    f.add_argument("--pmax", default=None, metavar="kPa",
                   help="the jet amplitude to fit at, if the sweep has several")
    f.add_argument("--max-degree", default=str(MAX_DEGREE), metavar="D",
                   help=f"highest polynomial degree tried, 1 to 4 (default {MAX_DEGREE})")
    f.add_argument("--folds", default=str(FOLDS), metavar="K",
                   help=f"folds of the cross-validation, 2 to 20 (default {FOLDS})")
    f.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    f.set_defaults(func=fit_command)

    a = actions.add_parser("apply", help="apply a correction to measurements", description=(
        "Read a CSV of measurements (a header row; column names as the correction file lists "
        "them, e.g. P1, P2 in mmHg and CCT in um for the ORA; optional sigma columns P1_sigma "
        "...; an optional id column) and print the corrected IOP and the stiffness index of "
        "each row with its 1-sigma uncertainty. Rows outside the fitted range are flagged; bad "
        "rows get a message and do not stop the others."))
    a.add_argument("--correction", required=True, metavar="JSON",
                   help="a file written by `airpuff correct fit`")
    a.add_argument("--measurements", required=True, metavar="CSV", help="the measurements ('-': stdin)")
    a.add_argument("--json", action="store_true", help="print one JSON object")
    a.set_defaults(func=apply_command)

    s = actions.add_parser("sensitivity", help="Sobol indices of every metric over a sweep",
                           description=(
        "Fit a polynomial surrogate of each metric over the swept parameters (degree by "
        "cross-validation) and compute its first-order and total Sobol indices with SALib "
        "(Saltelli sampling of the surrogate over the sweep's box, uniform)."))
    s.add_argument("--sweep", required=True, metavar="SWEEP_NC", help="combined sweep.nc")
    s.add_argument("--metrics", default=None, metavar="LIST",
                   help="comma list of metrics (default: every metric the sweep has)")
    s.add_argument("--samples", default="1024", metavar="N",
                   help="SALib base sample size N, a power of 2 from 64 to 65536 (default 1024)")
    s.add_argument("--max-degree", default=str(MAX_DEGREE), metavar="D",
                   help=f"highest surrogate degree tried, 1 to 4 (default {MAX_DEGREE})")
    s.add_argument("--json", action="store_true", help="print one JSON object")
    s.set_defaults(func=sensitivity_command)


def _whole(name: str, text, low: int, high: int) -> int:
    try:
        n = int(str(text))
    except ValueError:
        n = low - 1
    if not low <= n <= high:
        raise CorrectionError(name, f"invalid --{name} {text!r}: accepted a whole number from "
                                    f"{low} to {high}")
    return n


def _number(name: str, text) -> float | None:
    if text is None:
        return None
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        raise CorrectionError(name, f"invalid --{name} {text!r}: accepted a finite number")
    return v


def _fail(err: Exception) -> int:
    print(f"{PROG}: error: {' '.join(str(err).split())}", file=sys.stderr)
    return 2


def fit_command(args) -> int:
    from sweep.correction import fit_correction, sweep_sources
    from sweep.identification import MEASURABLE, IdentifyError, SweepTable

    try:
        if args.instrument not in INSTRUMENTS:
            raise CorrectionError("instrument", f"invalid --instrument {args.instrument!r}: "
                                                "accepted " + " or ".join(INSTRUMENTS))
        max_degree = _whole("max-degree", args.max_degree, 1, 4)
        folds = _whole("folds", args.folds, 2, 20)
        pmax = _number("pmax", args.pmax)
        names = tuple(dict.fromkeys((*MEASURABLE, *sweep_sources(args.instrument))))
        table = SweepTable.from_netcdf(args.sweep, names)
        d = fit_correction(table, args.instrument, max_degree, folds, SEED, pmax,
                           sweep_name=str(args.sweep).replace("\\", "/").rsplit("/", 1)[-1])
        with open(args.out, "w", encoding="utf-8") as f:
            json.dump(d, f, indent=1)
            f.write("\n")
    except (CorrectionError, IdentifyError) as err:
        return _fail(err)
    except OSError as err:
        return _fail(f"cannot write --out {args.out!r}: {err.strerror or err}")
    summary = fit_summary(d, args.out)
    if args.json:
        print(json.dumps(summary))
    else:
        print(format_fit_summary(summary))
    return 0


def fit_summary(d: dict, path: str) -> dict:
    return {"path": str(path), "instrument": d["instrument"], "calibration": d["calibration"],
            "used": d["sweep"]["used"], "excluded_failed": d["sweep"]["excluded_failed"],
            "excluded_no_reading": d["sweep"]["excluded_no_reading"],
            "targets": {t: {"degree": td["degree"], "held_out_rms": td["held_out"]["rms"],
                            "unit": td["unit"], "formula": td["formula"]}
                        for t, td in d["targets"].items()},
            "validation": d["validation"]}


def format_fit_summary(s: dict) -> str:
    lines = [f"{s['instrument']} correction ({s['calibration']} readings) written to {s['path']}",
             f"points used {s['used']}, left out: {s['excluded_failed']} failed, "
             f"{s['excluded_no_reading']} without a reading (no applanation)"]
    for t, td in s["targets"].items():
        lines.append(f"{t}: degree {td['degree']}, held-out RMS {td['held_out_rms']:.3g} "
                     f"{td['unit']}")
    v = s["validation"]
    c, r = v["corrected_IOP"]["slopes_of_error_mmHg"], v["raw_reading"]["slopes_of_error_mmHg"]

    def fmt(x):
        return "n/a" if x is None else f"{x:+.3f}"

    lines.append(f"slope of the IOP error per 100 um CCT: corrected {fmt(c['per_100um_CCT'])}, "
                 f"raw {fmt(r['per_100um_CCT'])} mmHg; per 0.1 MPa E0: corrected "
                 f"{fmt(c['per_0.1MPa_E0'])}, raw {fmt(r['per_0.1MPa_E0'])} mmHg "
                 f"(raw: {v['raw_reading']['name']})")
    rho = v["stiffness_index"]["spearman_with_true_E0"]
    lines.append(f"stiffness index vs true E0: Spearman {fmt(rho)} (held-out)")
    return "\n".join(lines)


OUTPUT_COLUMNS = ("row", "id", "status", "IOP", "IOP_sigma", "E0", "E0_sigma", "message")


def apply_command(args) -> int:
    try:
        correction = Correction.load(args.correction)
        try:
            if args.measurements == "-":
                text = sys.stdin.read()
            else:
                with open(args.measurements, encoding="utf-8", newline="") as f:
                    text = f.read()
        except FileNotFoundError:
            raise CorrectionError("measurements", f"measurements file {args.measurements!r} "
                                                  "not found") from None
        except (OSError, UnicodeDecodeError) as err:
            raise CorrectionError("measurements", f"cannot read measurements file "
                                  f"{args.measurements!r}: {type(err).__name__}") from None
        rows = read_measurements(text, correction)
    except CorrectionError as err:
        return _fail(err)
    except csv.Error as err:
        return _fail(f"measurements file {args.measurements!r} is not a readable CSV: {err}")
    results = apply_rows(correction, rows)
    n_bad = sum(r["status"] == "error" for r in results)
    if args.json:
        print(json.dumps({"instrument": correction.data["instrument"],
                          "calibration": correction.data["calibration"],
                          "units": {"IOP": "mmHg", "E0": "MPa"},
                          "accepted_columns": accepted_columns(correction),
                          "rows": results, "n_rows": len(results), "n_error": n_bad,
                          "n_outside": sum(r["status"] == "outside" for r in results)}))
    else:
        w = csv.writer(sys.stdout, lineterminator="\n")
        w.writerow([c if c not in ("IOP", "IOP_sigma") else c + "_mmHg" for c in OUTPUT_COLUMNS[:5]]
                   + ["E0_MPa", "E0_sigma_MPa", "message"])
        for r in results:
            msg = r.get("error") or "; ".join(r.get("flags") or [])
            w.writerow([r["row"], r["id"] or "", r["status"],
                        *(f"{r[k]:.4g}" if r.get(k) is not None else ""
                          for k in ("IOP", "IOP_sigma", "E0", "E0_sigma")), msg])
    for r in results:
        if r["status"] == "error":
            print(f"{PROG}: row {r['row']}: {r['error']}", file=sys.stderr)
    return 1 if n_bad else 0


def sensitivity_command(args) -> int:
    from airpuff_core.result import METRICS
    from sweep.identification import IdentifyError, SweepTable
    from sweep.sensitivity import format_indices, sobol_indices

    try:
        if args.metrics:
            metrics = [m.strip() for m in args.metrics.split(",") if m.strip()]
            bad = [m for m in metrics if m not in METRICS]
            if bad or not metrics:
                raise CorrectionError("metrics", f"invalid --metrics {args.metrics!r}: accepted "
                                                 "a comma list of " + ", ".join(METRICS))
        else:
            metrics = None  # every metric the sweep has
        n = _whole("samples", args.samples, 64, 65536)
        if n & (n - 1):
            raise CorrectionError("samples", f"invalid --samples {args.samples!r}: accepted a "
                                             "power of 2 from 64 to 65536")
        max_degree = _whole("max-degree", args.max_degree, 1, 4)
        table = SweepTable.from_netcdf(args.sweep, None if metrics is None else tuple(metrics))
        result = sobol_indices(table, metrics, n_base=n, max_degree=max_degree)
    except (CorrectionError, IdentifyError) as err:
        return _fail(err)
    if args.json:
        print(json.dumps(result))
    else:
        print(format_indices(result))
    return 0
