"""How a calibration carries over to another resolution (docs/calibration.md): the coefficients of
one calibration file applied to the raw readings of another's reference sweep (same instrument
and reference eye, another resolution), and the calibrated IOPg's, IOPnc's and IOPcc_ora's
errors against the true IOP.

    python -m studies.calibration_cross CAL_A.json CAL_B.json

prints, for each file's coefficients on each file's reference sweep, the largest and the RMS
error [mmHg].  The runs keep their refusal of a calibration of another resolution; this study
only measures what that refusal avoids.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from airpuff_core.calibration import apply_coefficients

READINGS = ("IOPg_cal", "IOPnc_cal", "IOPcc_ora_cal")


def cross_errors(coef_file: dict, sweep_file: dict) -> dict[str, tuple[float, float]]:
    """reading -> (max |error|, rms error) [mmHg] of ``coef_file``'s coefficients on
    ``sweep_file``'s reference sweep."""
    ref = sweep_file["reference_sweep"]
    iop = np.asarray(ref["IOP"], float)
    cal = apply_coefficients(coef_file["coefficients"], np.asarray(ref["P1_raw"], float),
                             np.asarray(ref["P2_raw"], float))
    out = {}
    for name in READINGS:
        err = np.asarray(cal[name]) - iop
        out[name] = (float(np.max(np.abs(err))), float(np.sqrt(np.mean(err ** 2))))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m studies.calibration_cross",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+", metavar="CALIBRATION.json")
    args = parser.parse_args(argv)
    files = {Path(f).name: json.loads(Path(f).read_text(encoding="utf-8")) for f in args.files}
    print("| coefficients of | on the reference sweep of | " + " | ".join(
        f"{r} - IOP max / rms [mmHg]" for r in READINGS) + " |")
    print("|---|---|" + "---|" * len(READINGS))
    for a, coef in files.items():
        for b, sweep in files.items():
            errors = cross_errors(coef, sweep)
            print(f"| {coef['resolution']} ({a}) | {sweep['resolution']} ({b}) | " + " | ".join(
                f"{errors[r][0]:.3f} / {errors[r][1]:.3f}" for r in READINGS) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
