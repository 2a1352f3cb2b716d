"""A corrected IOP and a stiffness index fitted on a sweep: the step from a sweep to a formula.

The idea is that of the Corvis ST's bIOP (Joda et al., Comput Methods Biomech Biomed Engin 19
(2016) 1311) and the ORA's IOPcc (Luce, J Cataract Refract Surg 31 (2005) 156): run the model over
(IOP, E0, thickness), record what the instrument would read, and fit the true IOP (and here also
the stiffness E0) as a function of those readings.  docs/correction.md has the method, the file
format and the measured accuracy.

* **Readings** (:data:`INSTRUMENTS`).  ORA: P1, P2 [mmHg] and CCT [um].  Corvis ST: IOPnc [mmHg],
  CCT [um] and DA [mm].  The readings are the model's raw ones (``calibration: "raw"``, names
  ending in ``_raw``): the jet pressure at the apex at the applanations, with no instrument
  calibration.  The Corvis IOPnc is the raw P1 (the first-applanation jet pressure), and its DA
  the model's DA: the apex deflection against the limbus plus the whole eye's movement
  (``eye_motion = spring_damper``; with the default ``none`` the deflection alone).  A calibrated reading is switched in by a new :class:`Reading` (its sweep
  variable and calibration name); nothing else changes.
* **Form**: a polynomial of total degree d in the readings, each scaled to [-1, 1] over the fitted
  range, z = (x - center) / half_range; coefficients by linear least squares (numpy).
* **Degree** by k-fold cross-validation on the sweep's own points (folds from a seeded
  permutation): the smallest degree whose held-out RMS is within ``DEGREE_TOLERANCE`` (5 %) of
  the best degree's.  The held-out RMS of that degree is the formula's stated error.
* **Points** that failed, or in which a reading is missing (no applanation), are left out and
  counted.

The same machinery gives the surrogate of :func:`sobol_indices` (Sobol indices with SALib).
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import math
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from airpuff_core.params import PARAMETERS
from airpuff_core.result import METRICS
from airpuff_core.version import __version__

from .identification import SweepTable

FORMAT = "airpuff-correction/1"
MAX_DEGREE = 3
FOLDS = 5
SEED = 0
RANGE_TOLERANCE = 1e-9  # relative to a range's width: a value this close to its end is inside
DEGREE_TOLERANCE = 0.05  # a higher degree must lower the held-out RMS by more than this fraction


class CorrectionError(ValueError):
    """Bad input to a fit or an application.  ``str(err)`` is one line; ``field`` names the
    offending input (an option, a column, ``sweep`` or ``correction``)."""

    def __init__(self, field_name: str, message: str):
        self.field = field_name
        super().__init__(message)


# -- what each instrument reads ------------------------------------------------------------------

@dataclass(frozen=True)
class Reading:
    """One input of a correction formula.

    ``name`` is the name in the formula (``_raw`` while the reading is the model's uncalibrated
    one); ``column`` and ``aliases`` the CSV column names accepted for it (case-insensitive);
    the value is ``scale`` x the sweep's variable ``source`` (a metric, or ``thickness``)."""

    name: str
    column: str
    aliases: tuple[str, ...]
    unit: str
    source: str
    scale: float
    calibration: str
    description: str


_CCT = Reading("CCT", "CCT", ("Pachy", "CCT_um", "pachymetry"), "um", "thickness", 1000.0,
               "none (a model parameter)", "central corneal thickness")

INSTRUMENTS: dict[str, tuple[Reading, ...]] = {
    "ora": (
        Reading("P1_raw", "P1", ("Pressure1",), "mmHg", "P1", 1.0, "raw",
                "jet pressure at the apex at the first applanation (uncalibrated)"),
        Reading("P2_raw", "P2", ("Pressure2",), "mmHg", "P2", 1.0, "raw",
                "jet pressure at the apex at the second applanation (uncalibrated)"),
        _CCT,
    ),
    "corvis": (
        Reading("IOPnc_raw", "IOPnc", ("IOP",), "mmHg", "P1", 1.0, "raw",
                "non-corrected IOP: the jet pressure at the apex at the first applanation, raw "
                "(the model's P1; the Corvis ST's own pulse is not modelled yet)"),
        _CCT,
        Reading("DA_raw", "DA", ("DefAmp", "Def. Amp. Max"), "mm", "DA", 1.0, "raw",
                "deformation amplitude: the apex deflection against the limbus plus the whole "
                "eye's movement (eye_motion=spring_damper; with none, the deflection amplitude)"),
    ),
}

# What a correction estimates: name -> (unit, description)
TARGETS: dict[str, tuple[str, str]] = {
    "IOP": ("mmHg", "corrected IOP: the model's true intraocular pressure"),
    "E0": ("MPa", "stiffness index: the model's corneal tangent modulus E0 at zero strain"),
}


# -- polynomial response surfaces ------------------------------------------------------------------

def exponents(n_vars: int, degree: int,
              max_powers: Sequence[int] | None = None) -> list[tuple[int, ...]]:
    """Exponent tuples of every monomial of total degree <= ``degree`` in ``n_vars`` variables,
    ordered by degree, then with the first variable's power highest.  ``max_powers[k]`` caps
    variable k's power: a variable seen at m distinct values supports powers up to m - 1 only
    (on 2 values z^2 = 1 is the constant again)."""
    out = []
    for d in range(degree + 1):
        out.extend(sorted((e for e in itertools.product(range(d + 1), repeat=n_vars)
                           if sum(e) == d and (max_powers is None
                                               or all(a <= m for a, m in zip(e, max_powers)))),
                          reverse=True))
    return out


def supported_powers(x: np.ndarray) -> list[int]:
    """The highest power each column of ``x`` supports: its number of distinct values - 1."""
    return [int(np.unique(x[:, k]).size) - 1 for k in range(x.shape[1])]


def design_matrix(z: np.ndarray, powers: Sequence[tuple[int, ...]]) -> np.ndarray:
    """A[i, j] = prod_k z[i, k] ** powers[j][k] (z: scaled inputs, shape (n, n_vars))."""
    z = np.atleast_2d(z)
    return np.stack([np.prod(z ** np.asarray(p), axis=1) for p in powers], axis=1)


@dataclass
class Surface:
    """y = sum_j c_j prod_k z_k ** p_jk with z_k = (x_k - center_k) / half_range_k."""

    inputs: list[str]
    center: np.ndarray
    half_range: np.ndarray
    powers: list[tuple[int, ...]]
    coefficients: np.ndarray

    @property
    def degree(self) -> int:
        return max(sum(p) for p in self.powers)

    def scaled(self, x) -> np.ndarray:
        return (np.atleast_2d(np.asarray(x, float)) - self.center) / self.half_range

    def __call__(self, x) -> np.ndarray:
        """Values at the rows of ``x`` (shape (n, n_inputs), in the inputs' units)."""
        return design_matrix(self.scaled(x), self.powers) @ self.coefficients

    def gradient(self, x) -> np.ndarray:
        """d y / d x at the rows of ``x``: shape (n, n_inputs), in y's unit per input unit."""
        z = self.scaled(x)
        out = np.zeros(z.shape)
        for k in range(z.shape[1]):
            dp, factor = [], []
            for p in self.powers:
                q = list(p)
                factor.append(q[k])
                q[k] = max(q[k] - 1, 0)
                dp.append(tuple(q))
            out[:, k] = (design_matrix(z, dp) @ (self.coefficients * np.asarray(factor))
                         ) / self.half_range[k]
        return out

    def terms(self) -> list[dict[str, Any]]:
        return [{"term": term_name(self.inputs, p), "powers": dict(zip(self.inputs, map(int, p))),
                 "coefficient": float(c)} for p, c in zip(self.powers, self.coefficients)]

    def formula(self, target: str, digits: int = 4) -> str:
        """The formula as one line, in the scaled inputs z(name)."""
        parts = []
        for p, c in zip(self.powers, self.coefficients):
            t = term_name([f"z({n})" for n in self.inputs], p)
            parts.append(f"{c:+.{digits}g}" + ("" if t == "1" else f" {t}"))
        text = " ".join(parts).lstrip("+")
        return f"{target} = {text}"

    def to_dict(self) -> dict[str, Any]:
        return {"inputs": list(self.inputs),
                "scaling": {n: {"center": float(c), "half_range": float(h)}
                            for n, c, h in zip(self.inputs, self.center, self.half_range)},
                "degree": self.degree, "terms": self.terms()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Surface":
        inputs = list(d["inputs"])
        center = np.array([float(d["scaling"][n]["center"]) for n in inputs])
        half = np.array([float(d["scaling"][n]["half_range"]) for n in inputs])
        powers = [tuple(int(t["powers"][n]) for n in inputs) for t in d["terms"]]
        coef = np.array([float(t["coefficient"]) for t in d["terms"]])
        if not (np.all(np.isfinite(center)) and np.all(half > 0) and np.all(np.isfinite(coef))):
            raise ValueError("scaling and coefficients must be finite, half ranges > 0")
        return cls(inputs, center, half, powers, coef)


def term_name(names: Sequence[str], powers: Sequence[int]) -> str:
    factors = [n if p == 1 else f"{n}^{p}" for n, p in zip(names, powers) if p]
    return "*".join(factors) or "1"


def scaling_of(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(center, half_range) mapping each column's [min, max] to [-1, 1]."""
    lo, hi = x.min(axis=0), x.max(axis=0)
    return (lo + hi) / 2, (hi - lo) / 2


def fit_surface(x: np.ndarray, y: np.ndarray, degree: int, inputs: Sequence[str],
                center: np.ndarray | None = None, half_range: np.ndarray | None = None,
                max_powers: Sequence[int] | None = None) -> Surface:
    """Least-squares polynomial of total degree ``degree`` through the points (x, y), each
    variable's power capped by ``max_powers`` (default: what its distinct values support)."""
    if center is None or half_range is None:
        center, half_range = scaling_of(x)
    if max_powers is None:
        max_powers = supported_powers(x)
    powers = exponents(x.shape[1], degree, max_powers)
    a = design_matrix((x - center) / half_range, powers)
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    return Surface(list(inputs), np.asarray(center, float), np.asarray(half_range, float),
                   powers, coef)


def n_terms(n_vars: int, degree: int) -> int:
    return math.comb(n_vars + degree, degree)


def folds_of(n: int, folds: int = FOLDS, seed: int = SEED) -> list[np.ndarray]:
    """The held-out index sets of k-fold cross-validation (a seeded permutation, k = min(folds,
    n) nearly equal parts)."""
    perm = np.random.default_rng(seed).permutation(n)
    return [np.sort(part) for part in np.array_split(perm, min(folds, n))]


def held_out_predictions(x: np.ndarray, y: np.ndarray, degree: int,
                         parts: list[np.ndarray]) -> np.ndarray:
    """Each point predicted by the surface fitted without its fold (same scaling for all folds:
    the full range, so every fold's formula is the same kind of object)."""
    center, half = scaling_of(x)
    caps = supported_powers(x)
    pred = np.empty_like(y)
    for held in parts:
        train = np.setdiff1d(np.arange(y.size), held)
        s = fit_surface(x[train], y[train], degree, [""] * x.shape[1], center, half, caps)
        pred[held] = s(x[held])
    return pred


@dataclass
class FitResult:
    """A surface with its cross-validation: ``held_out`` is each point's prediction from the fit
    without its fold; ``scores`` the held-out RMS of every degree tried."""

    target: str
    surface: Surface
    x: np.ndarray
    y: np.ndarray
    held_out: np.ndarray
    scores: dict[int, float]
    folds: int
    seed: int

    @property
    def residual(self) -> np.ndarray:
        return self.held_out - self.y

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.residual ** 2)))

    @property
    def max_abs(self) -> float:
        return float(np.max(np.abs(self.residual)))

    def summary(self) -> dict[str, Any]:
        unit = TARGETS.get(self.target, METRICS.get(self.target, ("",)))[0]
        return {"unit": unit, **self.surface.to_dict(),
                "formula": self.surface.formula(self.target),
                "held_out": {"rms": self.rms, "max_abs": self.max_abs, "folds": self.folds,
                             "seed": self.seed,
                             "rms_by_degree": {str(d): r for d, r in self.scores.items()}},
                "in_sample_rms": float(np.sqrt(np.mean((self.surface(self.x) - self.y) ** 2)))}


def fit_by_cross_validation(x: np.ndarray, y: np.ndarray, inputs: Sequence[str], target: str,
                            max_degree: int = MAX_DEGREE, folds: int = FOLDS,
                            seed: int = SEED) -> FitResult:
    """Choose the degree (1..max_degree) by k-fold cross-validation, then fit it on all points.

    A degree is tried only if every training set has more points than the surface has terms.
    The smallest degree whose held-out RMS is within ``DEGREE_TOLERANCE`` of the best is chosen
    (a higher degree must earn its terms)."""
    parts = folds_of(y.size, folds, seed)
    n_train = y.size - max(len(p) for p in parts)
    caps = supported_powers(x)
    scores, preds = {}, {}
    for d in range(1, max_degree + 1):
        if d > 1 and len(exponents(x.shape[1], d, caps)) == len(exponents(x.shape[1], d - 1, caps)):
            break  # no term the data support is added
        if n_train <= len(exponents(x.shape[1], d, caps)):
            break
        preds[d] = held_out_predictions(x, y, d, parts)
        scores[d] = float(np.sqrt(np.mean((preds[d] - y) ** 2)))
    if not scores:
        raise CorrectionError("sweep", f"{y.size} usable points are too few for a linear formula "
                                       f"in {x.shape[1]} inputs with {len(parts)}-fold "
                                       f"cross-validation (needs at least "
                                       f"{math.ceil((n_terms(x.shape[1], 1) + 1) * len(parts) / max(len(parts) - 1, 1))})")
    best = min(scores.values())
    scale = float(np.std(y)) or 1.0
    degree = min(d for d, r in scores.items() if r <= best * (1 + DEGREE_TOLERANCE) + 1e-12 * scale)
    return FitResult(target, fit_surface(x, y, degree, inputs, max_powers=caps), x, y,
                     preds[degree], scores,
                     len(parts), seed)


# -- the sweep's points ----------------------------------------------------------------------------

AXES = ("E0", "IOP", "thickness", "pmax")


def sweep_points(table: SweepTable) -> dict[str, np.ndarray]:
    """Flat arrays over every grid point: the four parameters and every metric of the table."""
    grids = np.meshgrid(table.E0, table.IOP, table.thickness, table.pmax, indexing="ij")
    out = {name: g.ravel() for name, g in zip(AXES, grids)}
    out.update({name: a.ravel() for name, a in table.metrics.items()})
    if table.ok is not None:
        out["ok"] = np.asarray(table.ok, bool).ravel()
    return out


def select_pmax(table: SweepTable, pmax: float | None) -> SweepTable:
    """The table at one jet amplitude (an instrument's pulse is fixed): the sweep's only pmax,
    or the grid value ``pmax``."""
    values = np.asarray(table.pmax, float)
    if pmax is None:
        if values.size == 1:
            return table
        raise CorrectionError("pmax", "the sweep has several pmax values ("
                              + ", ".join(f"{v:g}" for v in values) + " kPa); give --pmax")
    hit = np.flatnonzero(np.isclose(values, pmax, rtol=1e-9, atol=1e-12))
    if not hit.size:
        raise CorrectionError("pmax", f"pmax={pmax:g} kPa is not a value of the sweep (it has "
                              + ", ".join(f"{v:g}" for v in values) + " kPa)")
    i = int(hit[0])
    return SweepTable(table.E0, table.IOP, table.thickness, values[i:i + 1],
                      {n: a[..., i:i + 1] for n, a in table.metrics.items()},
                      table.n_not_ok if table.ok is None else int((~table.ok[..., i]).sum()),
                      table.run_options, table.model_version,
                      None if table.ok is None else table.ok[..., i:i + 1])


def sweep_sources(instrument: str) -> tuple[str, ...]:
    """The sweep variables that the instrument's readings come from (metrics only)."""
    return tuple(dict.fromkeys(r.source for r in INSTRUMENTS[instrument] if r.source in METRICS))


# -- fitting a correction --------------------------------------------------------------------------

def _instrument(name: str) -> tuple[Reading, ...]:
    if name not in INSTRUMENTS:
        raise CorrectionError("instrument", f"invalid instrument={name!r}: accepted "
                                            + " or ".join(INSTRUMENTS))
    return INSTRUMENTS[name]


def fit_correction(table: SweepTable, instrument: str, max_degree: int = MAX_DEGREE,
                   folds: int = FOLDS, seed: int = SEED, pmax: float | None = None,
                   sweep_name: str = "") -> dict[str, Any]:
    """The correction file's content (a JSON-ready dict) fitted on ``table``.

    Raises CorrectionError for a sweep that cannot give a formula (a reading constant over the
    sweep, too few usable points)."""
    readings = _instrument(instrument)
    pulse = str(table.run_options.get("instrument", "paper"))
    if pulse != "paper" and pulse != instrument:
        # the readings of one instrument on a sweep under another's pulse mix two instruments;
        # the paper's jet stands for either (as before there was a choice of pulse)
        raise CorrectionError("instrument", f"invalid instrument={instrument!r}: the sweep was "
                                            f"computed with the {pulse} pulse: accepted {pulse}")
    if not 1 <= max_degree <= 4:
        raise CorrectionError("max-degree", f"invalid max-degree={max_degree!r}: accepted 1 to 4")
    if not 2 <= folds <= 20:
        raise CorrectionError("folds", f"invalid folds={folds!r}: accepted 2 to 20")
    missing = [s for s in sweep_sources(instrument) if s not in table.metrics]
    if missing:
        raise CorrectionError("sweep", "the sweep table lacks " + ", ".join(missing))
    table = select_pmax(table, pmax)
    pts = sweep_points(table)
    n_grid = pts["E0"].size
    x_all = np.stack([pts[r.source] * r.scale for r in readings], axis=1)
    usable = np.isfinite(x_all).all(axis=1)
    status_ok = pts["ok"] if "ok" in pts else usable
    n_failed = int((~status_ok).sum())
    n_no_reading = int((status_ok & ~usable).sum())
    x = x_all[usable]
    for k, r in enumerate(readings):
        if x.shape[0] and np.ptp(x[:, k]) <= 1e-12 * max(1.0, abs(x[:, k]).max()):
            raise CorrectionError("sweep", f"{r.name} takes one value ({x[0, k]:g} {r.unit}) "
                                           f"over the sweep: a formula in it needs a sweep over "
                                           f"{'thickness' if r.source == 'thickness' else 'IOP, E0 and thickness'}")
    names = [r.name for r in readings]
    truth = {"IOP": pts["IOP"][usable], "E0": pts["E0"][usable]}
    fits = {t: fit_by_cross_validation(x, truth[t], names, t, max_degree, folds, seed)
            for t in TARGETS}
    raw = raw_reading(instrument, x)
    return {
        "format": FORMAT,
        "instrument": instrument,
        "calibration": "raw" if any(r.calibration == "raw" for r in readings) else "calibrated",
        "readings": [{"name": r.name, "column": r.column, "aliases": list(r.aliases),
                      "unit": r.unit, "calibration": r.calibration, "sweep_variable": r.source,
                      "description": r.description,
                      "range": [float(x[:, k].min()), float(x[:, k].max())]}
                     for k, r in enumerate(readings)],
        "targets": {t: {"description": TARGETS[t][1], **fits[t].summary(),
                        "range": [float(truth[t].min()), float(truth[t].max())]}
                    for t in TARGETS},
        "model_version": table.model_version,
        "airpuff_version": __version__,
        "sweep": {"file": sweep_name,
                  "grid": {"E0": _floats(table.E0), "IOP": _floats(table.IOP),
                           "thickness": _floats(table.thickness), "pmax": _floats(table.pmax)},
                  "units": {n: PARAMETERS[n].unit for n in AXES},
                  "run_options": dict(table.run_options),
                  "points": n_grid, "used": int(usable.sum()),
                  "excluded_failed": n_failed, "excluded_no_reading": n_no_reading},
        "points": {"E0": _floats(pts["E0"][usable]), "IOP": _floats(pts["IOP"][usable]),
                   "CCT": _floats(pts["thickness"][usable] * 1000.0),
                   **{r.name: _floats(x[:, k]) for k, r in enumerate(readings)},
                   **{f"{t}_held_out": _floats(fits[t].held_out) for t in TARGETS},
                   "raw_IOP_reading": _floats(raw)},
        "validation": validation(fits, pts["IOP"][usable], pts["thickness"][usable] * 1000.0,
                                 pts["E0"][usable], raw, RAW_READING[instrument][0]),
    }


def _floats(a) -> list[float]:
    return [float(v) for v in np.asarray(a, float).ravel()]


# The uncorrected IOP reading of each instrument, against which the correction is judged:
# (name, function of the readings' columns)
RAW_READING = {
    "ora": ("IOPg_raw = (P1_raw + P2_raw) / 2", lambda x: 0.5 * (x[:, 0] + x[:, 1])),
    "corvis": ("IOPnc_raw", lambda x: x[:, 0]),
}


def raw_reading(instrument: str, x: np.ndarray) -> np.ndarray:
    return RAW_READING[instrument][1](x)


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's rank correlation (Pearson's of the average ranks, ties shared).  Values of
    ``a`` equal to 1e-9 of its spread are ties (rounding must not rank an exact prediction of a
    grid's repeated values)."""
    from scipy.stats import spearmanr

    a = np.asarray(a, float)
    step = 1e-9 * (np.ptp(a) or 1.0)
    return float(spearmanr(np.round(a / step) * step, b).statistic)


def slopes(error: np.ndarray, iop: np.ndarray, cct_um: np.ndarray, e0: np.ndarray) -> dict:
    """Least-squares slopes of ``error`` against true IOP, CCT and E0 jointly:
    error ~ a + b_IOP IOP + b_CCT CCT + b_E0 E0, reported per mmHg, per 100 um and per 0.1 MPa."""
    cols = [np.ones_like(iop)]
    names = []
    for name, v, unit in (("IOP", iop, 1.0), ("CCT", cct_um, 100.0), ("E0", e0, 0.1)):
        if np.ptp(v) > 0:
            cols.append(v / unit)
            names.append(name)
    coef, *_ = np.linalg.lstsq(np.stack(cols, axis=1), error, rcond=None)
    out = dict(zip(names, (float(c) for c in coef[1:])))
    return {"per_mmHg_IOP": out.get("IOP"), "per_100um_CCT": out.get("CCT"),
            "per_0.1MPa_E0": out.get("E0")}


def validation(fits: Mapping[str, FitResult], iop, cct_um, e0, raw, raw_name) -> dict:
    """The criteria of docs/correction.md: held-out error of the corrected IOP, its remaining
    slopes against CCT and E0 beside the raw reading's, and the stiffness index's Spearman
    correlation with the true E0 (held-out predictions throughout)."""
    iop_fit, e0_fit = fits["IOP"], fits["E0"]
    return {
        "corrected_IOP": {"held_out_rms_mmHg": iop_fit.rms,
                          "held_out_max_abs_mmHg": iop_fit.max_abs,
                          "slopes_of_error_mmHg": slopes(iop_fit.residual, iop, cct_um, e0)},
        "raw_reading": {"name": raw_name,
                        "rms_error_mmHg": float(np.sqrt(np.mean((raw - iop) ** 2))),
                        "slopes_of_error_mmHg": slopes(raw - iop, iop, cct_um, e0)},
        "stiffness_index": {"held_out_rms_MPa": e0_fit.rms,
                            "spearman_with_true_E0": spearman(e0_fit.held_out, e0)
                            if np.ptp(e0) > 0 else None},
    }


# -- applying a correction -------------------------------------------------------------------------

@dataclass
class Correction:
    """A correction file, read back: apply it with :meth:`apply_row`."""

    data: dict[str, Any]
    readings: list[dict[str, Any]]
    surfaces: dict[str, Surface]
    held_out_rms: dict[str, float]
    target_range: dict[str, tuple[float, float]]

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Correction":
        try:
            if d.get("format") != FORMAT:
                raise ValueError(f"format is {d.get('format')!r}, expected {FORMAT!r}")
            readings = [dict(r) for r in d["readings"]]
            for r in readings:
                r["range"] = (float(r["range"][0]), float(r["range"][1]))
            names = [r["name"] for r in readings]
            surfaces, rms, trange = {}, {}, {}
            for t, td in d["targets"].items():
                s = Surface.from_dict(td)
                if s.inputs != names:
                    raise ValueError(f"the {t} formula's inputs differ from the readings")
                surfaces[t] = s
                rms[t] = float(td["held_out"]["rms"])
                trange[t] = (float(td["range"][0]), float(td["range"][1]))
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise CorrectionError("correction", f"not an airpuff correction file: "
                                  f"{type(err).__name__}: {err}".replace("\n", " ")) from None
        return cls(dict(d), readings, surfaces, rms, trange)

    @classmethod
    def load(cls, path) -> "Correction":
        try:
            with open(path, encoding="utf-8") as f:
                d = json.load(f)
        except FileNotFoundError:
            raise CorrectionError("correction", f"correction file {str(path)!r} not found") from None
        except (OSError, ValueError) as err:
            raise CorrectionError("correction", f"cannot read correction file {str(path)!r}: "
                                                f"{type(err).__name__}") from None
        if not isinstance(d, dict):
            raise CorrectionError("correction", f"{path}: not an airpuff correction file")
        return cls.from_dict(d)

    def column_names(self, reading: Mapping[str, Any]) -> list[str]:
        return [reading["column"], *reading.get("aliases", [])]

    def apply_row(self, values: Mapping[str, Any], sigmas: Mapping[str, Any] | None = None
                  ) -> dict[str, Any]:
        """The corrected IOP and stiffness index of one measurement.

        ``values`` and ``sigmas`` are keyed by the readings' names or any accepted column name.
        Returns ``{"status": "ok" | "outside" | "error", "IOP", "IOP_sigma", "E0", "E0_sigma",
        "flags", "error"}``: ``outside`` when a reading lies outside its fitted range, or an
        estimate outside the sweep's range by more than twice its held-out RMS (the values are
        still given, flagged as extrapolated), ``error`` for a row that
        cannot be used (a missing or non-numeric value, a negative sigma)."""
        sigmas = sigmas or {}
        try:
            x, s = [], []
            for r in self.readings:
                x.append(_number(_lookup(values, self.column_names(r) + [r["name"]]), r, "value"))
                sv = _lookup(sigmas, self.column_names(r) + [r["name"]], required=False)
                s.append(0.0 if sv is None else _number(sv, r, "sigma"))
        except CorrectionError as err:
            return {"status": "error", "error": str(err)}
        x, s = np.array([x]), np.array(s)
        flags = []
        for k, r in enumerate(self.readings):
            lo, hi = r["range"]
            tol = RANGE_TOLERANCE * (hi - lo)  # the range's ends as read back (450 vs 0.45 * 1000)
            if not lo - tol <= x[0, k] <= hi + tol:
                flags.append(f"{r['column']}={x[0, k]:g} {r['unit']} is outside the fitted range "
                             f"{lo:.4g} to {hi:.4g} {r['unit']} (extrapolated)")
        out: dict[str, Any] = {}
        for t, surf in self.surfaces.items():
            y = float(surf(x)[0])
            g = surf.gradient(x)[0]
            out[t] = y
            out[f"{t}_sigma"] = float(math.sqrt(self.held_out_rms[t] ** 2 + np.sum((g * s) ** 2)))
            lo, hi = self.target_range[t]
            # an estimate within twice the formula's error of the sweep's range is no extrapolation
            tol = max(RANGE_TOLERANCE * (hi - lo), 2.0 * self.held_out_rms[t])
            if not lo - tol <= y <= hi + tol:
                flags.append(f"the estimate {t}={y:.4g} {TARGETS[t][0]} is outside the sweep's "
                             f"{lo:g} to {hi:g} {TARGETS[t][0]} (extrapolated)")
        return {"status": "outside" if flags else "ok", **out, "flags": flags}


def _lookup(values: Mapping[str, Any], names: Iterable[str], required: bool = True):
    lowered = {str(k).strip().lower(): v for k, v in values.items()}
    for n in names:
        v = lowered.get(n.lower())
        if v is not None and not (isinstance(v, str) and not v.strip()):
            return v
    if required:
        names = list(names)
        raise CorrectionError(names[0], f"{names[0]} is missing (accepted names: "
                                        + ", ".join(dict.fromkeys(names)) + ")")
    return None


def _number(v, reading: Mapping[str, Any], what: str) -> float:
    col, unit = reading["column"], reading["unit"]
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise CorrectionError(col, f"{col} {what} {v!r} is not a number [{unit}]") from None
    if not math.isfinite(f):
        raise CorrectionError(col, f"{col} {what} {v!r} is not a finite number [{unit}]")
    if what == "sigma" and f < 0:
        raise CorrectionError(col, f"{col} sigma {f:g} is negative: accepted a number >= 0 [{unit}]")
    if what == "value" and unit == "um" and 0 < f < 5:
        raise CorrectionError(col, f"{col}={f:g}: CCT is in micrometres (e.g. 540), not mm")
    return f


# Identifier columns copied to the output, if present.
ID_COLUMNS = ("id", "eye", "patient", "name")
SIGMA_SUFFIXES = ("_sigma", "_sd", "_err")


def sigma_columns(header: Sequence[str]) -> dict[str, str]:
    """{base column name (lower case): sigma column} for columns like ``P1_sigma``, ``sigma_P1``."""
    out = {}
    for h in header:
        hl = h.strip().lower()
        for suf in SIGMA_SUFFIXES:
            if hl.endswith(suf) and len(hl) > len(suf):
                out[hl[: -len(suf)]] = h
        if hl.startswith("sigma_") and len(hl) > 6:
            out[hl[6:]] = h
    return out


def read_measurements(text: str, correction: Correction) -> list[dict[str, Any]]:
    """The rows of a measurements CSV: ``[{"row": n, "id": ..., "values": {...}, "sigmas":
    {...}}]``.  Raises CorrectionError for a file without a column for some reading (no row
    could be used); a bad value only spoils its own row (see :meth:`Correction.apply_row`)."""
    reader = csv.DictReader(io.StringIO(text.lstrip("\ufeff")))
    header = [h for h in (reader.fieldnames or []) if h is not None]
    if not header:
        raise CorrectionError("measurements", "the measurements file is empty (expected a CSV "
                                              "with a header row)")
    lower = {h.strip().lower(): h for h in header}
    for r in correction.readings:
        names = correction.column_names(r)
        if not any(n.lower() in lower for n in names):
            raise CorrectionError(r["column"], f"the measurements have no column for "
                                               f"{r['column']} [{r['unit']}] (accepted names: "
                                               + ", ".join(names) + "; found: "
                                               + ", ".join(header) + ")")
    sig = sigma_columns(header)
    id_col = next((lower[c] for c in ID_COLUMNS if c in lower), None)
    rows = []
    for n, rec in enumerate(reader, start=2):  # row 1 is the header
        if not any((v or "").strip() for k, v in rec.items() if k is not None):
            continue
        values = {h: rec.get(h) for h in header}
        sigmas = {base: rec.get(col) for base, col in sig.items()}
        extra = rec.get(None)
        rows.append({"row": n, "id": rec.get(id_col) if id_col else None, "values": values,
                     "sigmas": sigmas,
                     "error": f"row {n} has {len(extra)} more field(s) than the header"
                     if extra else None})
    if not rows:
        raise CorrectionError("measurements", "the measurements file has a header but no rows")
    return rows


def apply_rows(correction: Correction, rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Apply the correction to every row; each row's result carries ``row`` and ``id``."""
    out = []
    for r in rows:
        if r.get("error"):
            res = {"status": "error", "error": r["error"]}
        else:
            res = correction.apply_row(r["values"], r.get("sigmas"))
        out.append({"row": r.get("row"), "id": r.get("id"), **res})
    return out


def accepted_columns(correction: Correction) -> str:
    return "; ".join(f"{r['column']} [{r['unit']}]" + (f" (or {', '.join(r['aliases'])})"
                                                        if r.get("aliases") else "")
                     for r in correction.readings)
