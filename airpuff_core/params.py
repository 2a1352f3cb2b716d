"""Run parameters of one air-puff simulation, in user units, with validation and SI conversion.

Every user-facing edge (CLI, HTTP API, netCDF) speaks the clinically customary units listed in
``PARAMETERS``; the solver works in SI.  A numeric parameter is written once, as a ``ParamSpec``
in ``PARAMETERS`` (unit, default, range, description and its conversion to SI); the dataclasses
``RunParams`` (user units) and ``SIParams`` (SI) are generated from that table, and so are the
API's schema, the CLI's options and the form (``api/``).  ``RunParams`` is validated once, when
it is made (``RunParams.validate``); ``RunParams.si()`` gives the ``SIParams`` the solver uses,
built once per run.  Invalid values, alone or in combination (a cornea too soft to carry the
IOP, a layout the geometry does not have), raise :class:`ParameterError`, whose message names the
parameter and its accepted range, so that the CLI can print it on one line (exit code 2) and the
HTTP API can return it as a 422.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from .cornea.registry import CORNEA_CHOICES, CORNEA_OPTIONS, CORNEAS, model_name, resolve_options
from .errors import ParameterError

MMHG_PA = 133.322  # Pa per mmHg
UL_M3 = 1e-9  # m^3 per microlitre

# The time histories hold t_end / output_interval + 1 samples of every history; more than this
# many intervals cost minutes and gigabytes for one run (3e6 samples: 48 s, 0.5 GB).
MAX_HISTORY_INTERVALS = 100_000

# A number written as text (command line, form): optional sign, ASCII digits with an optional
# decimal point, optional exponent.  Stricter than float(), which also takes "1_0" (as 10),
# "1_000", "infinity", "nan" and digits of other scripts (the full-width "０.５").
DECIMAL = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?")


def parse_decimal(text: str) -> float:
    """The float written in ``text`` (surrounding white space allowed), in the plain decimal
    syntax of ``DECIMAL``; raises ValueError otherwise."""
    if not DECIMAL.fullmatch(text.strip()):
        raise ValueError(f"not a decimal number: {text!r}")
    return float(text)


def parse_whole(text: str) -> int:
    """The whole number written in ``text`` in ASCII digits (surrounding white space allowed);
    raises ValueError otherwise (``int`` would also take "1_0" and the full-width "１０")."""
    if not re.fullmatch(r"[+-]?[0-9]+", text.strip()):
        raise ValueError(f"not a whole number: {text!r}")
    return int(text)


# The prestretch lambda0 that balances the IOP is sought below this (docs/model.md section 3); a
# cornea that needs more is too soft for the membrane model.
PRESTRETCH_MAX = 10.0

# The stabilisations that make the clinical preset's results independent of the artificial
# sound speed (docs/model.md sections 4 and 11, docs/validation.md "The sound speed"): P1, P2
# within 0.2 mmHg, CH 0.3 mmHg, DA 0.01 mm from c0 = 10 to 40 m/s at IOP 10-25 mmHg.  The paper's
# model does not need them (its metrics do not move with c) and keeps its published numerics.
SOUND_SPEED_OPTIONS: dict[str, float] = {
    "hyperviscosity_speed": 15.0, "hyperviscosity_divergence": 0.5,
    "hyperviscosity_divergence_speed": 15.0,
    "hyperviscosity_density_speed": 10.0, "node_shifting": 1.0,
    "wall_drift_feedforward": 0.1, "wall_give_speed": 15.0,
}

# The choices each ``model`` preset makes; an option given explicitly overrides its preset.
MODEL_PRESETS: dict[str, dict[str, Any]] = {
    "paper": {"cornea": "membrane", "globe": "rigid", "ve_g": 0.0, "ve_tau": 10.0,
              "transverse_shear_modulus": 0.0, **{name: 0.0 for name in SOUND_SPEED_OPTIONS}},
    # the shell, the compliant globe and the viscoelasticity with tau = 10 ms of Kling et al.
    # (PLoS ONE 2014, e104904; docs/model.md sections 10 and 13); G_t and g fitted under the ORA
    # to the population's slope of Goldmann's IOP against CCT (+2.8 mmHg per 100 um) and its
    # mean CH (10.6 mmHg), inside their literature ranges (docs/validation.md, "The clinical
    # fit"; the fit's values 12.328 kPa and 0.5802, rounded)
    "clinical": {"cornea": "shell", "globe": "compliant", "ve_g": 0.580, "ve_tau": 10.0,
                 "transverse_shear_modulus": 12.33, **SOUND_SPEED_OPTIONS},
    # the clinical preset with the published values instead of the fitted ones: g 0.3 of Kling
    # et al. 2014 (table 3) and the transverse shear modulus measured on full-thickness human
    # stroma, 9.48 +- 2.92 kPa (Petsche et al., IOVS 53 (2012) 873)
    "clinical_published": {"cornea": "shell", "globe": "compliant", "ve_g": 0.3, "ve_tau": 10.0,
                           "transverse_shear_modulus": 9.48, **SOUND_SPEED_OPTIONS},
}
# the numeric parameters a preset sets: None (not given) until ``RunParams.validate``
PRESET_PARAMETERS = tuple(name for name in MODEL_PRESETS["clinical"]
                          if not isinstance(MODEL_PRESETS["clinical"][name], str))


@dataclass(frozen=True)
class SIConversion:
    """How a user-unit value becomes the SI value the solver uses: ``value * multiply /
    divide``, stored as the field ``name`` of :class:`SIParams` (the user name with its SI unit,
    e.g. ``E0_Pa``, when the user unit is not SI)."""

    name: str
    multiply: float = 1.0
    divide: float = 1.0

    def __call__(self, value: float) -> float:
        return value * self.multiply / self.divide


@dataclass(frozen=True)
class ParamSpec:
    """Description of one numeric parameter: unit, default, accepted open/closed range, and its
    conversion to SI (the field of ``SIParams`` it becomes)."""

    name: str
    unit: str
    default: float
    low: float
    high: float
    low_inclusive: bool
    high_inclusive: bool
    description: str
    to_si: SIConversion = None

    def accepted(self) -> str:
        lo = "[" if self.low_inclusive else "("
        hi = "]" if self.high_inclusive else ")"
        unit = f" {self.unit}" if self.unit not in ("", "1") else ""
        return f"a number in {lo}{self.low:g}, {self.high:g}{hi}{unit}"

    def check(self, value: Any) -> float:
        if isinstance(value, bool):
            raise ParameterError(self.name, value, self.accepted())
        try:
            x = parse_decimal(value) if isinstance(value, str) else float(value)
        except (TypeError, ValueError):
            raise ParameterError(self.name, value, self.accepted()) from None
        if not math.isfinite(x):
            raise ParameterError(self.name, value, self.accepted())
        ok_low = x >= self.low if self.low_inclusive else x > self.low
        ok_high = x <= self.high if self.high_inclusive else x < self.high
        if not (ok_low and ok_high):
            raise ParameterError(self.name, value, self.accepted())
        return x


def _p(name, unit, default, low, high, desc, low_inc=False, high_inc=True, si=None):
    """A ParamSpec; ``si``: (SI name, factor) or (SI name, 1, divisor) when the unit is not SI."""
    to_si = SIConversion(name) if si is None else SIConversion(*si)
    return ParamSpec(name, unit, default, low, high, low_inc, high_inc, desc, to_si)


# The ORA's pulse (docs/model.md section 6): no published rise rate or switch-off delay was
# found; both are calibrated on the ORA's applanation times (TimeIn, TimeOut of real records)
# at the normal eye.
ORA_RISE_RATE = 0.590  # kPa/ms
ORA_DELAY = 4.85  # ms
ORA_ONSET = 3.5  # ms

# name -> spec.  Ranges are what the model is meant for (clinical and numerical sanity), not what
# merely avoids a crash; they are documented in the API schema and in docs/model.md.
PARAMETERS: dict[str, ParamSpec] = {
    s.name: s
    for s in [
        _p("E0", "MPa", 0.5, 0.0, 50.0, "small-strain Young's modulus of the cornea",
           si=("E0_Pa", 1e6)),
        _p("IOP", "mmHg", 16.0, 0.0, 80.0, "intraocular pressure p0 (reference fluid pressure)",
           si=("p0_Pa", MMHG_PA)),
        _p("thickness", "mm", 0.5, 0.0, 2.0, "corneal thickness h", si=("thickness_m", 1e-3)),
        _p("pmax", "kPa", 10.0, 0.0, 50.0, "peak air-jet pressure, eq. (11) (instrument=paper)",
           low_inc=True, si=("pmax_Pa", 1e3)),
        _p("R", "mm", 7.0, 3.0, 15.0, "radius of the corneal arc", si=("R_m", 1e-3)),
        _p("r_post", "mm", 2.04, 0.5, 10.0, "radius of the rigid posterior support (sector geometry)",
           si=("r_post_m", 1e-3)),
        _p("alpha0", "degree", 60.0, 20.0, 80.0, "half-opening angle of the cornea", low_inc=True,
           si=("alpha0_rad", math.pi / 180.0)),
        _p("rho_cornea", "kg/m^3", 1000.0, 100.0, 5000.0, "density of the cornea"),
        _p("rho_fluid", "kg/m^3", 1000.0, 100.0, 5000.0, "reference density of the aqueous humour"),
        _p("mu", "Pa s", 7.5e-4, 0.0, 10.0, "viscosity of the aqueous humour", low_inc=True),
        _p("nu", "1", 0.5, -0.99, 0.99, "Poisson-type coupling of the membrane law", low_inc=True,
           high_inc=True),
        _p("fung_k", "1", 240.0, 0.0, 1000.0, "exponent of the Fung strain energy", low_inc=True),
        _p("a", "1", 21.5, 0.0, 1000.0,
           "spatial decay of the air pulse exp(-a sin^2 phi), eq. (11) (every instrument)",
           low_inc=True),
        _p("b", "1", 25.0, 0.0, 1000.0, "temporal decay of the air jet, eq. (11) (instrument=paper)"),
        _p("T", "ms", 30.0, 0.0, 10000.0, "duration scale of the air jet, eq. (11) "
           "(instrument=paper)", si=("T_s", 1e-3)),
        _p("t0", "ms", 15.0, 0.0, 10000.0, "time of the jet peak, eq. (11) (instrument=paper)",
           low_inc=True, si=("t0_s", 1e-3)),
        _p("ora_rise_rate", "kPa/ms", ORA_RISE_RATE, 0.0, 10.0,
           "rise rate of the ORA's pulse on the apex while its pump runs (instrument=ora; "
           "calibrated: the first applanation at 8.29 ms at the normal eye, docs/model.md "
           "section 6)", si=("ora_rise_rate_Pa_per_s", 1e6)),
        _p("ora_delay", "ms", ORA_DELAY, 0.0, 20.0,
           "delay of the ORA's pump switch-off after the first applanation it detects "
           "(instrument=ora; calibrated: the second applanation at 18.87 ms at the normal eye, "
           "docs/model.md section 6)", low_inc=True, si=("ora_delay_s", 1e-3)),
        _p("ora_onset", "ms", ORA_ONSET, 0.0, 20.0,
           "time over which the ORA's pump rate rises from 0 to ora_rise_rate (instrument=ora; "
           "a choice: the period of the cornea's lowest oscillation at the reference eye, "
           "docs/model.md section 6)", low_inc=True, si=("ora_onset_s", 1e-3)),
        _p("ora_fall_rate", "kPa/ms", ORA_RISE_RATE, 0.0, 10.0,
           "fall rate of the ORA's pulse on the apex after the switch-off (instrument=ora; "
           "the rise rate: a symmetric pulse, a choice)", si=("ora_fall_rate_Pa_per_s", 1e6)),
        _p("tait_gamma", "1", 7.0, 1.0, 20.0, "exponent of the equation of state (5)", low_inc=True),
        _p("c0", "m/s", 10.0, 0.0, 1500.0, "base artificial sound speed"),
        _p("c_slope", "1", 20.0, 0.0, 1000.0, "c = c0 + c_slope * v_max", low_inc=True),
        _p("coupling_tol", "1", 1e-4, 0.0, 0.1, "Dirichlet-Neumann tolerance, eq. (6)"),
        _p("t_end", "ms", 35.0, 0.0, 10000.0, "simulated time", si=("t_end_s", 1e-3)),
        _p("hyperviscosity", "1", 0.15, 0.0, 10.0,
           "strength gamma of the stabilising hyperviscosity gamma c h^5 H (0 switches it off; "
           "H from hyperviscosity_operator). Smallest stable strength at coarse / paper "
           "resolution: consistent_velocity 0.041-0.053 / 0.05-0.075, brookshaw 0.025-0.05 / "
           "0.05-0.075 (jet runs), consistent 0.094-0.103 / 0.0625-0.075 (docs/model.md "
           "section 4)",
           low_inc=True),
        _p("hyperviscosity_speed", "m/s", 0.0, 0.0, 1500.0,
           "speed c_v in the strength gamma c_v h^5 of the hyperviscosity on the velocity, in "
           "place of the sound speed c (0: c; docs/model.md section 4); set by the model preset "
           "(paper 0, clinical 15)", low_inc=True),
        _p("hyperviscosity_density_speed", "m/s", 0.0, 0.0, 1500.0,
           "speed c_rho in the strength gamma c^2/c_rho h^5 of the hyperviscosity on the "
           "density, in place of gamma c h^5: growing with c^2, it holds the pressure of the "
           "grid-scale density it balances independent of c (0: gamma c h^5; docs/model.md "
           "section 4); set by the model preset (paper 0, clinical 10)", low_inc=True),
        _p("hyperviscosity_divergence", "1", 0.0, 0.0, 10.0,
           "strength gamma_div of the damping of the velocity's divergence, a bulk viscosity "
           "gamma_div c_d h (0 switches it off; docs/model.md section 4); set by the "
           "model preset (paper 0, clinical 0.5)", low_inc=True),
        _p("hyperviscosity_divergence_speed", "m/s", 0.0, 0.0, 1500.0,
           "speed c_d in the divergence damping's bulk viscosity gamma_div c_d h, in place of "
           "the sound speed c: the smooth flow's discrete divergence has a part that does not "
           "fall with c, on which a bulk viscosity growing with c would act (0: c; docs/model.md "
           "section 4); set by the model preset (paper 0, clinical 15)", low_inc=True),
        _p("node_shifting", "1", 0.0, 0.0, 100.0,
           "strength A of the shifting of the fluid nodes towards a regular cloud, each step by "
           "-A h (v_max dt) (grad C - grad C0), C the nodes' kernel-sum concentration (0: off; "
           "docs/model.md section 4); set by the model preset (paper 0, clinical 1)",
           low_inc=True),
        _p("wall_drift_feedforward", "ms", 0.0, 0.0, 10.0,
           "filter time of the compliant walls' feed-forward of the fluid's volume drift rate, "
           "which removes the make-up's lag and its mean pressure error growing with c^2 (0: "
           "off; docs/model.md section 11); set by the model preset (paper 0, clinical 0.1)",
           low_inc=True,
           si=("wall_drift_feedforward_s", 1e-3)),
        _p("wall_give_speed", "m/s", 0.0, 0.0, 1500.0,
           "speed c_g that sets the return time of the compliant walls' transmitted give, "
           "tau = 0.1 ms c_g / c (a fixed acoustic length c_g 0.1 ms): the give under the slow "
           "flow's wall pressure then offsets the fluid's mean pressure by an amount that does "
           "not grow with c (0: tau = 0.1 ms; docs/model.md section 11); set by the model "
           "preset (paper 0, clinical 15)", low_inc=True),
        _p("output_interval", "ms", 0.05, 0.0, 10.0, "interval of the stored time histories",
           si=("output_interval_s", 1e-3)),
        _p("cfl", "1", 0.6, 0.0, 0.6,
           "acoustic CFL number: dt = cfl * h_min / (c + v_max) (stable to 0.72 at rest)"),
        _p("ve_g", "1", 0.0, 0.0, 0.95,
           "relative modulus g of the one-term Prony series of the cornea's viscoelasticity, "
           "G(t) = 1 - g (1 - exp(-t/ve_tau)), E0 the relaxed modulus; 0 is elastic; set by the "
           "model preset (paper 0, clinical 0.3: Kling et al. 2014)", low_inc=True),
        _p("ve_tau", "ms", 10.0, 0.0, 1000.0,
           "relaxation time of the cornea's viscoelasticity; set by the model preset (10: Kling "
           "et al. 2014)", si=("ve_tau_s", 1e-3)),
        _p("transverse_shear_modulus", "kPa", 0.0, 0.0, 1.0e5,
           "transverse (out-of-plane) shear modulus G_t of the shear-deformable shell (cornea="
           "mindlin, shear stiffness 5/6 G_t h; above 0 there, 0 with the other corneas; "
           "cornea=shell picks mindlin for G_t > 0, kirchhoff for 0); set by the model preset "
           "(paper 0, clinical 9.48: human stroma, Petsche et al. 2012)", low_inc=True,
           si=("transverse_shear_modulus_Pa", 1e3)),
        _p("ocular_rigidity", "1/uL", 0.0126, 0.0, 0.1,
           "Friedenwald's ocular rigidity K of the compliant globe, dP/dV = ln(10) K P "
           "(globe=compliant; in-vivo mean 0.0126, Pallikaris et al. 2005)",
           si=("ocular_rigidity_per_m3", 1.0, UL_M3)),
        _p("eye_mass", "g", 7.5, 0.0, 100.0,
           "mass of the globe moving with eye_motion=spring_damper (adult human eye about 7.5 g, "
           "docs/model.md section 14)", si=("eye_mass_kg", 1e-3)),
        _p("eye_spring", "N/m", 350.0, 0.0, 1.0e5,
           "axial spring of the orbit behind the globe (eye_motion=spring_damper; 350: Kling et "
           "al. 2014, table 3)", low_inc=True),
        _p("eye_damper", "N s/m", 100.0, 0.0, 1.0e5,
           "axial damper of the orbit behind the globe (eye_motion=spring_damper; 100 kg/s: Kling "
           "et al. 2014, table 3)", low_inc=True),
    ]
}

CHOICES: dict[str, tuple[str, ...]] = {
    "resolution": ("coarse", "paper", "fine"),
    "geometry": ("sector", "cap"),
    "layout": ("isotropic", "polar"),
    "c_rule": ("running_max", "per_step", "fixed"),
    "jet_start": ("as_written", "equilibrium"),
    "globe": ("rigid", "compliant"),
    "hyperviscosity_operator": ("brookshaw", "consistent", "consistent_velocity"),
    "model": tuple(MODEL_PRESETS),
    "cornea": CORNEA_CHOICES,
    "limbus": ("clamped", "pinned"),
    "instrument": ("paper", "ora", "corvis"),
    "eye_motion": ("none", "spring_damper"),
}
# the numeric parameters only one instrument's pulse reads (``a`` is read by all); another
# instrument refuses them away from their defaults
INSTRUMENT_PARAMETERS = {
    "paper": ("pmax", "b", "T", "t0"),
    "ora": ("ora_rise_rate", "ora_delay", "ora_onset", "ora_fall_rate"),
    "corvis": (),
}
# None: taken from the ``model`` preset (MODEL_PRESETS) unless given
CHOICE_DEFAULTS = {
    "resolution": "coarse",
    "geometry": "sector",
    "layout": "isotropic",
    "c_rule": "running_max",
    "jet_start": "as_written",
    "globe": None,
    "hyperviscosity_operator": "consistent_velocity",
    "model": "paper",
    "cornea": None,
    "limbus": "clamped",
    "instrument": "paper",
    "eye_motion": "none",
}
CHOICE_DESCRIPTIONS = {
    "resolution": "node count: coarse (~300 fluid nodes), paper (~1100), fine (~4500)",
    "geometry": "chamber shape: sector (paper) or cap (flat rigid plane through the limbus)",
    "layout": "fluid node layout: isotropic rings or the paper's polar lattice",
    "c_rule": "sound-speed rule: running_max of v_max, per_step (paper), or fixed c = c0",
    "jet_start": "as_written (the 0.19 % jet at t=0 arrives as a step) or equilibrium under p_a(0)",
    "globe": "rigid chamber walls (paper) or compliant: the walls recede with Friedenwald's "
             "pressure-volume law (ocular_rigidity)",
    "hyperviscosity_operator": "operator H of the hyperviscosity: consistent_velocity (K* L K "
                               "on velocity, zero on linear fields at walls and cornea too; L^3 "
                               "on density), brookshaw (L^3 on both: first order in h at walls "
                               "and cornea) or consistent (K* L K on density and velocity)",
    "model": "preset: paper (membrane cornea, rigid globe, elastic), clinical (shear-deformable "
             "shell cornea, G_t 12.33 kPa; compliant globe; viscoelastic: ve_g 0.580, ve_tau "
             "10 ms; G_t and ve_g fitted to the population's CCT slope and mean CH) or "
             "clinical_published (the same with the published G_t 9.48 kPa and ve_g 0.3); "
             "explicit options override it",
    "cornea": "; ".join(f"{e.name}: {e.description}" for e in CORNEAS.values())
              + "; shell (the older spelling): mindlin with transverse_shear_modulus > 0, "
                "kirchhoff with 0 (the clinical preset's shell)",
    "limbus": "support of the shell at the limbus (cornea kirchhoff or mindlin): clamped (rotation "
              "fixed) or pinned (free to rotate)",
    "instrument": "the air pulse: paper (the paper's jet, eq. (11): pmax, b, T, t0), ora (the "
                  "Ocular Response Analyzer's: rising at ora_rise_rate, reached over ora_onset, "
                  "switched off ora_delay after the first applanation it detects, falling at "
                  "ora_fall_rate) or corvis "
                  "(the Corvis ST's measured profile, peak 12.6 kPa at 18 ms); every one with "
                  "the spatial decay a",
    "eye_motion": "whole-eye motion: none (the eye stays put, the paper's) or spring_damper (the "
                  "globe a rigid body of eye_mass on the orbit's eye_spring and eye_damper, pushed "
                  "back by the air pulse; DA then includes its movement)",
}



def choice_default_text(name: str) -> str:
    """The default of choice ``name`` in words: its value, or, for an option the ``model``
    preset sets, what each preset gives (e.g. 'from model: membrane (paper), shell (clinical)')."""
    if CHOICE_DEFAULTS[name] is not None:
        return str(CHOICE_DEFAULTS[name])
    return "from model: " + ", ".join(f"{preset[name]} ({m})" for m, preset in MODEL_PRESETS.items()
                                      if name in preset)


SWEPT = ("E0", "IOP", "thickness", "pmax")

# Integer solver controls (not physical parameters).
INT_PARAMETERS = {
    "max_coupling_iterations": (30, 2, 1000, "cap on Dirichlet-Neumann iterations per step"),
    "hyperviscosity_interval": (1, 1, 16, "fluid steps per application of the hyperviscosity, "
                                "each integrating it over the time since the last (1: every "
                                "step). 2 moves P2 and CH by up to 0.03 mmHg with the "
                                "hyperviscosity gamma c h^5 alone, by 0.1-0.27 mmHg with "
                                "hyperviscosity_speed, _divergence or _density_speed (docs/"
                                "model.md section 4)"),
    "node_shifting_interval": (8, 1, 16, "fluid steps per node shift (node_shifting), each "
                               "shifting by the steps' time together (1: every step; docs/"
                               "model.md section 4)"),
}


def softest_E0(IOP, thickness, R, nu, fung_k):
    """The smallest E0 [MPa] whose membrane carries the IOP [mmHg] on an arc of radius R [mm]
    with a prestretch of at most PRESTRETCH_MAX (thickness in mm).

    The equibiaxial tension of the Fung law (docs/model.md section 3) at lambda0 is
    N = E0 h / (1 - nu^2) exp(Q) (1 + nu) E,  E = (lambda0^2 - 1) / 2,  Q = 2 k (1 + nu) E^2,
    and Laplace's law asks N = p0 R / 2.  N is linear in E0.  Everything is taken in logarithms:
    exp(Q) overflows for the default k at lambda0 = 10, and a product of tiny accepted values
    (a thickness of 1e-320 mm) underflows.  Returns inf when no finite E0 will do.
    """
    E = 0.5 * (PRESTRETCH_MAX ** 2 - 1.0)
    log_N_per_E0_Pa = (math.log(thickness) + math.log(1e-3) - math.log(1.0 - nu * nu)
                       + math.log(1.0 + nu) + math.log(E) + 2.0 * fung_k * (1.0 + nu) * E * E)
    log_target = math.log(0.5 * MMHG_PA * 1e-3) + math.log(IOP) + math.log(R)
    log_E0_MPa = log_target - log_N_per_E0_Pa + math.log(1e-6)
    return math.exp(log_E0_MPa) if log_E0_MPa < 700.0 else math.inf


# The numeric run parameters in SI units (m, s, kg, Pa, rad), as the solver uses them: one float
# field per entry of ``PARAMETERS``, named by its ``to_si`` (``E0_Pa``, where ``RunParams.E0`` is
# in MPa; a parameter in SI keeps its name).  Made by ``RunParams.si()`` once per run.
SIParams = dataclasses.make_dataclass(
    "SIParams", [(spec.to_si.name, float) for spec in PARAMETERS.values()], frozen=True,
    namespace={"__module__": __name__,
               "__doc__": "The numeric run parameters in SI units (``PARAMETERS``' to_si)."})


class _RunParamsMethods:
    """Construction, validation and conversion of ``RunParams`` (its fields come from the
    tables ``PARAMETERS``, ``CHOICES`` and ``INT_PARAMETERS``)."""

    def __post_init__(self):
        self.validate()

    # -- construction -----------------------------------------------------------------------
    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> "RunParams":
        """Build from a mapping of user-unit values; unknown keys are an error."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - names)
        if unknown:
            raise ParameterError(unknown[0], values[unknown[0]],
                                 "one of the known parameters: " + ", ".join(sorted(names)))
        return cls(**dict(values))

    def replace(self, **changes) -> "RunParams":
        """A copy with ``changes``; a new ``model`` re-derives the options of its preset that
        ``changes`` does not set."""
        if "model" in changes:
            for name in MODEL_PRESETS.get(changes["model"], {}):
                changes.setdefault(name, None)
        elif "cornea" in changes:
            # an option at its preset's value goes back to the preset, which drops it for a
            # cornea that does not use it
            preset = MODEL_PRESETS[self.model]
            for name in CORNEA_OPTIONS:
                if name in preset and getattr(self, name) == preset[name]:
                    changes.setdefault(name, None)
        return dataclasses.replace(self, **changes)

    # -- validation -------------------------------------------------------------------------
    def validate(self) -> None:
        if self.model not in MODEL_PRESETS:  # before the preset fills its options
            raise ParameterError("model", self.model, "one of " + ", ".join(MODEL_PRESETS))
        from_preset = set()
        for name, value in MODEL_PRESETS[self.model].items():
            if getattr(self, name) is None:
                object.__setattr__(self, name, value)
                from_preset.add(name)
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
        self._resolve_cornea(from_preset)
        self._check_combinations()

    def _resolve_cornea(self, from_preset) -> None:
        """``cornea`` by its registry name (``shell`` mapped by the transverse shear modulus) and
        the cornea-specific options it does not use refused or, from a preset, dropped
        (``cornea.registry.resolve_options``)."""
        cornea = model_name(self.cornea, self.transverse_shear_modulus)
        object.__setattr__(self, "cornea", cornea)
        options = resolve_options(
            cornea, {name: getattr(self, name) for name in CORNEA_OPTIONS}, from_preset,
            # the range of a numeric option for the models that use it: above its neutral 0
            {name: dataclasses.replace(PARAMETERS[name], low_inclusive=False).accepted()
             for name in CORNEA_OPTIONS if name in PARAMETERS})
        for name, value in options.items():
            object.__setattr__(self, name, value)

    def _check_combinations(self) -> None:
        """Values each in range that do not go together (docs/model.md section 1)."""
        if self.geometry == "sector" and not self.r_post < self.R:
            raise ParameterError("r_post", self.r_post, f"a number in (0.5, R={self.R:g}) mm")
        for instrument, names in INSTRUMENT_PARAMETERS.items():
            if instrument == self.instrument:
                continue
            for name in names:
                spec = PARAMETERS[name]
                if getattr(self, name) != spec.default:
                    raise ParameterError(
                        name, getattr(self, name),
                        f"its default {spec.default:g}{' ' + spec.unit if spec.unit != '1' else ''}"
                        f" with instrument={self.instrument} (only instrument={instrument} "
                        f"reads it)")
        if self.layout == "polar" and self.geometry != "sector":
            raise ParameterError("layout", self.layout,
                                 "isotropic with geometry cap (the polar lattice is a sector's)")
        if self.t_end / self.output_interval > MAX_HISTORY_INTERVALS:
            raise ParameterError(
                "output_interval", self.output_interval,
                f"{PARAMETERS['output_interval'].accepted()} with t_end / output_interval at most "
                f"{MAX_HISTORY_INTERVALS} samples of the histories (t_end={self.t_end:g} ms gives "
                f"{self.t_end / self.output_interval:.3g}; raise output_interval or lower t_end)")
        if not self.E0 * 1e6 * self.thickness * 1e-3 > 0.0:
            # the membrane stiffness E0 h [N/m] of the solver would underflow to 0
            raise ParameterError("thickness", self.thickness,
                                 f"a number in (0, 2] mm with E0 h > 0 in double precision "
                                 f"(E0={self.E0:g} MPa)")
        E0_min = softest_E0(self.IOP, self.thickness, self.R, self.nu, self.fung_k)
        if self.E0 < E0_min:
            spec = PARAMETERS["E0"]
            others = (f"IOP={self.IOP:g} mmHg, thickness={self.thickness:g} mm, R={self.R:g} mm, "
                      f"nu={self.nu:g}, fung_k={self.fung_k:g}")
            if E0_min > spec.high:
                accepted = (f"none in (0, {spec.high:g}] MPa with {others}: the membrane cannot "
                            f"carry the IOP with a prestretch up to {PRESTRETCH_MAX:g} (raise "
                            f"thickness or fung_k)")
            else:
                accepted = (f"a number of at least {E0_min:.3g} MPa with {others} (a softer cornea "
                            f"needs a prestretch above {PRESTRETCH_MAX:g} to carry the IOP)")
            raise ParameterError("E0", self.E0, accepted)

    # -- conversions ------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def si(self) -> SIParams:
        """The numeric parameters in SI units (call once per run)."""
        return SIParams(**{spec.to_si.name: spec.to_si(getattr(self, name))
                           for name, spec in PARAMETERS.items()})


def _run_fields() -> list[tuple]:
    """The fields of ``RunParams``: the numeric parameters (None for those the preset sets),
    the choices, the integer controls, in this order (that of ``to_dict``)."""
    fields = [(name, float | None if name in PRESET_PARAMETERS else float,
               dataclasses.field(default=None if name in PRESET_PARAMETERS else spec.default))
              for name, spec in PARAMETERS.items()]
    fields += [(name, str | None if CHOICE_DEFAULTS[name] is None else str,
                dataclasses.field(default=CHOICE_DEFAULTS[name])) for name in CHOICES]
    fields += [(name, int, dataclasses.field(default=spec[0]))
               for name, spec in INT_PARAMETERS.items()]
    return fields


RunParams = dataclasses.make_dataclass(
    "RunParams", _run_fields(), bases=(_RunParamsMethods,), frozen=True,
    namespace={"__module__": __name__,
               "__doc__": "All parameters of one run, in user units (see ``PARAMETERS`` for "
                          "units and ranges; ``CHOICES``, ``INT_PARAMETERS``)."})
