"""The parameter grid of a sweep: four axes (E0, IOP, thickness, pmax) and the common run options.

Everything here is in the user units of ``airpuff run`` (MPa, mmHg, mm, kPa; see
``airpuff_core.params.PARAMETERS``).  This module only describes *which* runs a sweep consists of;
running them is ``sweep.runner``'s job and storing them ``sweep.storage``'s.

Interface the HTTP API uses -- keep these names:

* ``parse_axis(name, text) -> list[float]``
* ``SweepSpec(E0=[...], IOP=[...], thickness=[...], pmax=[...], options={...})`` with
  ``points()``, ``n_points``, ``shape``, ``validate()``, ``run_options()``, ``to_dict()``,
  ``SweepSpec.from_dict(d)``.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from airpuff_core.budget import check_step_budget
from airpuff_core.params import (PARAMETERS, SWEPT, ParameterError, RunParams, parse_decimal,
                                 parse_whole)

# Grid values are rounded to this many significant digits, so that "0.1:0.3:3" gives exactly
# [0.1, 0.2, 0.3] and not 0.30000000000000004: the values end up in netCDF coordinates, in
# point keys (a resume must find the same keys) and in users' .sel() calls.
SIGNIFICANT_DIGITS = 12

GRID_FIELD = "E0 x IOP x thickness x pmax"  # the field named when the grid as a whole is too large

AXIS_SYNTAX = "a comma list of numbers (e.g. 0.3,0.5,0.7) or start:stop:num (e.g. 10:30:5)"


def _round(x: float) -> float:
    return float(f"{x:.{SIGNIFICANT_DIGITS}g}")


def _number(name: str, token: str, whole: str) -> float:
    try:
        x = parse_decimal(token)
    except ValueError:
        raise ParameterError(name, whole, AXIS_SYNTAX) from None
    if not math.isfinite(x):
        raise ParameterError(name, whole, AXIS_SYNTAX)
    return x


def _axis_parts(name: str, text: str) -> tuple[list[str], int | None]:
    """The written parts of an axis in the syntax of :func:`parse_axis`: ``([start, stop], num)``
    for ``start:stop:num``, ``(items, None)`` for a comma list (texts stripped, not yet numbers).
    Raises ParameterError on a malformed ``start:stop:num`` or ``num``."""
    text = str(text).strip()
    if ":" in text:
        parts = [part.strip() for part in text.split(":")]
        if len(parts) != 3:
            raise ParameterError(name, text, AXIS_SYNTAX)
        try:
            return parts[:2], parse_whole(parts[2])
        except ValueError:
            raise ParameterError(name, text, "start:stop:num with num a whole number >= 1") from None
    return [t.strip() for t in text.split(",")], None


def axis_length(name: str, text: str) -> int:
    """The number of values of an axis in the syntax of :func:`parse_axis`, without making them
    (``10:30:100000000`` answers at once).  Raises ParameterError on a malformed ``num``; the
    values themselves are checked by :func:`parse_axis`."""
    items, num = _axis_parts(name, text)
    return len(items) if num is None else num


def check_grid_size(lengths: dict[str, int], max_points: int, hint: str = "") -> int:
    """The number of points of a grid whose axes have ``lengths`` (swept name -> number of
    values); raises ParameterError naming the four axes if it is above ``max_points`` (``hint``
    says how to raise the limit)."""
    n = 1
    for name in SWEPT:
        n *= max(1, int(lengths.get(name, 1)))
    if n > max_points:
        shape = " x ".join(str(lengths.get(name, 1)) for name in SWEPT)
        raise ParameterError(GRID_FIELD, f"{shape} = {n} points",
                             f"at most {max_points} points{hint}")
    return n


def parse_axis(name: str, text: str) -> list[float]:
    """Values of one swept parameter from the command-line syntax, in the parameter's user unit.

    ``text`` is either a comma list (``"0.3,0.5,0.7"``) or ``start:stop:num`` (``"10:30:5"`` gives
    10, 15, 20, 25, 30: both ends included, ``num`` >= 1, and ``num`` = 1 needs start = stop).
    Each value is range-checked against ``PARAMETERS[name]``.  Raises :class:`ParameterError`
    (one-line message naming ``name`` and the accepted syntax or range) on any bad input,
    including an empty list and duplicate values.
    """
    values = axis_values(name, text)
    spec = PARAMETERS[name]
    values = [spec.check(v) for v in values]
    _check_unique(name, values)
    return values


def axis_values(name: str, text: str, max_num: int | None = None) -> list[float]:
    """The numbers written in ``text`` (syntax of :func:`parse_axis`), not yet range-checked:
    the web form (``api.sweep_form``) leaves ranges and duplicates to the request schema, so that
    its messages are those of ``POST /sweeps``.  ``max_num`` caps ``num`` of start:stop:num before
    any array is made.  Raises :class:`ParameterError` on bad syntax."""
    if name not in SWEPT:
        raise ParameterError("axis", name, "one of " + ", ".join(SWEPT))
    text = str(text).strip()
    if not text:
        raise ParameterError(name, text, AXIS_SYNTAX)
    items, num = _axis_parts(name, text)
    if num is not None:
        start, stop = (_number(name, item, text) for item in items)
        if num < 1 or (num == 1 and start != stop):
            raise ParameterError(name, text, "start:stop:num with num >= 2 (num = 1 only if start = stop)")
        if max_num is not None and num > max_num:
            raise ParameterError(name, text, f"start:stop:num with num at most {max_num}")
        return [_round(v) for v in np.linspace(start, stop, num)]
    if any(t == "" for t in items):
        raise ParameterError(name, text, AXIS_SYNTAX)
    return [_round(_number(name, t, text)) for t in items]


def _check_unique(name: str, values: list[float]) -> None:
    if len(set(values)) != len(values):
        dup = sorted(v for v, n in Counter(values).items() if n > 1)
        raise ParameterError(name, dup[0] if len(dup) == 1 else dup, "distinct values (no duplicates)")


def _default_axis(name: str):
    return lambda: [PARAMETERS[name].default]


@dataclass
class SweepSpec:
    """A full-factorial grid over the four swept parameters plus the options common to all runs.

    Fields (all user units, as in ``airpuff run``):

    * ``E0`` [MPa], ``IOP`` [mmHg], ``thickness`` [mm], ``pmax`` [kPa]: lists of floats; each
      defaults to the single default value of that parameter.
    * ``options``: every other ``RunParams`` field that differs from its default, e.g.
      ``{"resolution": "coarse", "t_end": 35.0}``.  Swept names are not allowed here.

    ``points()`` lists the runs in C order over (E0, IOP, thickness, pmax): the last axis varies
    fastest, matching the layout of the combined ``sweep.nc``.
    """

    E0: list = field(default_factory=_default_axis("E0"))
    IOP: list = field(default_factory=_default_axis("IOP"))
    thickness: list = field(default_factory=_default_axis("thickness"))
    pmax: list = field(default_factory=_default_axis("pmax"))
    options: dict = field(default_factory=dict)

    # -- shape ---------------------------------------------------------------------------------
    def axes(self) -> dict[str, list[float]]:
        """Swept name -> list of values, in the dimension order of ``sweep.nc``."""
        return {name: list(getattr(self, name)) for name in SWEPT}

    @property
    def shape(self) -> tuple[int, int, int, int]:
        return tuple(len(getattr(self, name)) for name in SWEPT)

    @property
    def n_points(self) -> int:
        return int(np.prod(self.shape))

    # -- validation ----------------------------------------------------------------------------
    def validate(self) -> "SweepSpec":
        """Check the whole sweep before anything is submitted (:meth:`validated_points`); returns
        ``self``."""
        self.validated_points()
        return self

    def validated_points(self) -> list[RunParams]:
        """Check the whole sweep and return its points (as :meth:`points`), each built -- and so
        validated -- once.

        Every axis must hold at least one number within its parameter's range and no
        duplicates; ``options`` must name known, non-swept parameters with valid values; and
        every point must be a valid ``RunParams`` (cross-checks such as r_post < R included).
        Values are normalised to floats in place.  Raises :class:`ParameterError` naming the field.
        """
        for name in SWEPT:
            values = getattr(self, name)
            if isinstance(values, (int, float)) and not isinstance(values, bool):
                values = [values]
            if isinstance(values, (str, bytes)) or not hasattr(values, "__iter__"):
                raise ParameterError(name, values, "a non-empty list of numbers")
            values = list(values)
            if not values:
                raise ParameterError(name, values, "a non-empty list of numbers")
            spec = PARAMETERS[name]
            values = [_round(spec.check(v)) for v in values]
            _check_unique(name, values)
            setattr(self, name, values)
        if not isinstance(self.options, Mapping):
            raise ParameterError("options", self.options, "a mapping of run option names to values")
        # None means "the default" (what a form or JSON body sends for an option left empty).
        self.options = {k: v for k, v in self.options.items() if v is not None}
        for name in self.options:
            if name in SWEPT:
                raise ParameterError(name, self.options[name],
                                     "a swept parameter: give it as an axis, not as an option")
        # A RunParams built from the options validates them with the usual one-line messages;
        # its normalised values (floats, not the strings a command line gives) are kept.
        base = RunParams.from_dict(dict(self.options))
        self.options = {k: getattr(base, k) for k in self.options}
        # Building a RunParams validates it, cross-field limits included (microseconds a point).
        points = self.points()
        # The work of a run depends on the options only (t_end, cfl, sound speed, resolution),
        # which every point shares.
        check_step_budget(points[0])
        return points

    # -- the runs ------------------------------------------------------------------------------
    def points(self) -> list[RunParams]:
        """One ``RunParams`` per grid point, C order over (E0, IOP, thickness, pmax)."""
        base = dict(self.options)
        return [RunParams.from_dict({**base, "E0": e, "IOP": i, "thickness": h, "pmax": p})
                for e in self.E0 for i in self.IOP for h in self.thickness for p in self.pmax]

    def point(self, index: int) -> RunParams:
        """The point at ``index`` of :meth:`points` (C order), built alone."""
        e, i, h, p = np.unravel_index(int(index), self.shape)
        return RunParams.from_dict({**self.options, "E0": self.E0[e], "IOP": self.IOP[i],
                                    "thickness": self.thickness[h], "pmax": self.pmax[p]})

    def index_of(self, params: RunParams) -> tuple[int, int, int, int]:
        """Grid index (iE0, iIOP, ithickness, ipmax) of a point of this sweep."""
        return tuple(list(getattr(self, n)).index(getattr(params, n)) for n in SWEPT)

    def run_options(self) -> dict[str, Any]:
        """All non-swept run parameters with defaults filled in (what every point shares)."""
        d = RunParams.from_dict(dict(self.options)).to_dict()
        for name in SWEPT:
            d.pop(name)
        return d

    # -- (de)serialisation ---------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form: ``{"E0": [...], "IOP": [...], "thickness": [...], "pmax": [...],
        "options": {...}}`` (user units)."""
        d: dict[str, Any] = {name: [float(v) for v in getattr(self, name)] for name in SWEPT}
        d["options"] = dict(self.options)
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], validate: bool = True) -> "SweepSpec":
        """Inverse of :meth:`to_dict`; also accepts a single number for an axis.  Missing axes
        take the parameter's default; unknown top-level keys raise ParameterError.  The result
        is validated unless ``validate`` is False: for a caller that validates it next with
        :meth:`validated_points` (building the grid once) or that stored it validated."""
        known = set(SWEPT) | {"options"}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ParameterError(unknown[0], d[unknown[0]], "one of " + ", ".join(sorted(known)))
        kwargs: dict[str, Any] = {}
        for name in SWEPT:
            if name in d:
                kwargs[name] = d[name]
        kwargs["options"] = dict(d.get("options") or {})
        spec = cls(**kwargs)
        return spec.validate() if validate else spec
