"""The sweep grid and the `airpuff sweep` command line: parsing, validation, bad input.

No solver runs here: these check what happens before anything is submitted.
"""

from __future__ import annotations

import json

import pytest

from airpuff_core.params import ParameterError, RunParams
from api.cli import main as airpuff_main
from sweep.grid import SweepSpec, parse_axis
from sweep.storage import point_key


# -- parse_axis -----------------------------------------------------------------------------------
def test_comma_list_keeps_order_and_units():
    assert parse_axis("E0", "0.3, 0.5,0.7") == [0.3, 0.5, 0.7]
    assert parse_axis("pmax", "0") == [0.0]  # pmax accepts 0 (a run at rest)


def test_start_stop_num_includes_both_ends_without_float_noise():
    assert parse_axis("IOP", "10:30:5") == [10.0, 15.0, 20.0, 25.0, 30.0]
    # linspace gives 0.30000000000000004; the grid must hold 0.3 so that .sel(E0=0.3) works
    assert parse_axis("E0", "0.1:0.3:3") == [0.1, 0.2, 0.3]
    assert parse_axis("thickness", "0.5:0.5:1") == [0.5]


@pytest.mark.parametrize("name,text,needle", [
    ("E0", "abc", "comma list"),
    ("E0", "", "comma list"),
    ("E0", "0.3,,0.5", "comma list"),
    ("IOP", "10:20", "start:stop:num"),
    ("IOP", "10:20:2.5", "whole number"),
    ("IOP", "10:20:0", "num >= 2"),
    ("IOP", "10:20:1", "num >= 2"),
    ("E0", "nan", "comma list"),
    ("E0", "0.5,0.5", "distinct"),
    ("E0", "60", "(0, 50] MPa"),
    ("IOP", "0:20:3", "(0, 80] mmHg"),  # the range check applies to generated values too
    ("pmax", "-1", "[0, 50] kPa"),
])
def test_bad_axis_raises_parameter_error_naming_the_axis(name, text, needle):
    with pytest.raises(ParameterError) as info:
        parse_axis(name, text)
    msg = str(info.value)
    assert info.value.name == name and name in msg and needle in msg
    assert "\n" not in msg


def test_only_swept_parameters_are_axes():
    with pytest.raises(ParameterError):
        parse_axis("R", "6,7")


# -- SweepSpec ------------------------------------------------------------------------------------
def test_points_in_c_order_with_options_applied():
    spec = SweepSpec(E0=[0.3, 0.5], IOP=[10, 20, 30], thickness=[0.5], pmax=[5, 10],
                     options={"resolution": "coarse", "t_end": "3"}).validate()
    assert spec.shape == (2, 3, 1, 2) and spec.n_points == 12
    pts = spec.points()
    assert len(pts) == 12
    # last axis fastest, as numpy's C order of an array with dims (E0, IOP, thickness, pmax)
    assert [(p.E0, p.IOP, p.pmax) for p in pts[:3]] == [(0.3, 10, 5), (0.3, 10, 10), (0.3, 20, 5)]
    assert pts[-1].E0 == 0.5 and pts[-1].IOP == 30 and pts[-1].pmax == 10
    assert all(p.t_end == 3.0 and p.resolution == "coarse" for p in pts)
    assert spec.options["t_end"] == 3.0  # normalised from the command-line string
    for i, p in enumerate(pts):
        import numpy as np
        assert np.ravel_multi_index(spec.index_of(p), spec.shape) == i


def test_axes_default_to_parameter_defaults():
    spec = SweepSpec(E0=[0.4]).validate()
    p = spec.points()[0]
    d = RunParams()
    assert (p.E0, p.IOP, p.thickness, p.pmax) == (0.4, d.IOP, d.thickness, d.pmax)


@pytest.mark.parametrize("kwargs,field", [
    ({"E0": []}, "E0"),
    ({"IOP": [10, 10]}, "IOP"),
    ({"thickness": [0.5, 5.0]}, "thickness"),
    ({"pmax": ["x"]}, "pmax"),
    ({"options": {"E0": 0.5}}, "E0"),  # a swept name is not an option
    ({"options": {"resolution": "ultra"}}, "resolution"),
    ({"options": {"nonsense": 1}}, "nonsense"),
    ({"options": {"r_post": 8.0}}, "r_post"),  # cross-field check of every point: r_post < R
    ({"options": {"instrument": "nct"}}, "instrument"),
    ({"pmax": [10.0, 12.0], "options": {"instrument": "corvis"}}, "pmax"),  # the paper's only
    ({"options": {"instrument": "ora", "ora_delay": -1}}, "ora_delay"),
])
def test_validate_names_the_bad_field(kwargs, field):
    with pytest.raises(ParameterError) as info:
        SweepSpec(**kwargs).validate()
    assert info.value.name == field


def test_dict_round_trip_is_json_safe():
    spec = SweepSpec(E0=[0.3, 0.5], IOP=[12.0], options={"resolution": "coarse", "t_end": 5}).validate()
    d = json.loads(json.dumps(spec.to_dict()))
    again = SweepSpec.from_dict(d)
    assert again.to_dict() == spec.to_dict()
    assert [point_key(p) for p in again.points()] == [point_key(p) for p in spec.points()]
    with pytest.raises(ParameterError):
        SweepSpec.from_dict({**d, "colour": "red"})


def test_point_key_depends_on_every_parameter_and_nothing_else():
    a = RunParams(E0=0.5, resolution="coarse")
    assert point_key(a) == point_key(RunParams(E0=0.5, resolution="coarse"))
    assert point_key(a) == point_key(RunParams.from_dict({"E0": "0.5", "resolution": "coarse"}))
    assert len({point_key(a), point_key(a.replace(E0=0.51)), point_key(a.replace(t_end=3)),
                point_key(a.replace(layout="polar"))}) == 4
    assert len(point_key(a)) == 16 and int(point_key(a), 16) >= 0


def test_point_key_of_the_cornea_options():
    """The shell's options and the hyperviscosity operator enter the key (the model version
    enters it too, so points stored by other solver code are never reused: test_reliability_sweep)."""
    a = RunParams()
    keys = {point_key(a), point_key(a.replace(cornea="shell")),
            point_key(a.replace(cornea="shell", limbus="pinned")), point_key(a.replace(model="clinical")),
            point_key(a.replace(hyperviscosity_operator="consistent"))}
    assert len(keys) == 5


def test_points_are_keyed_by_the_instrument_and_its_options():
    """The same grid under each instrument's pulse: every point a key of its own, and the
    ORA's delay in the key of the ORA's points."""
    grids = [SweepSpec(E0=[0.4, 0.6], IOP=[12.0, 16.0], options={"instrument": name})
             for name in ("paper", "ora", "corvis")]
    grids.append(SweepSpec(E0=[0.4, 0.6], IOP=[12.0, 16.0],
                           options={"instrument": "ora", "ora_delay": 3.0}))
    keys = [point_key(p) for spec in grids for p in spec.validated_points()]
    assert len(set(keys)) == len(keys) == 16
    assert [p.instrument for p in grids[2].validated_points()] == ["corvis"] * 4
    again = SweepSpec.from_dict(json.loads(json.dumps(grids[3].to_dict())))
    assert [point_key(p) for p in again.points()] == keys[12:]


# -- the command line: bad input is one line and exit code 2, before any cluster starts ------------
@pytest.mark.parametrize("argv,needle", [
    (["--E0", "abc"], "E0"),
    (["--E0", ""], "E0"),
    (["--IOP", "10:20"], "IOP"),
    (["--IOP", "5:30:x"], "IOP"),
    (["--thickness", "3"], "thickness"),
    (["--pmax", "1,1"], "pmax"),
    (["--resolution", "huge"], "resolution"),
    (["--instrument", "nct"], "instrument"),
    (["--instrument", "corvis", "--pmax", "8,10"], "pmax"),
    (["--t-end", "-2"], "t_end"),
    (["--workers", "0"], "workers"),
    (["--workers", "two"], "workers"),
])
def test_cli_bad_input_is_one_line_exit_2(argv, needle, capsys, tmp_path):
    out = tmp_path / "never"
    with pytest.raises(SystemExit) as info:
        airpuff_main(["sweep", *argv, "--out", str(out)])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err and "Traceback" not in err
    assert "accepted" in err or "invalid choice" in err or "expected" in err
    assert not out.exists()  # nothing was started or written


def test_cli_help_renders(capsys):
    with pytest.raises(SystemExit) as info:
        airpuff_main(["sweep", "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for flag in ("--E0", "--IOP", "--thickness", "--pmax", "--workers", "--scheduler", "--out",
                 "--resolution", "--retry-failed"):
        assert flag in out
