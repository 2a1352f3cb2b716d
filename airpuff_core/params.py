"""Run parameters of one air-puff simulation, in user units, with validation and SI conversion.

Every user-facing edge (CLI, HTTP API, netCDF) speaks the clinically customary units listed in
``PARAMETERS``; the solver works in SI.  ``RunParams`` holds user units; ``RunParams.si()`` returns
the SI values the solver uses.  Invalid values raise :class:`ParameterError`, whose message names
the parameter and its accepted range, so that the CLI can print it on one line (exit code 2) and the
HTTP API can return it as a 422.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

MMHG_PA = 133.322  # Pa per mmHg

RESOLUTIONS = ("coarse", "paper", "fine")
GEOMETRIES = ("sector", "cap")
LAYOUTS = ("isotropic", "polar")
C_RULES = ("running_max", "per_step", "fixed")
JET_START = ("as_written", "equilibrium")


class ParameterError(ValueError):
    """An invalid run parameter.  ``str(err)`` is one line naming the parameter and its range."""

    def __init__(self, name: str, value: Any, accepted: str):
        self.name = name
        self.value = value
        self.accepted = accepted
        super().__init__(f"invalid {name}={value!r}: accepted {accepted}")


@dataclass(frozen=True)
class ParamSpec:
    """Description of one numeric parameter: unit, default, accepted open/closed range."""

    name: str
    unit: str
    default: float
    low: float
    high: float
    low_inclusive: bool
    high_inclusive: bool
    description: str

    def accepted(self) -> str:
        lo = "[" if self.low_inclusive else "("
        hi = "]" if self.high_inclusive else ")"
        unit = f" {self.unit}" if self.unit not in ("", "1") else ""
        return f"a number in {lo}{self.low:g}, {self.high:g}{hi}{unit}"

    def check(self, value: Any) -> float:
        if isinstance(value, bool):
            raise ParameterError(self.name, value, self.accepted())
        try:
            x = float(value)
        except (TypeError, ValueError):
            raise ParameterError(self.name, value, self.accepted()) from None
        if not math.isfinite(x):
            raise ParameterError(self.name, value, self.accepted())
        ok_low = x >= self.low if self.low_inclusive else x > self.low
        ok_high = x <= self.high if self.high_inclusive else x < self.high
        if not (ok_low and ok_high):
            raise ParameterError(self.name, value, self.accepted())
        return x


def _p(name, unit, default, low, high, desc, low_inc=False, high_inc=True):
    return ParamSpec(name, unit, default, low, high, low_inc, high_inc, desc)


# name -> spec.  Ranges are what the model is meant for (clinical and numerical sanity), not what
# merely avoids a crash; they are documented in the API schema and in docs/model.md.
PARAMETERS: dict[str, ParamSpec] = {
    s.name: s
    for s in [
        _p("E0", "MPa", 0.5, 0.0, 50.0, "small-strain Young's modulus of the cornea"),
        _p("IOP", "mmHg", 16.0, 0.0, 80.0, "intraocular pressure p0 (reference fluid pressure)"),
        _p("thickness", "mm", 0.5, 0.0, 2.0, "corneal thickness h"),
        _p("pmax", "kPa", 10.0, 0.0, 50.0, "peak air-jet pressure", low_inc=True),
        _p("R", "mm", 7.0, 3.0, 15.0, "radius of the corneal arc"),
        _p("r_post", "mm", 2.04, 0.5, 10.0, "radius of the rigid posterior support (sector geometry)"),
        _p("alpha0", "degree", 60.0, 20.0, 80.0, "half-opening angle of the cornea", low_inc=True),
        _p("rho_cornea", "kg/m^3", 1000.0, 100.0, 5000.0, "density of the cornea"),
        _p("rho_fluid", "kg/m^3", 1000.0, 100.0, 5000.0, "reference density of the aqueous humour"),
        _p("mu", "Pa s", 7.5e-4, 0.0, 10.0, "viscosity of the aqueous humour", low_inc=True),
        _p("nu", "1", 0.5, -0.99, 0.99, "Poisson-type coupling of the membrane law", low_inc=True,
           high_inc=True),
        _p("fung_k", "1", 240.0, 0.0, 1000.0, "exponent of the Fung strain energy", low_inc=True),
        _p("a", "1", 21.5, 0.0, 1000.0, "spatial decay of the air jet, eq. (11)", low_inc=True),
        _p("b", "1", 25.0, 0.0, 1000.0, "temporal decay of the air jet, eq. (11)"),
        _p("T", "ms", 30.0, 0.0, 10000.0, "duration scale of the air jet, eq. (11)"),
        _p("t0", "ms", 15.0, 0.0, 10000.0, "time of the jet peak, eq. (11)", low_inc=True),
        _p("tait_gamma", "1", 7.0, 1.0, 20.0, "exponent of the equation of state (5)", low_inc=True),
        _p("c0", "m/s", 10.0, 0.0, 1500.0, "base artificial sound speed"),
        _p("c_slope", "1", 20.0, 0.0, 1000.0, "c = c0 + c_slope * v_max", low_inc=True),
        _p("coupling_tol", "1", 1e-4, 0.0, 0.1, "Dirichlet-Neumann tolerance, eq. (6)"),
        _p("t_end", "ms", 35.0, 0.0, 10000.0, "simulated time"),
        _p("hyperviscosity", "1", 0.25, 0.0, 10.0,
           "strength gamma of the stabilising hyperviscosity gamma c h^5 L^3 (0 switches it off)",
           low_inc=True),
        _p("output_interval", "ms", 0.05, 0.0, 10.0, "interval of the stored time histories"),
        _p("cfl", "1", 0.6, 0.0, 0.6,
           "acoustic CFL number: dt = cfl * h_min / (c + v_max) (stable to 0.72 at rest)"),
    ]
}

CHOICES: dict[str, tuple[str, ...]] = {
    "resolution": RESOLUTIONS,
    "geometry": GEOMETRIES,
    "layout": LAYOUTS,
    "c_rule": C_RULES,
    "jet_start": JET_START,
}
CHOICE_DEFAULTS = {
    "resolution": "coarse",
    "geometry": "sector",
    "layout": "isotropic",
    "c_rule": "running_max",
    "jet_start": "as_written",
}
CHOICE_DESCRIPTIONS = {
    "resolution": "node count: coarse (~300 fluid nodes), paper (~1100), fine (~4500)",
    "geometry": "chamber shape: sector (paper) or cap (flat rigid plane through the limbus)",
    "layout": "fluid node layout: isotropic rings or the paper's polar lattice",
    "c_rule": "sound-speed rule: running_max of v_max, per_step (paper), or fixed c = c0",
    "jet_start": "as_written (the 0.19 % jet at t=0 arrives as a step) or equilibrium under p_a(0)",
}

SWEPT = ("E0", "IOP", "thickness", "pmax")

# Integer solver controls (not physical parameters).
INT_PARAMETERS = {
    "max_coupling_iterations": (30, 2, 1000, "cap on Dirichlet-Neumann iterations per step"),
}


def _defaults() -> dict[str, Any]:
    d: dict[str, Any] = {k: s.default for k, s in PARAMETERS.items()}
    d.update(CHOICE_DEFAULTS)
    d.update({k: v[0] for k, v in INT_PARAMETERS.items()})
    return d


@dataclass(frozen=True)
class RunParams:
    """All parameters of one run, in user units (see ``PARAMETERS`` for units and ranges)."""

    E0: float = PARAMETERS["E0"].default
    IOP: float = PARAMETERS["IOP"].default
    thickness: float = PARAMETERS["thickness"].default
    pmax: float = PARAMETERS["pmax"].default
    R: float = PARAMETERS["R"].default
    r_post: float = PARAMETERS["r_post"].default
    alpha0: float = PARAMETERS["alpha0"].default
    rho_cornea: float = PARAMETERS["rho_cornea"].default
    rho_fluid: float = PARAMETERS["rho_fluid"].default
    mu: float = PARAMETERS["mu"].default
    nu: float = PARAMETERS["nu"].default
    fung_k: float = PARAMETERS["fung_k"].default
    a: float = PARAMETERS["a"].default
    b: float = PARAMETERS["b"].default
    T: float = PARAMETERS["T"].default
    t0: float = PARAMETERS["t0"].default
    tait_gamma: float = PARAMETERS["tait_gamma"].default
    c0: float = PARAMETERS["c0"].default
    c_slope: float = PARAMETERS["c_slope"].default
    coupling_tol: float = PARAMETERS["coupling_tol"].default
    t_end: float = PARAMETERS["t_end"].default
    hyperviscosity: float = PARAMETERS["hyperviscosity"].default
    output_interval: float = PARAMETERS["output_interval"].default
    cfl: float = PARAMETERS["cfl"].default
    resolution: str = CHOICE_DEFAULTS["resolution"]
    geometry: str = CHOICE_DEFAULTS["geometry"]
    layout: str = CHOICE_DEFAULTS["layout"]
    c_rule: str = CHOICE_DEFAULTS["c_rule"]
    jet_start: str = CHOICE_DEFAULTS["jet_start"]
    max_coupling_iterations: int = INT_PARAMETERS["max_coupling_iterations"][0]
    extra: dict = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self):
        self.validate()

    # -- construction -----------------------------------------------------------------------
    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> "RunParams":
        """Build from a mapping of user-unit values; unknown keys are an error."""
        names = {f.name for f in dataclasses.fields(cls)} - {"extra"}
        unknown = sorted(set(values) - names)
        if unknown:
            raise ParameterError(unknown[0], values[unknown[0]],
                                 "one of the known parameters: " + ", ".join(sorted(names)))
        return cls(**dict(values))

    def replace(self, **changes) -> "RunParams":
        return dataclasses.replace(self, **changes)

    # -- validation -------------------------------------------------------------------------
    def validate(self) -> None:
        for name, spec in PARAMETERS.items():
            object.__setattr__(self, name, spec.check(getattr(self, name)))
        for name, allowed in CHOICES.items():
            v = getattr(self, name)
            if v not in allowed:
                raise ParameterError(name, v, "one of " + ", ".join(allowed))
        for name, (_, lo, hi, _) in INT_PARAMETERS.items():
            v = getattr(self, name)
            try:
                iv = int(v)
            except (TypeError, ValueError):
                raise ParameterError(name, v, f"an integer in [{lo}, {hi}]") from None
            if isinstance(v, bool) or iv != v or not (lo <= iv <= hi):
                raise ParameterError(name, v, f"an integer in [{lo}, {hi}]")
            object.__setattr__(self, name, iv)
        if self.geometry == "sector" and not self.r_post < self.R:
            raise ParameterError("r_post", self.r_post, f"a number in (0.5, R={self.R:g}) mm")
        if self.t0 > self.t_end * 10:
            pass  # a jet that peaks after the end is allowed (pure rest runs); nothing to check

    # -- conversions ------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d.pop("extra")
        return d

    def si(self) -> dict[str, float]:
        """SI values used by the solver (m, s, kg, Pa, rad)."""
        return {
            "E0": self.E0 * 1e6,
            "p0": self.IOP * MMHG_PA,
            "h": self.thickness * 1e-3,
            "pmax": self.pmax * 1e3,
            "R": self.R * 1e-3,
            "r_post": self.r_post * 1e-3,
            "alpha0": math.radians(self.alpha0),
            "rho_c": self.rho_cornea,
            "rho_f": self.rho_fluid,
            "mu": self.mu,
            "nu": self.nu,
            "fung_k": self.fung_k,
            "a": self.a,
            "b": self.b,
            "T": self.T * 1e-3,
            "t0": self.t0 * 1e-3,
            "gamma": self.tait_gamma,
            "c0": self.c0,
            "c_slope": self.c_slope,
            "tol": self.coupling_tol,
            "t_end": self.t_end * 1e-3,
            "hyperviscosity": self.hyperviscosity,
            "output_interval": self.output_interval * 1e-3,
            "cfl": self.cfl,
        }


def units() -> dict[str, str]:
    """Unit of every numeric parameter, keyed by name."""
    return {k: s.unit for k, s in PARAMETERS.items()}


DEFAULTS = _defaults()
