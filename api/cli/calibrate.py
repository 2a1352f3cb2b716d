"""`airpuff calibrate`: an instrument's calibration fitted on the model's own IOP sweep at the
reference eye, written beside the package's calibrations (docs/calibration.md).

    airpuff calibrate --instrument paper --model clinical --resolution paper --check \\
        --out calibration_sweeps/paper --figure calibration.png

The reference sweep (IOP 10 to 30 in 2.5 mmHg by default, ``--IOP``) runs on a local Dask
cluster (``--workers``, as `airpuff sweep`; its points are stored in ``--out`` and a repeated
command reuses them) or one point after the other in this process (``--in-process``).
``--check`` adds the sweeps over CCT and E0 at IOP 16 and records the slopes of the raw and the
calibrated IOPg in the file.  The file is keyed by instrument, model version and resolution;
runs of another model version get no calibrated readings until the command is run again.

Exit codes: 0 calibration written (``--check``: and the calibrated IOPg within 0.3 mmHg of the
true IOP at the reference eye); 1 a reference point without both applanations (nothing
written), or the check's tolerance missed (the file is written, the miss printed); 2 bad input
(one line naming the parameter and its accepted values).
"""

from __future__ import annotations

import json
import sys

from airpuff_core.params import CHOICES, PARAMETERS, ParameterError

from .common import RUN_OPTIONS, add_run_options, escape_percent, fail, parse_whole

PROG = "airpuff calibrate"
DEFAULT_OUT = "calibration_sweeps"


def add_calibrate_parser(sub) -> None:
    """Register the ``calibrate`` sub-command on the ``airpuff`` parser."""
    from airpuff_core.calibration import REFERENCE_EYE

    p = sub.add_parser("calibrate", help="fit an instrument's calibration on the model's IOP sweep",
                       description=(
                           "Run the IOP sweep of the reference eye with the instrument's pulse, "
                           "fit the map of the raw applanation pressures to the Goldmann-"
                           "equivalent scale, and write it keyed by instrument, model version "
                           "and resolution."))
    p.add_argument("--IOP", dest="IOP", default="10:30:9", metavar="LIST",
                   help="the true IOPs of the reference sweep [mmHg], a comma list or "
                        "start:stop:num (default 10:30:9)")
    for name in ("E0", "thickness", "pmax"):
        s = PARAMETERS[name]
        default = REFERENCE_EYE.get(name, s.default)
        p.add_argument("--" + name, dest=name, default=None, metavar=s.unit,
                       help=f"{s.description} [{s.unit}] of the reference sweep, "
                            f"{s.accepted()}, default {default:g}")
    add_run_options(p, swept=False)
    escape_percent(p)
    p.add_argument("--workers", default="2", metavar="N",
                   help="local Dask worker processes for the sweeps (default 2)")
    p.add_argument("--in-process", action="store_true",
                   help="run the points one after the other in this process (no Dask, no files)")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help=f"folder of the reference sweep's points and sweep.nc (default {DEFAULT_OUT})")
    p.add_argument("--calibration-dir", default=None, metavar="DIR",
                   help="where the calibration file goes (default the package's calibrations, "
                        "or AIRPUFF_CALIBRATION_DIR)")
    p.add_argument("--check", action="store_true",
                   help="also run the CCT (0.45-0.65 mm) and E0 (0.3-0.9 MPa) sweeps at IOP 16 "
                        "and record the slopes of the raw and calibrated IOPg")
    p.add_argument("--figure", default=None, metavar="FILE.png",
                   help="draw the reference sweep (raw and calibrated readings against the true IOP)")
    p.add_argument("--json", action="store_true", help="print the calibration as JSON")
    p.set_defaults(func=calibrate_command)


def _inputs(args):
    """(instrument, IOP values, options, eye, pmax, workers) from the arguments; raises
    ParameterError on any bad value."""
    from sweep.grid import parse_axis

    iop = parse_axis("IOP", args.IOP)
    options = {}
    for name in list(RUN_OPTIONS) + list(CHOICES):
        v = getattr(args, name, None)
        if v is not None and name != "instrument":
            options[name] = v
    eye = {}
    for name in ("E0", "thickness"):
        if getattr(args, name) is not None:
            eye[name] = PARAMETERS[name].check(getattr(args, name))
    if "R" in options:
        eye["R"] = PARAMETERS["R"].check(options.pop("R"))
    pmax = PARAMETERS["pmax"].check(args.pmax) if args.pmax is not None else None
    try:
        workers = parse_whole(str(args.workers))
    except ValueError:
        workers = 0
    if workers < 1:
        raise ParameterError("workers", args.workers, "a whole number >= 1")
    return (args.instrument or "paper"), iop, options, eye, pmax, workers


def calibrate_command(args) -> int:
    from sweep.calibration import (TOLERANCE_MMHG, check_calibration, check_specs,
                                   command_line, make_calibration, reference_spec, run_in_process,
                                   run_on_dask, write_calibration)

    try:
        instrument, iop, options, eye, pmax, workers = _inputs(args)
        spec = reference_spec(instrument, iop, options, eye, pmax)
        checks = check_specs(spec) if args.check else {}
    except ParameterError as err:
        fail(PROG, err)
    from pathlib import Path

    out = Path(args.out)
    run = run_in_process if args.in_process else run_on_dask(workers)
    try:
        readings = run(spec, out / "reference")
        data = make_calibration(instrument, spec, readings, command_line(spec, args.check))
    except ValueError as err:
        sys.stderr.write(f"{PROG}: {err}\n")
        return 1
    if checks:
        data["check"] = check_calibration(
            data, {axis: run(s, out / f"check_{axis}") for axis, s in checks.items()})
    path = write_calibration(data, args.calibration_dir)
    if args.figure:
        from sweep.plots import plot_calibration

        plot_calibration(data, args.figure)
    if args.json:
        sys.stdout.write(json.dumps(data) + "\n")
    else:
        print(summary(data, path))
    errors = [data["fit"]["IOPg_cal_max_abs_error"]]
    errors += [abs(data.get("check", {}).get("at_reference_eye", {}).get("IOPg_cal", 0.0))]
    if max(errors) > TOLERANCE_MMHG:
        sys.stderr.write(f"{PROG}: the calibrated IOPg misses the true IOP by "
                         f"{max(errors):.3f} mmHg at the reference eye (tolerance "
                         f"{TOLERANCE_MMHG} mmHg)\n")
        return 1
    return 0


def summary(data: dict, path) -> str:
    """The calibration in a few lines: its key, coefficients, errors and the check's slopes."""
    c, fit = data["coefficients"], data["fit"]
    lines = [f"calibration of instrument {data['instrument']} (model {data['model']}, "
             f"{data['resolution']} resolution, model version {data['model_version']}): {path}",
             f"  P_cal = {c['pressure_offset']:.4f} + {c['pressure_slope']:.5f} P_raw [mmHg]",
             f"  CRF_cal = P1_cal - 0.70 P2_cal + {c['crf_constant']:.4f}",
             f"  IOPcc_ora_cal = {c['iopcc_ora_scale']:.4f} (P2_cal - 0.43 P1_cal) + "
             f"{c['iopcc_ora_constant']:.4f}",
             f"  IOPnc_cal = {c['iopnc_offset']:.4f} + {c['iopnc_slope']:.5f} P1_raw",
             f"  reference sweep (IOP {data['reference_sweep']['IOP'][0]:g} to "
             f"{data['reference_sweep']['IOP'][-1]:g}): |IOPg_cal - IOP| max "
             f"{fit['IOPg_cal_max_abs_error']:.3f}, rms {fit['IOPg_cal_rms_error']:.3f}; "
             f"IOPnc_cal max {fit['IOPnc_cal_max_abs_error']:.3f}; IOPcc_ora_cal max "
             f"{fit['IOPcc_ora_cal_max_abs_error']:.3f} mmHg"]
    check = data.get("check")
    if check:
        for axis in ("thickness", "E0"):
            a = check[axis]
            lines.append(f"  IOP {check['IOP']:g}, against {axis}: IOPg raw "
                         f"{a['IOPg_raw_slope']:+.3f}, calibrated {a['IOPg_cal_slope']:+.3f}, "
                         f"IOPnc_cal {a['IOPnc_cal_slope']:+.3f}, IOPcc_ora_cal "
                         f"{a['IOPcc_ora_cal_slope']:+.3f} {a['slope_unit']}")
        ref = check.get("at_reference_eye")
        if ref:
            lines.append(f"  IOP {check['IOP']:g} at the reference eye (not a fitted point): "
                         f"IOPg_cal - IOP {ref['IOPg_cal']:+.3f} mmHg")
    return "\n".join(lines)
