"""Identify the true IOP and the corneal stiffness E0 from a measurement, using a stored sweep.

The inverse problem: given any subset of the measurable metrics P1, P2 [mmHg], DA [mm], t_A1 and
t_A2 [ms] (each with a standard uncertainty), find the (IOP, E0) of the model that reproduces them,
at a given corneal thickness and jet amplitude pmax.

Method (see docs/identify.md for the measured accuracy):

1. Take the (E0, IOP) slice of the sweep at ``thickness`` and ``pmax``.  A value on the grid is
   selected; a value between two grid values is interpolated linearly between the two slices;
   a value outside the grid is an :class:`IdentifyError`.  Failed points are NaN and are never
   used (the cells around them are treated as not covered).
2. Interpolate every measured metric bilinearly on a fine 201 x 201 (IOP, E0) grid spanning the
   sweep.  There is no extrapolation: the fine grid never leaves the sweep's box.
3. chi^2 = sum_m ((model_m - meas_m) / s_m)^2 with s_m^2 = sigma_m^2 + e_m^2, where sigma_m is the
   stated measurement uncertainty (defaults in ``DEFAULT_SIGMA``) and e_m an estimate of the
   interpolation error of metric m (leave-one-out on the sweep's interior nodes, divided by 4
   because linear interpolation is second order and the left-out prediction uses twice the
   spacing).
4. Estimate = argmin chi^2.  Region = {chi^2 <= chi^2_min + 2.30}: the 68 % joint confidence region
   of two parameters.  The IOP and E0 intervals are its extent.  An interval that reaches both ends
   of the sweep's range is reported as "not identified by this measurement".
5. Out of range (an error, never an extrapolated guess): a measured value farther than one s_m
   outside the range that metric takes over the slice, or a best fit on the edge of the sweep
   with chi^2_min above the 99 % quantile of chi^2 with n_measured degrees of freedom.

``refine`` improves a grid estimate with direct solver runs (Gauss-Newton with finite differences,
at most ``max_runs`` runs, never leaving the sweep's box).

Two scales of pressure (docs/calibration.md): the raw P1, P2 (the jet pressure at the apex at each
applanation, what the model computes) or the calibrated P1_cal, P2_cal, IOPg_cal, CH_cal (the
instrument's Goldmann-equivalent scale, what an ORA or a Corvis prints).  A measurement uses one
scale; a calibrated one needs the sweep's points to have a calibration (their instrument,
resolution and model version), and is compared with the sweep's calibrated readings.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from airpuff_core.calibration import CALIBRATED
from airpuff_core.params import PARAMETERS
from airpuff_core.result import METRICS

# The measurable quantities (the one list: the command line and the HTTP API take theirs from
# here) with the default standard uncertainty (1 sigma) of a measurement, in the metric's unit.
# The calibrated pressures' defaults are those of P1_cal and P2_cal at 0.5 mmHg each, carried to
# their mean (IOPg_cal: 0.5/sqrt(2)) and difference (CH_cal: 0.5 sqrt(2)).
RAW_SIGMA = {"P1": 0.5, "P2": 0.5, "DA": 0.02, "t_A1": 0.1, "t_A2": 0.1}
CALIBRATED_SIGMA = {"P1_cal": 0.5, "P2_cal": 0.5, "IOPg_cal": 0.35, "CH_cal": 0.71}
DEFAULT_SIGMA = {**RAW_SIGMA, **CALIBRATED_SIGMA}
MEASURABLE = tuple(DEFAULT_SIGMA)
RAW_PRESSURES = ("P1", "P2")
CALIBRATED_PRESSURES = tuple(CALIBRATED_SIGMA)
# The accepted range of a measurement's sigma, in the metric's unit.  Below the lower bound no
# instrument resolves a difference, and chi^2 divides by sigma^2, which underflows to 0 (at
# sigma ~ 1e-162) and would make every point of the sweep look infinitely far.
SIGMA_RANGE = (1e-6, 1e6)
# The scale of the measured pressures: both sides of chi^2 are on one scale.
SCALE = {
    "raw": ("raw: P1 and P2 are compared with the sweep's raw readings (the instrument's pressure "
            "at the apex at each applanation, which includes the cornea's resistance), not with "
            "the Goldmann-equivalent P1_cal and P2_cal; give uncalibrated readings"),
    "calibrated": ("calibrated: the measured P1_cal, P2_cal, IOPg_cal, CH_cal are compared with "
                   "the sweep's calibrated readings (the instrument's Goldmann-equivalent scale, "
                   "docs/calibration.md), as an ORA or a Corvis prints them"),
}
# Units of the measured quantities and of the estimated and given parameters (user units).
UNITS = {**{name: METRICS[name][0] for name in RAW_SIGMA},
         **{name: CALIBRATED[name][0] for name in CALIBRATED_SIGMA},
         **{name: PARAMETERS[name].unit for name in ("IOP", "E0", "thickness", "pmax")}}

DELTA_CHI2_68 = 2.30  # 68.3 % joint region of 2 parameters
# 99 % quantiles of chi^2 with k = 1..5 degrees of freedom (no scipy in the project)
CHI2_99 = {1: 6.63, 2: 9.21, 3: 11.34, 4: 13.28, 5: 15.09}
FINE_N = 201


class IdentifyError(ValueError):
    """Bad input or a measurement the sweep does not cover.  ``str(err)`` is one line; ``field``
    names the offending input (a metric name, ``thickness``, ``pmax`` or ``sweep``)."""

    def __init__(self, field_name: str, message: str):
        self.field = field_name
        super().__init__(message)


# -- measurement --------------------------------------------------------------------------------

def make_measurement(values: Mapping[str, Any]) -> dict[str, tuple[float, float]]:
    """Normalise ``{"P1": 17.9, "DA": (1.05, 0.03), "t_A1": {"value": 7.2, "sigma": 0.2}}`` to
    ``{name: (value, sigma)}``; a missing sigma takes ``DEFAULT_SIGMA``.  Raises IdentifyError."""
    out: dict[str, tuple[float, float]] = {}
    for name, v in values.items():
        if v is None:
            continue
        if name not in MEASURABLE:
            raise IdentifyError(name, f"unknown measured quantity {name!r}; accepted: "
                                      + ", ".join(MEASURABLE))
        sigma = None
        if isinstance(v, Mapping):
            value, sigma = v.get("value"), v.get("sigma")
        elif isinstance(v, (tuple, list)):
            value, sigma = (v[0], v[1]) if len(v) == 2 else (v[0] if v else None, None)
        else:
            value = v
        try:
            value = float(value)
            sigma = DEFAULT_SIGMA[name] if sigma is None else float(sigma)
        except (TypeError, ValueError):
            raise IdentifyError(name, f"{name}: value and sigma must be numbers") from None
        if not math.isfinite(value):
            raise IdentifyError(name, f"{name}={value!r}: accepted a finite number [{UNITS[name]}]")
        if not (math.isfinite(sigma) and SIGMA_RANGE[0] <= sigma <= SIGMA_RANGE[1]):
            raise IdentifyError(name, f"{name} sigma={sigma!r}: accepted a number in "
                                      f"[{SIGMA_RANGE[0]:g}, {SIGMA_RANGE[1]:g}] {UNITS[name]}")
        out[name] = (value, sigma)
    if not out:
        raise IdentifyError("measurement", "no measured quantity given; give at least one of "
                                           + ", ".join(MEASURABLE))
    raw = [n for n in RAW_PRESSURES if n in out]
    calibrated = [n for n in CALIBRATED_PRESSURES if n in out]
    if raw and calibrated:
        raise IdentifyError(calibrated[0], f"{', '.join(raw)} (raw) and {', '.join(calibrated)} "
                                           "(calibrated) are on two scales: accepted the raw "
                                           "P1, P2 or the calibrated P1_cal, P2_cal, IOPg_cal, "
                                           "CH_cal, not both")
    if len(calibrated) > 2:
        raise IdentifyError(calibrated[2], f"{', '.join(calibrated)}: accepted at most two of "
                                           "P1_cal, P2_cal, IOPg_cal, CH_cal (any two give the "
                                           "others: IOPg = (P1 + P2)/2, CH = P1 - P2)")
    return out


def measurement_scale(measurement: Mapping[str, Any]) -> str | None:
    """``"raw"`` or ``"calibrated"``: the scale of the measured pressures; None if none given."""
    if any(n in measurement for n in CALIBRATED_PRESSURES):
        return "calibrated"
    if any(n in measurement for n in RAW_PRESSURES):
        return "raw"
    return None


# -- the sweep table ------------------------------------------------------------------------------

@dataclass
class SweepTable:
    """The metrics of a sweep as plain arrays (no netCDF handle kept open).

    ``metrics[name]`` has shape (E0, IOP, thickness, pmax), NaN where the point is not ok.
    """

    E0: np.ndarray
    IOP: np.ndarray
    thickness: np.ndarray
    pmax: np.ndarray
    metrics: dict[str, np.ndarray]
    n_not_ok: int = 0
    run_options: dict = field(default_factory=dict)
    model_version: str = ""  # of the ok points (several, comma-separated, if they differ)
    ok: np.ndarray | None = None  # shape (E0, IOP, thickness, pmax): the point's status is ok
    calibration_missing: str = ""  # why the calibrated readings are missing, where they are

    @classmethod
    def from_netcdf(cls, path, names=MEASURABLE) -> "SweepTable":
        """The metrics ``names`` (default the measurable ones; None: every metric of
        ``METRICS`` that the file has) of a combined sweep.nc."""
        from airpuff_core.dataset import open_dataset

        try:
            ds = open_dataset(path, engine="netcdf4")
        except FileNotFoundError:
            raise IdentifyError("sweep", f"sweep file {str(path)!r} not found") from None
        except Exception as err:  # noqa: BLE001 - any unreadable file
            raise IdentifyError("sweep", f"cannot read sweep file {str(path)!r}: "
                                         f"{type(err).__name__}") from None
        with ds:
            if names is None:
                names = [n for n in METRICS if n in ds.variables]
            missing = [n for n in ("E0", "IOP", "thickness", "pmax", "status", *names)
                       if n not in ds.variables and n not in CALIBRATED]
            if missing:
                raise IdentifyError("sweep", f"{path} is not a combined airpuff sweep "
                                             f"(missing {', '.join(missing)})")
            ds = ds.transpose("E0", "IOP", "thickness", "pmax", ...)
            ok = np.asarray(ds["status"].values).astype(str) == "ok"
            metrics = {}
            reasons = []
            for name in names:
                if name not in ds.variables:  # a file combined before calibrated readings existed
                    metrics[name] = np.full(ok.shape, np.nan)
                    reasons.append("the sweep file has no calibrated readings (combined by an "
                                   "older version: combine it again)")
                    continue
                a = np.asarray(ds[name].values, float).copy()
                a[~ok] = np.nan
                metrics[name] = a
                if name in CALIBRATED and ds[name].attrs.get("comment"):
                    reasons.append(str(ds[name].attrs["comment"]))
            try:
                options = json.loads(ds.attrs.get("run_options_json", "{}"))
            except ValueError:
                options = {}
            versions = (sorted(set(np.asarray(ds["model_version"].values).astype(str)[ok]))
                        if "model_version" in ds.variables else [])
            return cls(np.asarray(ds.E0.values, float), np.asarray(ds.IOP.values, float),
                       np.asarray(ds.thickness.values, float), np.asarray(ds.pmax.values, float),
                       metrics, int((~ok).sum()), options, ",".join(versions), ok,
                       reasons[0] if reasons else "")

    @classmethod
    def from_records(cls, spec: Mapping[str, Any], records, names=MEASURABLE) -> "SweepTable":
        """From a SweepSpec dict and point records ``{"E0", "IOP", "thickness", "pmax",
        "status", <metrics>}`` (what the HTTP service keeps in its database)."""
        axes = {n: np.asarray(sorted(float(v) for v in spec[n]), float)
                for n in ("E0", "IOP", "thickness", "pmax")}
        shape = tuple(len(axes[n]) for n in ("E0", "IOP", "thickness", "pmax"))
        metrics = {name: np.full(shape, np.nan) for name in names}
        versions = set()
        reasons = set()
        ok = np.zeros(shape, bool)
        n_ok = 0
        for r in records:
            if r.get("status") != "ok":
                continue
            if r.get("calibration_missing"):
                reasons.add(str(r["calibration_missing"]))
            idx = tuple(int(np.argmin(np.abs(axes[n] - float(r[n]))))
                        for n in ("E0", "IOP", "thickness", "pmax"))
            n_ok += 1
            ok[idx] = True
            if r.get("model_version"):
                versions.add(str(r["model_version"]))
            for name in names:
                v = r.get(name)
                metrics[name][idx] = np.nan if v is None else float(v)
        return cls(axes["E0"], axes["IOP"], axes["thickness"], axes["pmax"], metrics,
                   int(np.prod(shape)) - n_ok, dict(spec.get("options") or {}),
                   ",".join(sorted(versions)), ok, "; ".join(sorted(reasons)))


def _axis_weights(name: str, axis: np.ndarray, value: float | None) -> list[tuple[int, float]]:
    """[(index, weight)] selecting ``value`` on ``axis`` (on the grid, or linear between the two
    neighbouring values); IdentifyError outside."""
    order = np.argsort(axis)
    a = axis[order]
    unit = UNITS[name]
    if value is None:
        if a.size == 1:
            return [(int(order[0]), 1.0)]
        raise IdentifyError(name, f"the sweep has several {name} values "
                                  f"({', '.join(f'{v:g}' for v in a)} {unit}); give --{name}")
    value = float(value)
    if not math.isfinite(value):
        raise IdentifyError(name, f"{name}={value!r}: accepted a finite number [{unit}]")
    tol = 1e-9 * max(1.0, abs(value))
    hit = np.flatnonzero(np.abs(a - value) <= tol)
    if hit.size:
        return [(int(order[hit[0]]), 1.0)]
    if value < a[0] or value > a[-1]:
        covered = f"{a[0]:g}" if a.size == 1 else f"{a[0]:g} to {a[-1]:g}"
        raise IdentifyError(name, f"{name}={value:g} {unit} is outside the sweep "
                                  f"(covered: {covered} {unit}); no extrapolation")
    j = int(np.searchsorted(a, value))
    w = (value - a[j - 1]) / (a[j] - a[j - 1])
    return [(int(order[j - 1]), 1.0 - w), (int(order[j]), w)]


@dataclass
class Slice:
    """Metrics on the (E0, IOP) grid at one thickness and pmax, axes sorted ascending."""

    E0: np.ndarray
    IOP: np.ndarray
    metrics: dict[str, np.ndarray]  # shape (E0, IOP)
    thickness: float
    pmax: float


def take_slice(table: SweepTable, thickness: float | None = None,
               pmax: float | None = None) -> Slice:
    wt = _axis_weights("thickness", table.thickness, thickness)
    wp = _axis_weights("pmax", table.pmax, pmax)
    oe, oi = np.argsort(table.E0), np.argsort(table.IOP)
    out = {}
    for name, a in table.metrics.items():
        acc = 0.0
        for it, w1 in wt:
            for ip, w2 in wp:
                acc = acc + w1 * w2 * a[:, :, it, ip]
        out[name] = np.asarray(acc)[np.ix_(oe, oi)]
    th = table.thickness[wt[0][0]] if thickness is None else float(thickness)
    pm = table.pmax[wp[0][0]] if pmax is None else float(pmax)
    return Slice(table.E0[oe], table.IOP[oi], out, float(th), float(pm))


# -- interpolation ------------------------------------------------------------------------------

def _cells(axis: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the cell and the fraction within it, for points ``x`` inside ``axis``."""
    if axis.size == 1:
        return np.zeros(x.shape, int), np.zeros(x.shape)
    i = np.clip(np.searchsorted(axis, x, side="right") - 1, 0, axis.size - 2)
    f = (x - axis[i]) / (axis[i + 1] - axis[i])
    return i, f


def bilinear(E0: np.ndarray, IOP: np.ndarray, grid: np.ndarray, e: np.ndarray,
             p: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of ``grid`` (shape (E0, IOP)) at the points (e, p) (same shape).
    NaN wherever a corner of the cell is NaN.  Points must lie inside the grid's box."""
    ie, fe = _cells(E0, e)
    ip, fp = _cells(IOP, p)
    if E0.size == 1:
        g = grid[0]
        return g[ip] * (1 - fp) + g[np.minimum(ip + 1, IOP.size - 1)] * fp
    if IOP.size == 1:
        g = grid[:, 0]
        return g[ie] * (1 - fe) + g[np.minimum(ie + 1, E0.size - 1)] * fe
    return (grid[ie, ip] * (1 - fe) * (1 - fp) + grid[ie + 1, ip] * fe * (1 - fp)
            + grid[ie, ip + 1] * (1 - fe) * fp + grid[ie + 1, ip + 1] * fe * fp)


def interpolation_error(E0: np.ndarray, IOP: np.ndarray, grid: np.ndarray) -> float:
    """Estimated error of bilinear interpolation of one metric on this grid.

    Leave-one-out along each axis: at every interior node, the value predicted linearly from its
    two neighbours differs from the stored one by the second-difference term; the error inside a
    cell of the actual spacing is about a quarter of that (linear interpolation is second order,
    and its worst error is mid-cell).  Returns the RMS over all such nodes (0 if there is none)."""
    res = []
    for axis, arr in ((E0, grid), (IOP, grid.T)):
        if axis.size < 3:
            continue
        for k in range(1, axis.size - 1):
            w = (axis[k] - axis[k - 1]) / (axis[k + 1] - axis[k - 1])
            pred = arr[k - 1] * (1 - w) + arr[k + 1] * w
            d = (arr[k] - pred) / 4.0
            res.extend(d[np.isfinite(d)].tolist())
    return float(np.sqrt(np.mean(np.square(res)))) if res else 0.0


# -- the estimate ---------------------------------------------------------------------------------

@dataclass
class Estimate:
    IOP: float
    E0: float
    IOP_interval: tuple[float, float]
    E0_interval: tuple[float, float]
    IOP_identified: bool
    E0_identified: bool
    chi2_min: float
    consistent: bool
    measurement: dict[str, tuple[float, float]]
    model_at_estimate: dict[str, float]
    interpolation_sigma: dict[str, float]
    thickness: float
    pmax: float
    instrument: str
    sweep_IOP: tuple[float, float]
    sweep_E0: tuple[float, float]
    n_not_ok: int
    notes: list[str] = field(default_factory=list)
    method: str = "sweep interpolation"
    refined: dict | None = None

    def to_dict(self) -> dict[str, Any]:
        r = lambda x: None if x is None or not math.isfinite(x) else float(f"{x:.6g}")  # noqa: E731
        d = {
            "IOP": r(self.IOP), "E0": r(self.E0),
            "IOP_interval": [r(v) for v in self.IOP_interval],
            "E0_interval": [r(v) for v in self.E0_interval],
            "IOP_identified": self.IOP_identified, "E0_identified": self.E0_identified,
            "E0_interval_fraction": r((self.E0_interval[1] - self.E0_interval[0])
                                      / (self.sweep_E0[1] - self.sweep_E0[0])),
            "confidence": 0.68,
            "region": "chi2 <= chi2_min + 2.30 (68 % joint region of IOP and E0)",
            "chi2_min": r(self.chi2_min), "n_measured": len(self.measurement),
            "consistent": self.consistent,
            "measurement": {k: {"value": v, "sigma": s} for k, (v, s) in self.measurement.items()},
            "model_at_estimate": {k: r(v) for k, v in self.model_at_estimate.items()},
            "interpolation_sigma": {k: r(v) for k, v in self.interpolation_sigma.items()},
            "thickness": self.thickness, "pmax": self.pmax, "instrument": self.instrument,
            "scale": SCALE[measurement_scale(self.measurement) or "raw"],
            "sweep_range": {"IOP": list(self.sweep_IOP), "E0": list(self.sweep_E0)},
            "points_not_ok": self.n_not_ok,
            "method": self.method, "notes": list(self.notes),
            "units": {k: UNITS[k] for k in ("IOP", "E0", "thickness", "pmax", *self.measurement)},
        }
        if self.refined is not None:
            d["refined"] = self.refined
        return d


def _check_measured_range(sl: Slice, meas, interp_sigma, calibration_missing: str = "") -> None:
    for name, (value, sigma) in meas.items():
        a = sl.metrics[name]
        finite = a[np.isfinite(a)]
        if finite.size == 0 and name in CALIBRATED:
            raise IdentifyError(name, f"{name} (calibrated) is not available at any ok point of "
                                      f"the sweep slice: {calibration_missing or 'no calibration'}"
                                      "; give the raw P1, P2 instead")
        if finite.size == 0:
            raise IdentifyError(name, f"{name} is not available at any ok point of the sweep slice "
                                      f"(thickness {sl.thickness:g} mm, pmax {sl.pmax:g} kPa)")
        lo, hi = float(finite.min()), float(finite.max())
        s = math.hypot(sigma, interp_sigma[name])
        if value < lo - s or value > hi + s:
            raise IdentifyError(name, f"{name}={value:g} {UNITS[name]} is outside what the sweep "
                                      f"covers: {lo:.4g} to {hi:.4g} {UNITS[name]} at thickness "
                                      f"{sl.thickness:g} mm, pmax {sl.pmax:g} kPa, IOP "
                                      f"{sl.IOP[0]:g}-{sl.IOP[-1]:g} mmHg, E0 {sl.E0[0]:g}-"
                                      f"{sl.E0[-1]:g} MPa; no extrapolation")


def chi2_map(sl: Slice, meas, interp_sigma, n: int = FINE_N):
    """(E0 values, IOP values, chi^2 array (E0, IOP), model arrays) on the fine grid."""
    e = np.linspace(sl.E0[0], sl.E0[-1], n if sl.E0.size > 1 else 1)
    p = np.linspace(sl.IOP[0], sl.IOP[-1], n if sl.IOP.size > 1 else 1)
    ee, pp = np.meshgrid(e, p, indexing="ij")
    chi2 = np.zeros(ee.shape)
    models = {}
    for name, (value, sigma) in meas.items():
        m = bilinear(sl.E0, sl.IOP, sl.metrics[name], ee, pp)
        models[name] = m
        s2 = sigma ** 2 + interp_sigma[name] ** 2
        chi2 = chi2 + (m - value) ** 2 / s2  # NaN propagates: not covered there
    return e, p, chi2, models


EDGE_TOL = 0.01  # fraction of the sweep's range


def _at_edges(inside: np.ndarray, axis: np.ndarray) -> tuple[bool, bool]:
    tol = EDGE_TOL * (axis[-1] - axis[0])
    return bool(inside.min() <= axis[0] + tol), bool(inside.max() >= axis[-1] - tol)


def sweep_instrument(table: SweepTable, instrument: str | None = None) -> str:
    """The instrument whose pulse the sweep was computed with (``paper`` for a sweep made before
    there was a choice); ``instrument``, the one the measurement was taken with, must be it."""
    from airpuff_core.params import CHOICES

    swept = str(table.run_options.get("instrument", "paper"))
    if instrument is not None and instrument not in CHOICES["instrument"]:
        raise IdentifyError("instrument", f"invalid instrument={instrument!r}: accepted one of "
                                          + ", ".join(CHOICES["instrument"]))
    if instrument is not None and instrument != swept:
        raise IdentifyError("instrument", f"instrument={instrument} but the sweep was computed "
                                          f"with the {swept} pulse: accepted {swept} (a "
                                          f"measurement of the {instrument} needs a sweep with "
                                          f"instrument={instrument})")
    return swept


def identify(table: SweepTable, measurement: Mapping[str, Any], thickness: float | None = None,
             pmax: float | None = None, instrument: str | None = None) -> Estimate:
    """Estimate (IOP, E0) and their 68 % region from the sweep; raises IdentifyError.
    ``instrument``: the instrument of the measurement, checked against the sweep's."""
    swept = sweep_instrument(table, instrument)
    meas = make_measurement(measurement)
    sl = take_slice(table, thickness, pmax)
    if sl.E0.size < 2 or sl.IOP.size < 2:
        raise IdentifyError("sweep", "identification needs at least 2 E0 and 2 IOP values in the "
                                     f"sweep (it has {sl.E0.size} x {sl.IOP.size})")
    interp_sigma = {name: interpolation_error(sl.E0, sl.IOP, sl.metrics[name]) for name in meas}
    _check_measured_range(sl, meas, interp_sigma, table.calibration_missing)
    e, p, chi2, models = chi2_map(sl, meas, interp_sigma)
    if not np.isfinite(chi2).any():
        raise IdentifyError("sweep", "no part of the sweep slice has all the measured metrics "
                                     "(failed points or missing applanations)")
    c = np.where(np.isfinite(chi2), chi2, np.inf)
    k = np.unravel_index(int(np.argmin(c)), c.shape)
    cmin = float(c[k])
    n = len(meas)
    threshold = CHI2_99.get(n, n + 3 * math.sqrt(2 * n))
    on_edge = k[0] in (0, e.size - 1) or k[1] in (0, p.size - 1)
    if on_edge and cmin > threshold:
        worst = max(meas, key=lambda m: abs(models[m][k] - meas[m][0]) / meas[m][1])
        raise IdentifyError(worst, f"the measurement lies outside what the sweep covers: the "
                                   f"closest sweep point is on its edge (IOP {p[k[1]]:.3g} mmHg, "
                                   f"E0 {e[k[0]]:.3g} MPa) with chi2 {cmin:.3g} > {threshold:.3g}; "
                                   f"{worst}={meas[worst][0]:g} {UNITS[worst]} vs "
                                   f"{models[worst][k]:.4g} there; no extrapolation")
    region = c <= cmin + DELTA_CHI2_68
    e_in = e[region.any(axis=1)]
    p_in = p[region.any(axis=0)]
    notes = []
    # "at the edge" within EDGE_TOL of the range: an interval from 1 % above the lower end to the
    # upper end says no more than the whole range does
    e_lo, e_hi = _at_edges(e_in, e)
    p_lo, p_hi = _at_edges(p_in, p)
    e_ident = not (e_lo and e_hi)
    p_ident = not (p_lo and p_hi)
    if not e_ident:
        notes.append("E0 is not identified by this measurement: its interval spans the whole "
                     "sweep range")
    elif e_lo or e_hi:
        notes.append("the E0 interval reaches the sweep's edge: it is bounded on one side only")
    if not p_ident:
        notes.append("IOP is not identified by this measurement: its interval spans the whole "
                     "sweep range")
    elif p_lo or p_hi:
        notes.append("the IOP interval reaches the sweep's edge: it is bounded on one side only")
    consistent = cmin <= threshold
    if not consistent:
        notes.append(f"the measured values are not jointly consistent with the model "
                     f"(chi2_min {cmin:.3g} > {threshold:.3g} for {n} values)")
    if table.n_not_ok:
        notes.append(f"{table.n_not_ok} sweep point(s) failed or missing; cells around them "
                     "are not used")
    return Estimate(
        IOP=float(p[k[1]]), E0=float(e[k[0]]),
        IOP_interval=(float(p_in.min()), float(p_in.max())),
        E0_interval=(float(e_in.min()), float(e_in.max())),
        IOP_identified=p_ident, E0_identified=e_ident, chi2_min=cmin, consistent=consistent,
        measurement=meas, model_at_estimate={m: float(models[m][k]) for m in meas},
        interpolation_sigma=interp_sigma, thickness=sl.thickness, pmax=sl.pmax, instrument=swept,
        sweep_IOP=(float(sl.IOP[0]), float(sl.IOP[-1])), sweep_E0=(float(sl.E0[0]), float(sl.E0[-1])),
        n_not_ok=table.n_not_ok, notes=notes)


# -- refinement with direct solver runs -----------------------------------------------------------

def solver_metrics(params: Mapping[str, Any]) -> dict[str, float]:
    """Metrics of one direct solver run (``RunParams.from_dict(params)``) and its calibrated
    readings (NaN without a calibration); NaN where missing.  Module-level so that it can be
    sent to another process."""
    from airpuff_core import simulate
    from airpuff_core.calibration import calibrate_metrics
    from airpuff_core.params import RunParams
    from airpuff_core.provenance import model_version

    run_params = RunParams.from_dict(dict(params))
    result = simulate(run_params, threads=1)  # one per sweep worker
    metrics = {k: float(v) for k, v in result.metrics.items()}
    calibrated, _, _ = calibrate_metrics(run_params.to_dict(), metrics, model_version())
    return {**metrics, **{k: float(v) for k, v in calibrated.items()}}


def _solver_metrics(options: dict, thickness: float, pmax: float) -> Callable[[float, float], dict]:
    def run(IOP: float, E0: float) -> dict:
        return solver_metrics({**options, "E0": float(E0), "IOP": float(IOP),
                               "thickness": thickness, "pmax": pmax})

    return run


def refine(table: SweepTable, est: Estimate, max_runs: int = 7,
           run: Callable[[float, float], dict] | None = None,
           progress: Callable[[str], None] | None = None) -> Estimate:
    """Improve ``est`` with direct solver runs at the sweep's run options (Gauss-Newton with
    forward differences, Levenberg-damped, steps kept inside the sweep's box).  Uses at most
    ``max_runs`` (>= 4) runs: 1 at the start, 2 finite differences per Jacobian (recomputed after
    an accepted step) and 1 per trial step (a rejected trial is retried with more damping).
    The interval is the linearised 68 % region (half-width sqrt(2.30 C_ii) of the covariance
    C = (J^T W J)^-1), clipped to the sweep's range."""
    if max_runs < 4:
        raise IdentifyError("refine", f"refine needs at least 4 solver runs (got {max_runs})")
    meas = est.measurement
    names = list(meas)
    y = np.array([meas[m][0] for m in names])
    s = np.array([meas[m][1] for m in names])
    if run is None:
        run = _solver_metrics(table.run_options, est.thickness, est.pmax)
    lo = np.array([est.sweep_IOP[0], est.sweep_E0[0]])
    hi = np.array([est.sweep_IOP[1], est.sweep_E0[1]])
    scale = hi - lo
    h = scale * np.array([0.04, 0.04])  # finite-difference steps: 4 % of the sweep's range
    runs = 0

    def f(x):
        nonlocal runs
        runs += 1
        if progress:
            progress(f"refine: solver run {runs} at IOP {x[0]:.3f} mmHg, E0 {x[1]:.4f} MPa")
        m = run(float(x[0]), float(x[1]))
        return np.array([m.get(n, np.nan) if m.get(n) is not None else np.nan for n in names], float)

    def chi2(r):
        return float(np.sum(((r - y) / s) ** 2))

    x = np.array([est.IOP, est.E0], float)
    fx = f(x)
    if not np.all(np.isfinite(fx)):
        raise IdentifyError("refine", "the solver gave no value for some measured metric at the "
                                      "grid estimate; cannot refine")
    cx = chi2(fx)
    J = None
    need_jacobian = True
    lam = 1e-3
    history = [{"IOP": float(x[0]), "E0": float(x[1]), "chi2": cx}]
    while runs < max_runs:
        if need_jacobian:
            if runs + 3 > max_runs:
                break  # a new Jacobian and a trial would not fit in the budget
            Jn = np.zeros((len(names), 2))
            for j in range(2):
                step = np.zeros(2)
                step[j] = h[j] if x[j] + h[j] <= hi[j] else -h[j]  # inward at the upper edge
                Jn[:, j] = (f(x + step) - fx) / step[j]
            if not np.all(np.isfinite(Jn)):
                break
            J, need_jacobian = Jn, False
        # Levenberg-Marquardt in variables scaled by the sweep's range, damping lam * mean
        # curvature * I: a direction the data do not constrain (E0 from P1, P2) gets a small step,
        # not a huge one.
        A = (J / s[:, None]) * scale[None, :]
        g = A.T @ ((y - fx) / s)
        H = A.T @ A
        du = np.linalg.solve(H + lam * max(np.trace(H) / 2, 1e-12) * np.eye(2), g)
        dx = np.clip(du * scale, -0.25 * scale, 0.25 * scale)
        xn = np.clip(x + dx, lo, hi)
        fn = f(xn)
        cn = chi2(fn) if np.all(np.isfinite(fn)) else math.inf
        history.append({"IOP": float(xn[0]), "E0": float(xn[1]), "chi2": cn})
        if cn < cx:
            x, fx, cx = xn, fn, cn
            lam = max(lam / 10, 1e-6)
            need_jacobian = True
            if np.all(np.abs(dx) < 0.002 * scale):
                break  # converged
        else:
            lam *= 10  # reject; retry with the same Jacobian and a shorter step
    intervals = []
    identified = []
    notes = [n for n in est.notes if "interval" not in n and "identified" not in n]
    if J is not None and np.all(np.isfinite(J)):
        A = J / s[:, None]
        H = A.T @ A
        try:
            C = np.linalg.pinv(H, rcond=1e-10)
            half = np.sqrt(np.maximum(DELTA_CHI2_68 * np.diag(C), 0.0))
        except np.linalg.LinAlgError:
            half = np.array([math.inf, math.inf])
    else:
        half = np.array([math.inf, math.inf])
    for j in range(2):
        a, b = max(lo[j], x[j] - half[j]), min(hi[j], x[j] + half[j])
        intervals.append((float(a), float(b)))
        tol = EDGE_TOL * scale[j]
        identified.append(not (a <= lo[j] + tol and b >= hi[j] - tol))
    for j, name in enumerate(("IOP", "E0")):
        tol = EDGE_TOL * scale[j]
        if not identified[j]:
            notes.append(f"{name} is not identified by this measurement: its linearised interval "
                         "spans the whole sweep range")
        elif intervals[j][0] <= lo[j] + tol or intervals[j][1] >= hi[j] - tol:
            notes.append(f"the {name} interval reaches the sweep's edge: it is bounded on one "
                         "side only")
    n = len(names)
    threshold = CHI2_99.get(n, n + 3 * math.sqrt(2 * n))
    return Estimate(
        IOP=float(x[0]), E0=float(x[1]), IOP_interval=intervals[0], E0_interval=intervals[1],
        IOP_identified=identified[0], E0_identified=identified[1], chi2_min=cx,
        consistent=cx <= threshold, measurement=meas,
        model_at_estimate={m: float(v) for m, v in zip(names, fx)},
        interpolation_sigma={m: 0.0 for m in names}, thickness=est.thickness, pmax=est.pmax,
        instrument=est.instrument, sweep_IOP=est.sweep_IOP, sweep_E0=est.sweep_E0, n_not_ok=est.n_not_ok, notes=notes,
        method=f"refined with {runs} direct solver runs (Gauss-Newton, forward differences)",
        refined={"grid_estimate": {"IOP": est.IOP, "E0": est.E0,
                                   "IOP_interval": list(est.IOP_interval),
                                   "E0_interval": list(est.E0_interval)},
                 "solver_runs": runs, "iterations": history,
                 "run_options": dict(table.run_options)})
