"""The clinical model fitted to two population means (issue 27): G_t to a CCT slope, g to CH.

Two tissue parameters of the clinical preset are known only loosely (docs/sources.md section 6);
each is fitted to one published population mean (section 7), everything else stays published:

* ``transverse_shear_modulus`` G_t [kPa] (the shear stiffness S = 5/6 G_t h of the ``mindlin``
  cornea) to the population slope of the reading against CCT, +2.8 mmHg per 100 um (Goldmann);
* ``ve_g`` g, the relative modulus of the one-term Prony series, to the population mean CH,
  10.6 mmHg (UK Biobank, n = 93,345).

``ve_tau`` stays 10 ms (Kling et al. 2014).  Each value is bounded by its literature range
(``SHEAR``, ``RATIO``); a target that cannot be met inside the range stops the value at the
range's edge, and the result says so.

**The responses.**  At a trial (G_t, g) the study runs the reference eye (IOP 16 mmHg, E0 0.5 MPa)
at the CCTs of ``--cct`` (default 0.45, 0.54, 0.65 mm): the CCT slope is the least-squares slope
of the reading (IOPg) over them, in mmHg per 100 um; CH is read at the reference CCT 0.54 mm.

**The decoupling, used.**  The shear stiffness S = 5/6 G_t h sets the cornea's static resistance
at applanation, and through h the CCT slope; g sets the viscoelastic lag between the two
applanations, CH.  IOPg = (P1 + P2)/2 is their mean, so the lag, which raises P1 and lowers P2,
largely cancels in it.  The fit is therefore block-triangular (Gauss-Seidel): solve the slope for
G_t at the current g (3 runs per evaluation), then CH for g at that G_t (1 run per evaluation,
the reference CCT only), then check the slope at the new g (2 new runs: the reference CCT's run
is shared).  Only if the slope left its tolerance is G_t solved again, from a Newton step with
the slope's derivative of the previous solve.  The coupling is measured, not assumed: the
summary gives the local derivatives (planes through the nearest evaluations) and the factor
|dS/dg dCH/dG_t / (dS/dG_t dCH/dg)| by which one outer iteration shrinks the error (0.08 in the
coarse development fit: the slope does move with g, +0.3 mmHg per 100 um per 0.1 of g, so a
second outer iteration is usually needed).  Each 1-D solve is a safeguarded secant on a monotone
response: secant steps clipped to the range until the target is bracketed, then Illinois false
position inside the bracket (it never leaves it); an edge whose response still falls short of the
target ends the solve there.

**Instrument and calibration.**  The clinical fit is the ORA's calibrated reading (issue 26: the
ORA pulse and the calibration to the Goldmann scale, ``airpuff_core/calibration.py``).  The
calibration is made again at every trial (G_t, g), on its reference sweep (``airpuff calibrate``'s
reference eye and IOPs, ``--calibration-iop``), because an instrument's calibration belongs to the
population it was made on: a calibration made at the published values would bias the fit toward
them.  It scales both readings by its slope b (IOPg_cal, CH_cal), so the calibrated targets ask
for a different G_t and g than the raw ones.  What this version of the solver lacks (the ORA
pulse, the calibration) is refused with a one-line error (exit code 2); anything but the ORA's
calibrated readings (``--instrument paper``, ``--raw``) runs only with ``--development``: a
labelled development mode whose numbers are not a clinical fit.

    python -m studies.fit_clinical --out fit_ora --resolution paper --workers 2
    python -m studies.fit_clinical --out fit_dev --instrument paper --raw --development --resolution coarse

Every run is a point of the sweep's storage (``<out>/points/<key>.nc``, the key the hash of its
parameters and the model version; ``--points`` another folder, shared between fits), so a rerun
reuses what is stored; ``--workers N`` computes the points of one evaluation on a local Dask
cluster of N worker processes through the sweep engine (``sweep.engine.PointEngine``),
``--workers 0`` (default) in this process.  Every run and every
evaluation of a response is recorded (``<out>/evaluations.jsonl`` as it goes; ``fit.json``,
``fit.nc`` and ``fit.md`` at the end).
"""

from __future__ import annotations

import json
import math
import shlex
import sys
import time
from collections import OrderedDict
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from airpuff_core.atomic import atomic_write
from airpuff_core.params import CHOICES, ParameterError, RunParams, parse_decimal
from airpuff_core.provenance import model_version
from sweep.engine import PointEngine, stored_record
from sweep.record import PointRecord
from sweep.storage import point_key, save_point


class FitError(RuntimeError):
    """A fit that cannot go on: a run failed where a response was needed."""


@dataclass(frozen=True)
class FittedParameter:
    """A tissue parameter the fit moves: its run-parameter name, published value, literature range
    [low, high] and where the range comes from (docs/sources.md section 6)."""

    name: str
    symbol: str
    unit: str
    published: float
    low: float
    high: float
    range_source: str


# Petsche et al., IOVS 53 (2012) 873: full thickness 9.48 +- 2.92 kPa; its thirds in series
# (7.71, 1.99, 1.31 kPa) give 2.15 kPa, the effective modulus of layers that carry the same
# transverse shear force; the upper edge is the full-thickness mean + 2 SD, 15.32 kPa.
SHEAR = FittedParameter(
    "transverse_shear_modulus", "G_t", "kPa", 9.48, 2.15, 15.32,
    "Petsche et al. IOVS 53 (2012) 873: low = the three thirds in series (2.15 kPa), "
    "high = full-thickness mean + 2 SD (9.48 + 2 x 2.92)")
# Hatami-Marbini, J Biomech 47 (2014) 723: tan delta about 0.15 needs g >= 0.26 for one Prony
# term (max tan delta = g / (2 sqrt(1 - g))); Kling et al. PLoS ONE 9 (2014) e104904: 0.3, its
# caption readable as 0.7 (the relaxed fraction).
RATIO = FittedParameter(
    "ve_g", "g", "1", 0.30, 0.26, 0.70,
    "low = Hatami-Marbini J Biomech 47 (2014) 723, tan delta 0.15 (g >= 0.26 for one Prony term); "
    "high = Kling et al. PLoS ONE 9 (2014) e104904 read as the relaxed fraction (0.7)")


@dataclass(frozen=True)
class Target:
    """A population mean the fit meets: value, tolerance of the fit, source."""

    name: str
    unit: str
    value: float
    tolerance: float
    source: str


SLOPE_TARGET = Target(
    "cct_slope", "mmHg per 100 um", 2.8, 0.05,
    "Goldmann IOP against CCT, +2.8 mmHg per 100 um: Br J Ophthalmol 89 (2005) 851 (clinic, UK; "
    "population studies +1.2 to +2.9) and PMC2915858 (970 eyes, 95 % CI 2.3-3.6)")
CH_TARGET = Target(
    "CH", "mmHg", 10.6, 0.05,
    "UK Biobank, n = 93,345: Zhang et al., Ophthalmology 126 (2019) 1500 (TwinsUK 10.3 +- 1.4)")

# The reference eye: the normal eye of docs/validation.md.
REFERENCE = {"IOP": 16.0, "E0": 0.5}
REFERENCE_CCT = 0.54
CCT_POINTS = (0.45, 0.54, 0.65)
# the readings fitted: the raw ones (the run's metrics) or the calibrated ones (issue 26,
# airpuff_core/calibration.py), the calibration made again at every trial
RAW_READINGS = {"slope": "IOPg", "CH": "CH"}
CALIBRATED_READINGS = {"slope": "IOPg_cal", "CH": "CH_cal"}


# The derivatives of the first Newton step of each solve (the solves correct them from their own
# evaluations), from docs/validation.md: the CCT slope's +0.28 mmHg per 100 um per kPa of G_t
# ("The clinical fit": the development fit's local derivative), CH's +2.5 mmHg per 0.1 of g at
# paper resolution ("How CH moves").
FIRST_DERIVATIVES = {"transverse_shear_modulus": 0.28, "ve_g": 25.0}


# -- the 1-D solver ---------------------------------------------------------------------------
@dataclass
class Solve:
    """Outcome of :func:`solve_monotone`: the value, its residual, how it ended (``converged``,
    ``lower edge``, ``upper edge``: the target not met inside the range; ``evaluations``: the
    cap reached) and every (x, residual) evaluated, in order."""

    x: float
    residual: float
    status: str
    history: list[tuple[float, float]] = field(default_factory=list)

    def derivative(self) -> float | None:
        """The secant slope of the last two evaluations (None if fewer or coincident)."""
        if len(self.history) < 2:
            return None
        (xa, fa), (xb, fb) = self.history[-2:]
        return (fb - fa) / (xb - xa) if xb != xa else None

    def bracket(self) -> tuple[tuple[float, float], tuple[float, float]] | None:
        """The narrowest pair of evaluations (x, residual) whose residuals have opposite signs,
        lower x first (None if the target was never bracketed)."""
        pairs = [(a, b) for a in self.history for b in self.history
                 if a[0] < b[0] and (a[1] < 0) != (b[1] < 0)]
        return min(pairs, key=lambda ab: ab[1][0] - ab[0][0]) if pairs else None

    def jump_ratio(self) -> float | None:
        """How much faster the residual changes across the final bracket than elsewhere: the
        secant slope over the bracket divided by the median secant slope of the other pairs of
        neighbouring evaluations (in x), or, with no other pair, by that over the outermost
        evaluations.  About 1 for a smooth response; large (say > 10) where the response jumps
        across the target inside the bracket, so that no value in it meets the target."""
        bracket = self.bracket()
        points = sorted(set(self.history))
        if bracket is None or len(points) < 3:
            return None
        (xa, fa), (xb, fb) = bracket
        across = abs((fb - fa) / (xb - xa))
        others = [abs((f1 - f0) / (x1 - x0)) for (x0, f0), (x1, f1) in zip(points, points[1:])
                  if x1 > x0 and not (x0 >= xa and x1 <= xb)]
        if not others:
            (x0, f0), (x1, f1) = points[0], points[-1]
            others = [abs((f1 - f0) / (x1 - x0))]
        reference = float(np.median(others))
        return across / reference if reference > 0 else math.inf


def solve_monotone(residual: Callable[[float], float], low: float, high: float, x0: float,
                   step: float, tolerance: float, max_evaluations: int = 10,
                   derivative: float | None = None, x_tolerance: float = 0.0,
                   f0: float | None = None) -> Solve:
    """The root of a monotone ``residual`` in [low, high], or the edge nearest to it.

    Starts at ``x0`` (clipped into the range); the second point is a Newton step with
    ``derivative`` if given, else ``x0 + step`` toward the root on the assumption that the
    residual increases with x.  Until the root is bracketed: secant steps clipped to the range;
    when a step is clipped onto an edge already evaluated (the residual there has the sign of
    every other evaluation, and the secant points out of the range), the solve ends at that edge
    (status ``lower edge`` or ``upper edge``: the target is not met inside the range).  Once
    bracketed: Illinois false position (the residual of an end kept twice in a row is halved),
    which never leaves the bracket.  Ends when |residual| <= ``tolerance`` (``converged``), when
    the bracket is narrower than ``x_tolerance`` (``bracket``: the best end), or after
    ``max_evaluations`` (``evaluations``: the best point).  ``f0``: the residual at ``x0`` if
    it is known already (it then counts as the first evaluation without being computed again).
    """
    history: list[tuple[float, float]] = []

    def ev(x: float) -> float:
        f = float(residual(x))
        if not math.isfinite(f):
            raise FitError(f"the response is not finite at {x:g}")
        history.append((x, f))
        return f

    def best(status: str) -> Solve:
        x, f = min(history, key=lambda p: abs(p[1]))
        return Solve(x, f, status, history)

    x = min(max(x0, low), high)
    if f0 is not None and x == x0:
        f = float(f0)
        history.append((x, f))
    else:
        f = ev(x)
    below = (x, f) if f < 0 else None  # the bracket's ends: residual < 0 and > 0
    above = (x, f) if f >= 0 else None
    last_end = None  # which end the last evaluation replaced (Illinois)
    previous, current = None, (x, f)
    while abs(current[1]) > tolerance:
        if below is not None and above is not None:
            if above[0] - below[0] != 0 and abs(above[0] - below[0]) <= x_tolerance:
                return best("bracket")
            x_new = below[0] - below[1] * (above[0] - below[0]) / (above[1] - below[1])
        else:
            if previous is None:
                x_new = (current[0] - current[1] / derivative if derivative
                         else current[0] - math.copysign(step, current[1]))
            else:
                x_new = _secant(previous, current)
                if x_new is None:
                    x_new = current[0] - math.copysign(step, current[1])
            x_new = min(max(x_new, low), high)
            if any(x_new == xe for xe, _ in history):
                edge = "lower edge" if x_new == low else "upper edge" if x_new == high else None
                if edge is None:  # a secant step onto a point already run: step instead
                    x_new = min(max(current[0] - math.copysign(step, current[1]), low), high)
                    if any(x_new == xe for xe, _ in history):
                        return best("evaluations")
                else:
                    xe, fe = next(p for p in history if p[0] == x_new)
                    return Solve(xe, fe, edge, history)
        if len(history) >= max_evaluations:
            return best("evaluations")
        f_new = ev(x_new)
        if f_new < 0:
            if last_end == "below" and above is not None:
                above = (above[0], above[1] / 2)
            below, last_end = (x_new, f_new), "below"
        else:
            if last_end == "above" and below is not None:
                below = (below[0], below[1] / 2)
            above, last_end = (x_new, f_new), "above"
        previous, current = current, (x_new, f_new)
    return Solve(current[0], current[1], "converged", history)


def _secant(a: tuple[float, float], b: tuple[float, float]) -> float | None:
    """Where the line through the points a, b (x, residual) crosses zero (None if flat)."""
    (xa, fa), (xb, fb) = a, b
    if fb == fa or xb == xa:
        return None
    return xb - fb * (xb - xa) / (fb - fa)


# -- the runs ---------------------------------------------------------------------------------
class PointRunner:
    """Computes runs as points of the sweep's storage in ``points_dir``: a stored point is read
    back; the others are computed in this process (``client`` None) or on the Dask cluster of
    ``client`` through the sweep engine.  ``log(record, params)`` is called for every run."""

    def __init__(self, points_dir: Path, client=None, log: Callable | None = None):
        self.points_dir = Path(points_dir)
        self.points_dir.mkdir(parents=True, exist_ok=True)
        self.engine = PointEngine(client, self.points_dir) if client is not None else None
        self.log = log or (lambda record, params: None)

    def run(self, points: list[RunParams]) -> list[PointRecord]:
        keys = [point_key(p) for p in points]
        records: dict[str, PointRecord] = {}
        todo: OrderedDict[str, RunParams] = OrderedDict()
        for key, params in zip(keys, points):
            if key in records or key in todo:
                continue
            record = stored_record(self.points_dir, key)
            if record is not None:
                records[key] = record
                self.log(record, params)
            else:
                todo[key] = params
        if self.engine is None:
            from sweep.worker import compute_point

            for key, params in todo.items():
                record, data = compute_point(params, key)
                save_point(self.points_dir, key, record, data)
                records[key] = record
                self.log(record, params)
        else:
            waiting = OrderedDict(todo)
            source = {"fit": lambda n: list(waiting.items())[:n]}
            while waiting or self.engine.tasks:
                for key in self.engine.feed(source):
                    del waiting[key]
                self.engine.wait(timeout=1.0)
                for key, _, record in self.engine.collect():
                    records[key] = record
                    self.log(record, todo[key])
        return [records[key] for key in keys]


@contextmanager
def point_runner(points_dir: Path, workers: int, warm: RunParams, log: Callable | None = None):
    """A :class:`PointRunner` on ``points_dir``: in this process (``workers`` 0) or on a local
    Dask cluster of ``workers`` processes (their Numba cache warmed on ``warm`` first), closed
    when the block ends."""
    if workers <= 0:
        yield PointRunner(points_dir, None, log)
        return
    from sweep.cluster import close_client, make_client
    from sweep.numba_cache import warm_numba_cache

    warm_numba_cache(warm)
    client = make_client(workers=workers)
    try:
        yield PointRunner(points_dir, client, log)
    finally:
        close_client(client)


@dataclass
class Responses:
    """The two responses of the fit at a trial (G_t, g), from real runs.

    ``base``: the run parameters of the reference eye (user units; without thickness and the
    two fitted parameters); ``ccts``: the CCTs [mm] of the slope; ``reference_cct``: where CH
    is read.  ``calibration_iops``: None for the raw readings (IOPg, CH); otherwise the IOPs
    [mmHg] of the calibration's reference sweep, made again at every trial (G_t, g) because a
    calibration is a property of the population it was made on: the readings are then the
    calibrated IOPg_cal and CH_cal (``airpuff_core.calibration``, docs/calibration.md).
    """

    runner: PointRunner
    base: dict
    ccts: tuple[float, ...] = CCT_POINTS
    reference_cct: float = REFERENCE_CCT
    calibration_iops: tuple[float, ...] | None = None
    evaluations: list[dict] = field(default_factory=list)
    log: Callable[[dict], None] = print
    _calibrations: dict = field(default_factory=dict, repr=False)

    @property
    def readings(self) -> dict[str, str]:
        """The readings fitted: the CCT slope's and CH's metric names."""
        return dict(RAW_READINGS if self.calibration_iops is None else CALIBRATED_READINGS)

    def params(self, shear: float, ratio: float, cct: float, **eye) -> RunParams:
        return RunParams.from_dict({**self.base, SHEAR.name: shear, RATIO.name: ratio,
                                    "thickness": cct, **eye})

    def _run(self, shear: float, ratio: float, points: list[RunParams]) -> list[dict]:
        records = self.runner.run(points)
        for p, record in zip(points, records):
            if not record.ok:
                raise FitError(f"the run at G_t {shear:g} kPa, g {ratio:g}, CCT {p.thickness:g} "
                               f"mm, IOP {p.IOP:g} mmHg failed: {record.message}")
        return [record.metrics for record in records]

    def _readings(self, shear: float, ratio: float, ccts) -> list[dict[str, float]]:
        """The fitted readings (``slope``, ``CH``) of the reference eye at each CCT."""
        metrics = self._run(shear, ratio, [self.params(shear, ratio, c) for c in ccts])
        if self.calibration_iops is None:
            return [{"slope": m["IOPg"], "CH": m["CH"]} for m in metrics]
        from airpuff_core.calibration import apply_coefficients

        coefficients = self.calibration(shear, ratio)
        out = []
        for m in metrics:
            cal = apply_coefficients(coefficients, _number(m["P1"]), _number(m["P2"]))
            out.append({"slope": cal[CALIBRATED_READINGS["slope"]],
                        "CH": cal[CALIBRATED_READINGS["CH"]]})
        return out

    def calibration(self, shear: float, ratio: float) -> dict[str, float]:
        """The calibration's coefficients at (G_t, g): ``airpuff calibrate``'s fit on the IOP
        sweep of its reference eye (``airpuff_core.calibration.REFERENCE_EYE``) with these
        tissue values; made once per trial and recorded as an evaluation."""
        if (shear, ratio) in self._calibrations:
            return self._calibrations[(shear, ratio)]
        from airpuff_core.calibration import REFERENCE_EYE, apply_coefficients, fit_coefficients

        points = [self.params(shear, ratio, REFERENCE_EYE["thickness"],
                              **{**REFERENCE_EYE, "IOP": iop}) for iop in self.calibration_iops]
        metrics = self._run(shear, ratio, points)
        p1 = [_number(m["P1"]) for m in metrics]
        p2 = [_number(m["P2"]) for m in metrics]
        try:
            coefficients = fit_coefficients(list(self.calibration_iops), p1, p2)
        except ValueError as err:
            raise FitError(f"no calibration at G_t {shear:g} kPa, g {ratio:g}: {err}") from None
        self._calibrations[(shear, ratio)] = coefficients
        errors = np.asarray(apply_coefficients(coefficients, p1, p2)["IOPg_cal"]) - np.asarray(
            self.calibration_iops)
        self._record("calibration_slope", shear, ratio, coefficients["pressure_slope"], "",
                     {"coefficients": coefficients, "IOP": list(self.calibration_iops),
                      "P1_raw": p1, "P2_raw": p2,
                      "max_error_mmHg": float(np.max(np.abs(errors)))})
        return coefficients

    def slope(self, shear: float, ratio: float, solve: str = "") -> float:
        """Least-squares slope [mmHg per 100 um] of the slope reading over ``ccts``; the CH
        reading at the reference CCT, if it is one of them, is recorded too."""
        readings = self._readings(shear, ratio, self.ccts)
        values = np.array([r["slope"] for r in readings], dtype=float)
        if not np.all(np.isfinite(values)):
            raise FitError(f"{self.readings['slope']} is missing at G_t {shear:g} kPa, "
                           f"g {ratio:g} (CCT {list(self.ccts)}): {values.tolist()}")
        slope_per_mm = np.polyfit(np.array(self.ccts), values, 1)[0]
        value = float(slope_per_mm * 0.1)
        detail = {"ccts_mm": list(self.ccts), "readings_mmHg": values.tolist()}
        if self.reference_cct in self.ccts:
            detail["CH_at_reference"] = readings[self.ccts.index(self.reference_cct)]["CH"]
        self._record("cct_slope", shear, ratio, value, solve, detail)
        return value

    def ch(self, shear: float, ratio: float, solve: str = "") -> float:
        """The CH reading [mmHg] at the reference CCT."""
        (reading,) = self._readings(shear, ratio, (self.reference_cct,))
        value = reading["CH"]
        if value is None or not math.isfinite(value):
            raise FitError(f"{self.readings['CH']} is missing at G_t {shear:g} kPa, g {ratio:g}")
        self._record("CH", shear, ratio, float(value), solve, {})
        return float(value)

    def _record(self, response, shear, ratio, value, solve, detail):
        entry = {"kind": "response", "n": len(self.evaluations) + 1, "solve": solve,
                 "response": response, SHEAR.name: shear, RATIO.name: ratio, "value": value,
                 **detail}
        self.evaluations.append(entry)
        self.log(entry)


def _number(value) -> float:
    """A metric of a point record as a float (None, a missing reading, is NaN)."""
    return math.nan if value is None else float(value)


# -- the fit ----------------------------------------------------------------------------------
@dataclass
class FitResult:
    shear: float
    ratio: float
    shear_status: str
    ratio_status: str
    slope: float
    ch: float
    solves: list[dict]
    outer_iterations: int


def fit(responses: Responses, slope_target: Target = SLOPE_TARGET, ch_target: Target = CH_TARGET,
        start: tuple[float, float] | None = None, max_outer: int = 3,
        max_evaluations: int = 8) -> FitResult:
    """G_t to the CCT slope and g to CH, block-triangular (the module's docstring): solve the
    slope for G_t at the current g, CH for g at that G_t, check the slope at the new g; repeat
    from a Newton step while the slope is out of its tolerance (at most ``max_outer`` times)."""
    shear, ratio = start or (SHEAR.published, RATIO.published)
    solves: list[dict] = []
    # the first Newton steps' derivatives; each later solve starts from its predecessor's
    shear_derivative = FIRST_DERIVATIVES[SHEAR.name]
    ratio_derivative = FIRST_DERIVATIVES[RATIO.name]
    shear_step = 0.25 * (SHEAR.high - SHEAR.low)
    ratio_step = 0.25 * (RATIO.high - RATIO.low)
    slope_residual = None  # the slope's residual at (shear, ratio), once the check knows it
    for outer in range(1, max_outer + 1):
        g = ratio
        s = solve_monotone(lambda x: responses.slope(x, g, f"G_t #{outer}") - slope_target.value,
                           SHEAR.low, SHEAR.high, shear, shear_step, slope_target.tolerance,
                           max_evaluations, shear_derivative,
                           x_tolerance=1e-4 * (SHEAR.high - SHEAR.low), f0=slope_residual)
        solves.append({"parameter": SHEAR.name, "outer": outer, "at": {RATIO.name: g},
                       **asdict(s), "bracket": s.bracket(),
                       "jump_ratio": s.jump_ratio()})
        shear = s.x
        shear_derivative = s.derivative() or shear_derivative
        r = solve_monotone(lambda x: responses.ch(shear, x, f"g #{outer}") - ch_target.value,
                           RATIO.low, RATIO.high, ratio, ratio_step, ch_target.tolerance,
                           max_evaluations, ratio_derivative,
                           x_tolerance=1e-4 * (RATIO.high - RATIO.low))
        solves.append({"parameter": RATIO.name, "outer": outer, "at": {SHEAR.name: shear},
                       **asdict(r), "bracket": r.bracket(),
                       "jump_ratio": r.jump_ratio()})
        ratio = r.x
        ratio_derivative = r.derivative() or ratio_derivative
        slope = responses.slope(shear, ratio, f"check #{outer}")
        ch = responses.ch(shear, ratio, f"check #{outer}")
        slope_residual = slope - slope_target.value
        if abs(slope_residual) <= slope_target.tolerance or (
                s.status.endswith("edge") and _beyond_edge(s, slope_residual)):
            return FitResult(shear, ratio, s.status, r.status, slope, ch, solves, outer)
    return FitResult(shear, ratio, "outer iterations", r.status, slope, ch, solves, max_outer)


def _beyond_edge(solve: Solve, residual: float) -> bool:
    """Whether a solve that stopped at an edge still has its residual on the same side there
    (the target is still out of reach at the new g)."""
    return math.copysign(1.0, residual) == math.copysign(1.0, solve.residual)


def sensitivities(slope_points, ch_points, at: tuple[float, float]) -> dict:
    """The responses' local derivatives at ``at`` = (G_t, g) and what they mean for the fit.

    ``slope_points`` and ``ch_points``: (G_t, g, value) of every evaluation (CH also from the
    reference-CCT runs of the slope's evaluations).  Each response is fitted by a plane through
    the 4 distinct points nearest to ``at`` (distances in units of each parameter's range).
    ``gauss_seidel_factor`` = |dS/dg dCH/dG_t / (dS/dG_t dCH/dg)|, the factor by which one
    outer iteration of :func:`fit` shrinks the error of a linear model: small when the two
    responses are decoupled."""
    def plane(points):
        pts = sorted({(p[0], p[1]): p[2] for p in points}.items(),
                     key=lambda kv: ((kv[0][0] - at[0]) / (SHEAR.high - SHEAR.low)) ** 2
                     + ((kv[0][1] - at[1]) / (RATIO.high - RATIO.low)) ** 2)[:4]
        if len(pts) < 3:
            return None
        a = np.array([[1.0, x - at[0], y - at[1]] for (x, y), _ in pts])
        v = np.array([val for _, val in pts])
        coef, _, rank, _ = np.linalg.lstsq(a, v, rcond=None)
        return coef[1:] if rank == 3 else None

    ds, dc = plane(slope_points), plane(ch_points)
    if ds is None or dc is None:
        return {}
    out = {"dslope_dG_t": ds[0], "dslope_dg": ds[1], "dCH_dG_t": dc[0], "dCH_dg": dc[1]}
    out["gauss_seidel_factor"] = abs(ds[1] * dc[0] / (ds[0] * dc[1])) if ds[0] * dc[1] else math.nan
    return {k: float(v) for k, v in out.items()}


# -- the records --------------------------------------------------------------------------------
def run_entry(record: PointRecord, params: RunParams) -> dict:
    """The record of one run in the fit's log."""
    m = record.metrics or {}
    return {"kind": "run", "key": record.key, "status": record.status,
            "computed": record.computed, "message": record.message, "wall_s": record.wall_s,
            SHEAR.name: params.transverse_shear_modulus, RATIO.name: params.ve_g,
            "thickness": params.thickness, "IOP": params.IOP,
            **{name: m.get(name) for name in ("P1", "P2", "CH", "IOPg", "CRF", "IOPcc_ora",
                                              "DA", "t_A1", "t_A2")}}


class FitLog:
    """A fit's log: every evaluation of a response and every run, appended to ``path`` (JSON
    lines, the file emptied first: stored runs are reused, their entries repeated) and printed
    on one line each; the runs' entries are kept in ``runs``."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.path.write_text("")
        self.runs: list[dict] = []

    def __call__(self, entry: dict) -> None:
        with open(self.path, "a") as f:
            f.write(json.dumps(entry, default=_json_default) + "\n")
        if entry["kind"] == "run":
            print(f"  run G_t {entry[SHEAR.name]:.4f} g {entry[RATIO.name]:.4f} CCT "
                  f"{entry['thickness']:g}: {entry['status']} "
                  f"{'computed' if entry['computed'] else 'reused'} "
                  f"IOPg {entry['IOPg']} CH {entry['CH']}", flush=True)
        else:
            calibration = (f" (P_cal = {entry['coefficients']['pressure_offset']:.4f} + "
                           f"{entry['value']:.5f} P, IOPg_cal - IOP max "
                           f"{entry['max_error_mmHg']:.3f} mmHg on its reference sweep)"
                           if entry["response"] == "calibration_slope" else "")
            print(f"[{entry['solve']}] {entry['response']} at G_t {entry[SHEAR.name]:.4f} kPa, "
                  f"g {entry[RATIO.name]:.4f}: {entry['value']:.4f}{calibration}", flush=True)

    def run(self, record: PointRecord, params: RunParams) -> None:
        """Logs one run (a ``PointRunner``'s ``log``)."""
        entry = run_entry(record, params)
        self.runs.append(entry)
        self(entry)


def write_outputs(out: Path, summary: dict, runs: list[dict], evaluations: list[dict]) -> None:
    """``fit.json`` (everything), ``fit.nc`` (the runs and the evaluations as variables, the
    fit as attributes) and ``fit.md`` (the table), each written atomically."""
    import xarray as xr

    text = json.dumps({**summary, "runs": runs, "evaluations": evaluations}, indent=1,
                      default=_json_default)
    atomic_write(out / "fit.json", lambda tmp: tmp.write_text(text + "\n"))

    def column(rows, name, kind=float):
        if kind is float:
            return np.array([np.nan if r.get(name) is None else float(r[name]) for r in rows])
        return np.array([str(r.get(name, "")) for r in rows], dtype=object)

    data = {}
    for name in ("status", "key"):
        data[f"run_{name}"] = ("run", column(runs, name, str))
    for name in (SHEAR.name, RATIO.name, "thickness", "IOP", "P1", "P2", "CH", "IOPg", "CRF",
                 "IOPcc_ora", "DA", "t_A1", "t_A2", "wall_s"):
        data[f"run_{name}"] = ("run", column(runs, name))
    for name in ("response", "solve"):
        data[f"evaluation_{name}"] = ("evaluation", column(evaluations, name, str))
    for name in (SHEAR.name, RATIO.name, "value"):
        data[f"evaluation_{name}"] = ("evaluation", column(evaluations, name))
    ds = xr.Dataset(data)
    units = {SHEAR.name: "kPa", RATIO.name: "1", "thickness": "mm", "IOP": "mmHg", "P1": "mmHg",
             "P2": "mmHg", "CH": "mmHg", "IOPg": "mmHg", "CRF": "mmHg", "IOPcc_ora": "mmHg",
             "DA": "mm", "t_A1": "ms", "t_A2": "ms", "wall_s": "s"}
    for name, unit in units.items():
        ds[f"run_{name}"].attrs["units"] = unit
    ds["evaluation_value"].attrs["comment"] = ("cct_slope in mmHg per 100 um, CH in mmHg "
                                               "(evaluation_response)")
    for key, value in summary.items():
        ds.attrs[key] = value if isinstance(value, (str, int, float)) else json.dumps(
            value, default=_json_default)
    atomic_write(out / "fit.nc", lambda tmp: ds.to_netcdf(tmp))
    atomic_write(out / "fit.md", lambda tmp: tmp.write_text(markdown(summary, evaluations)))


def _json_default(value):
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    raise TypeError(f"not JSON: {value!r}")


def markdown(summary: dict, evaluations: list[dict]) -> str:
    """The fit as a markdown table: the fitted values against their ranges and targets, then
    every evaluation of a response."""
    lines = [f"# {summary['title']}", "", summary["mode_note"], "",
             f"Command: `{summary['command']}`  ", f"Model version {summary['model_version']}, "
             f"resolution {summary['resolution']}, instrument {summary['instrument']}, "
             f"readings {summary['readings']}; {summary['runs_computed']} runs computed, "
             f"{summary['runs_reused']} reused, {summary['wall_s']:.0f} s.", "",
             "| parameter | published | range | fitted | status | target | reached |",
             "|---|---|---|---|---|---|---|"]
    for p, t in ((SHEAR, summary["targets"]["cct_slope"]), (RATIO, summary["targets"]["CH"])):
        fitted = summary["fitted"][p.name]
        lines.append(
            f"| {p.symbol} (`{p.name}`) [{p.unit}] | {p.published:g} | {p.low:g} - {p.high:g} | "
            f"{fitted['value']:.4g} | {fitted['status']} | {t['name']} {t['value']:g} +- "
            f"{t['tolerance']:g} {t['unit']} | {fitted['reached']:.3f} |")
    lines += ["", "Ranges: " + "; ".join(f"{p.symbol}: {p.range_source}" for p in (SHEAR, RATIO)),
              "", "Targets: " + "; ".join(f"{t['name']}: {t['source']}"
                                          for t in summary["targets"].values()), ""]
    sens = summary.get("sensitivities") or {}
    if sens:
        lines += [f"Local derivatives at the fit (planes through the nearest evaluations): "
                  f"slope {sens['dslope_dG_t']:+.3f} per kPa, {sens['dslope_dg']:+.2f} per unit g "
                  f"[mmHg per 100 um]; CH {sens['dCH_dG_t']:+.3f} per kPa, {sens['dCH_dg']:+.1f} per "
                  f"unit g [mmHg]. One outer iteration shrinks a linear model's error by "
                  f"{sens['gauss_seidel_factor']:.3f} (|dS/dg dCH/dG_t / (dS/dG_t dCH/dg)|); "
                  f"{summary['outer_iterations']} outer iteration(s) run.", ""]
    lines += solve_lines(summary.get("solves") or [])
    lines += calibration_lines(evaluations, summary)
    lines += ["| # | solve | response | G_t [kPa] | g | value |", "|---|---|---|---|---|---|"]
    for e in evaluations:
        lines.append(f"| {e['n']} | {e['solve']} | {e['response']} | {e[SHEAR.name]:.4f} | "
                     f"{e[RATIO.name]:.4f} | {e['value']:.3f} |")
    return "\n".join(lines) + "\n"


JUMP_RATIO = 10.0  # a bracket's slope this many times the search's: the response jumps there


def solve_lines(solves: list[dict]) -> list[str]:
    """Each 1-D solve's end in words: its status, where it stopped and, if it bracketed the
    target without meeting it, the bracket and whether the response jumps across the target
    there (``Solve.jump_ratio`` above ``JUMP_RATIO``)."""
    if not solves:
        return []
    symbols = {SHEAR.name: SHEAR.symbol, RATIO.name: RATIO.symbol}
    lines = ["Solves:", ""]
    for s in solves:
        text = (f"- {symbols[s['parameter']]} #{s['outer']}: {s['status']} at {s['x']:.5g} "
                f"(residual {s['residual']:+.3f}, {len(s['history'])} evaluations)")
        bracket = s.get("bracket")
        if s["status"] != "converged" and bracket:
            (xa, fa), (xb, fb) = bracket
            ratio = s.get("jump_ratio")
            jumps = ratio is not None and ratio > JUMP_RATIO
            text += (f"; the target lies between {xa:.5g} ({fa:+.3f}) and {xb:.5g} ({fb:+.3f})"
                     + (f": the response JUMPS across it there ({ratio:.0f} x its slope "
                        f"elsewhere), no value meets it" if jumps else ""))
        lines.append(text)
    return lines + [""]


CALIBRATION_AIM = 0.3  # mmHg, airpuff calibrate's aim on its reference sweep (docs/calibration.md)


def calibration_lines(evaluations: list[dict], summary: dict) -> list[str]:
    """The calibrations the fit made (one per trial): how many, the spread of their slopes,
    which missed ``CALIBRATION_AIM`` on their reference sweep, and the one at the fitted
    values."""
    made = [e for e in evaluations if e["response"] == "calibration_slope"]
    if not made:
        return []
    slopes = [e["value"] for e in made]
    missed = [e for e in made if e.get("max_error_mmHg", 0.0) > CALIBRATION_AIM]
    text = (f"Calibrations made: {len(made)} (one per trial (G_t, g)), slope b "
            f"{min(slopes):.4f} to {max(slopes):.4f}; {len(missed)} missed "
            f"{CALIBRATION_AIM:g} mmHg on their reference sweep"
            + (": " + ", ".join(f"(G_t {e[SHEAR.name]:.4g}, g {e[RATIO.name]:.4g}) "
                                 f"{e['max_error_mmHg']:.2f}" for e in missed) if missed else ""))
    fitted = summary.get("fitted") or {}
    at = (fitted.get(SHEAR.name, {}).get("value"), fitted.get(RATIO.name, {}).get("value"))
    final = [e for e in made if (e[SHEAR.name], e[RATIO.name]) == at]
    if final:
        e = final[-1]
        text += (f". At the fitted values: P_cal = {e['coefficients']['pressure_offset']:.4f} + "
                 f"{e['value']:.5f} P, IOPg_cal - IOP max {e['max_error_mmHg']:.3f} mmHg")
        if e["max_error_mmHg"] > CALIBRATION_AIM:
            text += (f" (MISSES {CALIBRATION_AIM:g} mmHg: the readings fitted there are not on "
                     f"Goldmann's scale, so neither is the fit)")
    return [text + ".", ""]


# -- the command ----------------------------------------------------------------------------------
def _floats(text: str) -> tuple[float, ...]:
    return tuple(parse_decimal(v) for v in text.split(","))


def _fail(message: str) -> None:
    sys.stderr.write(f"fit_clinical: error: {message}\n")
    raise SystemExit(2)


def instruments() -> tuple[str, ...]:
    """The instruments of this version of the solver (the paper's jet when it has none)."""
    return CHOICES.get("instrument", ("paper",))


def calibration_available() -> bool:
    """Whether this version of the solver has the instruments' calibration (issue 26)."""
    try:
        from airpuff_core.calibration import apply_coefficients, fit_coefficients  # noqa: F401
    except ImportError:
        return False
    return True


def check_mode(args) -> str:
    """``clinical`` (the ORA's pulse, calibrated readings, paper or fine resolution: coarse
    resolution reads CH 0.4-1.6 mmHg low, docs/validation.md) or ``development`` (anything
    else, only with ``--development``); what this version of the solver lacks is refused (one
    line, exit code 2)."""
    if args.instrument not in instruments():
        _fail(f"instrument: {args.instrument} is not in this version of the solver (it has "
              f"{', '.join(instruments())}; issue 26's pulses); run the labelled development "
              f"mode with --instrument paper --raw --development")
    if not args.raw and not calibration_available():
        _fail("readings: calibrated readings are not in this version of the solver (issue 26's "
              "calibration); run the labelled development mode with --raw --development")
    if args.instrument == "ora" and not args.raw and args.resolution != "coarse":
        return "clinical"
    if not args.development:
        what = " ".join(f for f, on in ((f"--instrument {args.instrument}", True),
                                        ("--raw", args.raw),
                                        ("--resolution coarse", args.resolution == "coarse"))
                        if on)
        _fail(f"{what} gives no clinical fit (the clinical fit is the ORA's calibrated reading "
              f"at paper or fine resolution): add --development to run the labelled "
              f"development mode")
    return "development"


def parse_args(argv):
    from api.cli.common import OneLineParser

    ap = OneLineParser(prog="fit_clinical", description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="folder of the fit and its runs")
    ap.add_argument("--resolution", default="paper", choices=CHOICES["resolution"])
    ap.add_argument("--instrument", default="ora", choices=("ora", "paper"),
                    help="the instrument's pulse (default ora: the clinical fit)")
    ap.add_argument("--raw", action="store_true",
                    help="fit the raw readings (development mode only)")
    ap.add_argument("--development", action="store_true",
                    help="allow --instrument paper or --raw: a labelled development fit")
    ap.add_argument("--slope-target", default=str(SLOPE_TARGET.value),
                    help="population slope of the reading against CCT [mmHg per 100 um]")
    ap.add_argument("--ch-target", default=str(CH_TARGET.value), help="population mean CH [mmHg]")
    ap.add_argument("--slope-tolerance", default=str(SLOPE_TARGET.tolerance))
    ap.add_argument("--ch-tolerance", default=str(CH_TARGET.tolerance))
    ap.add_argument("--cct", default=",".join(f"{c:g}" for c in CCT_POINTS),
                    help="CCTs of the slope [mm]; the reference CCT must be one of them")
    ap.add_argument("--reference-cct", default=str(REFERENCE_CCT), help="CCT of CH [mm]")
    ap.add_argument("--start", default=None, metavar="G_T,G",
                    help="starting values (default the published 9.48 kPa, 0.3)")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="any other run parameter of the reference eye (e.g. E0=0.6, IOP=18)")
    ap.add_argument("--points", type=Path, default=None,
                    help="folder of the runs' storage (default <out>/points); fits that share "
                         "one reuse their common runs (studies/fit_sensitivity.py)")
    ap.add_argument("--workers", default="0",
                    help="Dask worker processes for the runs (0: in this process)")
    ap.add_argument("--max-evaluations", default="8", help="evaluations per 1-D solve")
    ap.add_argument("--calibration-iop", default=None, metavar="IOPS",
                    help="IOPs [mmHg] of the calibration's reference sweep, made at every trial "
                         "(default that of airpuff calibrate)")
    return ap.parse_args(argv), ap


@dataclass
class FitSetup:
    """A fit's options, parsed and checked (:func:`fit_setup`): its mode, targets, the reference
    eye's run parameters ``base`` (user units; without thickness and the two fitted
    parameters), the slope's CCTs, where CH is read, the calibration's IOPs (None: raw readings),
    the start, the workers and the evaluations per 1-D solve."""

    args: object
    argv: list[str]
    mode: str
    slope_target: Target
    ch_target: Target
    base: dict
    ccts: tuple[float, ...]
    reference_cct: float
    calibration_iops: tuple[float, ...] | None
    start: tuple[float, float] | None
    workers: int
    max_evaluations: int

    def responses(self, runner: PointRunner, log: Callable[[dict], None] = print) -> Responses:
        """The fit's :class:`Responses` on ``runner``."""
        return Responses(runner, self.base, self.ccts, self.reference_cct,
                         self.calibration_iops, log=log)

    def warm_params(self) -> RunParams:
        """The reference eye's run at the published tissue values (warms a cluster's cache)."""
        return RunParams.from_dict({**self.base, "thickness": self.reference_cct})


def fit_setup(argv: list[str]) -> FitSetup:
    """The fit's command line, parsed and checked; bad input ends with one line and exit
    code 2 (nothing run, nothing written)."""
    args, ap = parse_args(argv)
    mode = check_mode(args)
    try:
        slope_target = Target(**{**asdict(SLOPE_TARGET), "value": parse_decimal(args.slope_target),
                                 "tolerance": parse_decimal(args.slope_tolerance)})
        ch_target = Target(**{**asdict(CH_TARGET), "value": parse_decimal(args.ch_target),
                              "tolerance": parse_decimal(args.ch_tolerance)})
        ccts = _floats(args.cct)
        reference_cct = parse_decimal(args.reference_cct)
        start = _floats(args.start) if args.start else None
        workers = int(args.workers)
        calibration_iops = None
        if not args.raw:
            from sweep.calibration import DEFAULT_IOP

            calibration_iops = (_floats(args.calibration_iop) if args.calibration_iop
                                else tuple(DEFAULT_IOP))
        max_evaluations = int(args.max_evaluations)
    except ValueError as err:
        ap.error(str(err))
    if len(ccts) < 2 or len(set(ccts)) != len(ccts):
        ap.error(f"--cct: at least two distinct CCTs, got {args.cct}")
    if args.raw and args.calibration_iop:
        ap.error("--calibration-iop: calibrated readings only (not with --raw)")
    if calibration_iops is not None and len(set(calibration_iops)) < 2:
        ap.error(f"--calibration-iop: at least two distinct IOPs, got {args.calibration_iop}")
    if start is not None and len(start) != 2:
        ap.error(f"--start: two values G_t,g, got {args.start}")
    if workers < 0 or max_evaluations < 2:
        ap.error("--workers: 0 or more; --max-evaluations: 2 or more")
    base = {"model": "clinical", "resolution": args.resolution, **REFERENCE}
    if "instrument" in CHOICES:
        base["instrument"] = args.instrument
    for item in args.set:
        name, _, value = item.partition("=")
        if name in (SHEAR.name, RATIO.name, "thickness", "model", "resolution", "instrument"):
            ap.error(f"--set {name}: set by the fit (use --start, --cct, --resolution, "
                     f"--instrument)")
        base[name] = value
    try:
        for c in set(ccts) | {reference_cct}:
            RunParams.from_dict({**base, "thickness": c})
    except ParameterError as err:
        ap.error(str(err))
    return FitSetup(args, list(argv), mode, slope_target, ch_target, base, ccts, reference_cct,
                    calibration_iops, start, workers, max_evaluations)


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    setup = fit_setup(argv)
    args, mode, base = setup.args, setup.mode, setup.base
    ccts, reference_cct, calibration_iops = setup.ccts, setup.reference_cct, setup.calibration_iops
    slope_target, ch_target = setup.slope_target, setup.ch_target

    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    log = FitLog(out / "evaluations.jsonl")
    runs = log.runs

    t0 = time.perf_counter()
    with point_runner(args.points or out / "points", setup.workers, setup.warm_params(),
                      log.run) as runner:
        responses = setup.responses(runner, log)
        try:
            result = fit(responses, slope_target, ch_target, setup.start,
                         max_evaluations=setup.max_evaluations)
            error = None
        except FitError as err:
            result, error = None, str(err)
    summary = summary_of(mode, args, argv, base, ccts, reference_cct, calibration_iops,
                         responses.readings, slope_target, ch_target, result, error, runs,
                         responses.evaluations, time.perf_counter() - t0)
    write_outputs(out, summary, runs, responses.evaluations)
    print(markdown(summary, responses.evaluations))
    return 1 if error else 0


def summary_of(mode, args, argv, base, ccts, reference_cct, calibration_iops, readings,
               slope_target, ch_target, result, error, runs, evaluations, wall_s) -> dict:
    """The fit's summary: what was fitted, how, from which runs."""
    development = mode == "development"
    title = ("DEVELOPMENT fit (not a clinical fit): " if development else "Clinical fit: ") + \
        f"G_t to the CCT slope, g to CH ({args.instrument}, " \
        f"{'raw' if args.raw else 'calibrated'} readings)"
    why = [w for w, on in (("not the ORA's pulse", args.instrument != "ora"),
                           ("raw readings", args.raw),
                           ("coarse resolution", args.resolution == "coarse")) if on]
    note = (f"Development mode ({', '.join(why)}): these numbers exercise the fit; they are "
            f"not fitted tissue values and make no clinical claim."
            if development else "The ORA pulse and the calibrated readings (the calibration made "
            "again at every trial). The numbers are the model version's: valid as a clinical fit "
            "only with settled numerics (docs/validation.md, the sound speed).")
    fitted = {}
    if result is not None:
        fitted = {SHEAR.name: {"value": result.shear, "status": result.shear_status,
                               "reached": result.slope},
                  RATIO.name: {"value": result.ratio, "status": result.ratio_status,
                               "reached": result.ch}}
    else:
        nan = {"value": math.nan, "status": f"failed: {error}", "reached": math.nan}
        fitted = {SHEAR.name: nan, RATIO.name: nan}
    return {
        "title": title, "mode": mode, "mode_note": note, "command":
            "python -m studies.fit_clinical " + " ".join(shlex.quote(a) for a in argv),
        "model_version": model_version(), "resolution": args.resolution,
        "instrument": args.instrument, "readings": "raw" if args.raw else "calibrated",
        "reading_names": readings, "reference_eye": {**base, "CCT_mm": reference_cct},
        "calibration_iops_mmHg": list(calibration_iops or []),
        "ccts_mm": list(ccts),
        "targets": {"cct_slope": asdict(slope_target), "CH": asdict(ch_target)},
        "ranges": {p.name: asdict(p) for p in (SHEAR, RATIO)},
        "fitted": fitted, "error": error or "",
        "outer_iterations": result.outer_iterations if result else 0,
        "sensitivities": sensitivities(
            [(e[SHEAR.name], e[RATIO.name], e["value"]) for e in evaluations
             if e["response"] == "cct_slope"],
            [(e[SHEAR.name], e[RATIO.name], e["value"]) for e in evaluations
             if e["response"] == "CH"]
            + [(e[SHEAR.name], e[RATIO.name], e["CH_at_reference"]) for e in evaluations
               if e["response"] == "cct_slope" and "CH_at_reference" in e],
            (result.shear, result.ratio)) if result else {},
        "solves": result.solves if result else [],
        "runs_computed": sum(1 for r in runs if r["computed"]),
        "runs_reused": sum(1 for r in runs if not r["computed"]),
        "wall_s": wall_s,
    }


if __name__ == "__main__":
    sys.exit(main())
