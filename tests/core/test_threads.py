"""Threads (airpuff_core/threads.py): the MFPM build and the hyperviscous passes split their nodes
into chunks that run in parallel, and a run's numbers must not depend on how many threads or
chunks there are, nor on where the arrays lie in memory, nor on the process
(tests/sweep/test_sweep_dask.py compares a Dask worker's run with the same run here).  The
fused hyperviscous operator is checked against the single-field reference kernels
(``hyperviscous_term``: one field, one pass per operator factor, the adjoint by its own scatter),
which share no code with it."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from airpuff_core import ParameterError, RunParams
from airpuff_core.coupling import CoupledModel
from airpuff_core.fluid import COND_MAX
from airpuff_core.kernels.mfpm import (flow_operator_work, hyperviscous_flow_operator,
                                       hyperviscous_term, mapped_derivatives, mfpm_derivatives)
from airpuff_core.threads import check_threads

OPERATORS = ("brookshaw", "consistent_velocity", "consistent")


@pytest.fixture(scope="module", params=OPERATORS)
def model(request):
    return CoupledModel(RunParams(resolution="coarse",
                                  hyperviscosity_operator=request.param))


def _flow(model, fields, n_chunks):
    n = model.x.size
    out = np.empty((3, n))
    hyperviscous_flow_operator(*fields, *model.fluid.ops_n.hyperviscosity_args(),
                               model.fluid.hv_consistent_density, model.fluid.hv_consistent_velocity,
                               n_chunks, flow_operator_work(n), *out)
    return out


def test_flow_operator_is_the_single_field_operator_on_each_field(model):
    """H rho, H v_x, H v_y of the three-field kernel = the reference kernel on each field, with
    rho and v_y even and v_x odd in x, and K^* L K where the option asks for it."""
    n = model.x.size
    rng = np.random.default_rng(1)
    fields = rng.standard_normal((3, n))
    out = _flow(model, fields, 1)
    ops = model.fluid.ops_n
    w1, w2 = np.empty(n), np.empty(n)
    for slot, parity, consistent in ((0, 1.0, model.fluid.hv_consistent_density),
                                     (1, -1.0, model.fluid.hv_consistent_velocity),
                                     (2, 1.0, model.fluid.hv_consistent_velocity)):
        ref = np.empty(n)
        hyperviscous_term(fields[slot], parity, *ops.hyperviscosity_args(), consistent,
                          np.ones(n), w1, w2, ref)
        scale = np.abs(ref).max()
        assert np.abs(out[slot] - ref).max() <= 1e-12 * scale, slot


@pytest.mark.parametrize("n_chunks", [2, 3, 7])
def test_flow_operator_does_not_depend_on_the_chunks(model, n_chunks):
    rng = np.random.default_rng(2)
    fields = rng.standard_normal((3, model.x.size))
    assert np.array_equal(_flow(model, fields, 1), _flow(model, fields, n_chunks))


@pytest.mark.parametrize("n_chunks", [2, 5])
def test_mfpm_build_does_not_depend_on_the_chunks(n_chunks):
    """Every output of the build (derivatives, condition numbers, the Brookshaw and consistent
    pair lists) is the same, bit for bit, with one chunk or several."""
    model = CoupledModel(RunParams(resolution="coarse"))
    ops = model.fluid.ops_n
    n = model.x.size
    rng = np.random.default_rng(3)
    x = model.x + 0.02 * ops.h * rng.standard_normal(n) * (model.fluid.kind == 0)
    fields = rng.standard_normal((3, n))
    parity = np.array([1.0, -1.0, 1.0])
    ops.table.update(x, model.y)
    t = ops.table

    def build(chunks):
        out = np.zeros((3, n, 5))
        arrays = [np.zeros(n), np.zeros(n, np.int64), np.zeros_like(ops.nbr),
                  np.zeros_like(ops.sign), np.zeros_like(ops.lap_b),
                  np.zeros_like(ops.lap_c), np.zeros((5, ops.nbr.size))]
        status = mfpm_derivatives(x, model.y, ops.h, ops.inv_h, ops.area, ops.kappa, t.start,
                                  t.nbr, t.mirrored, ops.all_nodes, fields, parity, COND_MAX, out,
                                  *arrays, True, True, chunks)
        return status, out, arrays

    status1, out1, arrays1 = build(1)
    status2, out2, arrays2 = build(n_chunks)
    assert status1 == status2 == 0
    assert np.array_equal(out1, out2)
    for a, b in zip(arrays1, arrays2):
        assert np.array_equal(a, b)


def _mapped(ops, x, y, fields, chunks):
    """The operator kept by the last build (``lap_w``), mapped to positions moved from (x, y):
    the derivatives of the fields (odd, even, even), in ``chunks`` chunks, and the strains."""
    n = x.size
    rng = np.random.default_rng(6)
    moved_x = x * (1.0 + 0.01 * np.sin(300.0 * y)) + 1e-3 * ops.h * rng.standard_normal(n)
    moved_y = y + 1e-3 * ops.h * rng.standard_normal(n)
    out = np.zeros((3, n, 5))
    strain = np.zeros(n)
    status = mapped_derivatives(moved_x, moved_y, ops.all_nodes, fields,
                                np.array([-1.0, 1.0, 1.0]), ops.start, ops.nbr, ops.sign,
                                ops.count, ops.lap_w, out, strain, chunks)
    assert status == 0
    return np.concatenate([out.ravel(), strain])


@pytest.mark.parametrize("n_chunks", [2, 5])
def test_mapped_derivatives_do_not_depend_on_the_chunks(n_chunks):
    """The kept operator mapped to moved nodes gives the same bits with one chunk or several."""
    model = CoupledModel(RunParams(resolution="coarse"))
    ops = model.fluid.ops_n
    fields = np.random.default_rng(7).standard_normal((3, model.x.size))
    assert np.array_equal(_mapped(ops, model.x, model.y, fields, 1),
                          _mapped(ops, model.x, model.y, fields, n_chunks))


def test_mfpm_build_does_not_depend_on_where_its_arrays_lie():
    """The result must not depend on the memory addresses of the arrays (which differ between
    processes, e.g. a Dask worker and its client; a build with reassociated reductions did).  Twenty builds, each after an allocation that shifts the heap, in 1-3 chunks,
    give the same consistent-Laplacian coefficients and derivatives bit for bit."""
    model = CoupledModel(RunParams(resolution="coarse"))
    ops, t = model.fluid.ops_n, model.fluid.ops_n.table
    n = model.x.size
    fields = np.stack([np.sin(300 * model.x), np.cos(200 * model.y)])
    parity = np.array([-1.0, 1.0])
    first = None
    shifts = []
    for trial in range(20):
        shifts.append(np.empty(17 + 1000 * trial))  # moves the next allocations
        out = np.zeros((2, n, 5))
        lap_c = np.zeros_like(ops.lap_c)
        lap_w = np.zeros((5, ops.nbr.size))
        arrays = [np.zeros(n), np.zeros(n, np.int64), np.zeros_like(ops.nbr),
                  np.zeros_like(ops.sign), np.zeros_like(ops.lap_b),
                  lap_c, lap_w]
        mfpm_derivatives(model.x, model.y, ops.h, ops.inv_h, ops.area, ops.kappa, t.start, t.nbr,
                         t.mirrored, ops.all_nodes, fields, parity, COND_MAX, out, *arrays, True,
                         True, 1 + trial % 3)
        if first is None:
            first = (out, lap_c, lap_w)
        assert (np.array_equal(out, first[0]) and np.array_equal(lap_c, first[1])
                and np.array_equal(lap_w, first[2])), trial


def build_and_operator_outputs():
    """Every output of a coarse build (derivatives of an odd and two even fields, condition
    numbers, both pair lists) and of the three-field hyperviscous operator, on one chunk and
    on three, at nodes moved off the lattice."""
    model = CoupledModel(RunParams(resolution="coarse"))
    ops, t = model.fluid.ops_n, model.fluid.ops_n.table
    n = model.x.size
    rng = np.random.default_rng(5)
    x = model.x + 0.02 * ops.h * rng.standard_normal(n) * (model.fluid.kind == 0)
    ops.table.update(x, model.y)
    fields = rng.standard_normal((3, n))
    ops.start[:] = t.start
    arrays = {"cond": ops.cond, "count": ops.count, "nbr": ops.nbr, "sign": ops.sign,
              "lap_b": ops.lap_b, "lap_c": ops.lap_c, "lap_w": ops.lap_w}
    outputs = {}
    for chunks in (1, 3):
        out = np.zeros((3, n, 5))
        status = mfpm_derivatives(x, model.y, ops.h, ops.inv_h, ops.area, ops.kappa, t.start,
                                  t.nbr, t.mirrored, ops.all_nodes, fields,
                                  np.array([1.0, -1.0, 1.0]), COND_MAX, out, *arrays.values(),
                                  True, True, chunks)
        assert status == 0
        outputs[f"derivatives_{chunks}"] = out
        outputs.update({f"{name}_{chunks}": a.copy() for name, a in arrays.items()})
        outputs[f"operator_{chunks}"] = _flow(model, fields, chunks)  # on the lists just built
        outputs[f"mapped_{chunks}"] = _mapped(ops, x, model.y, fields, chunks)
    return outputs


COMPILE_AND_SAVE = """
import sys
import numpy as np
from tests.core.test_threads import build_and_operator_outputs
np.savez(sys.argv[1], **build_and_operator_outputs())
"""


@pytest.mark.slow
def test_fresh_compilation_gives_the_cached_bits(tmp_path):
    """The kernels compiled afresh (a process with an empty Numba cache, as a new Dask worker or
    a fresh clone), the same kernels loaded from that cache by a second process, and this
    process's give the same bits: fused multiply-adds are chosen per expression, the same in
    every compiled copy, and no sum is reassociated (``kernels.mfpm.FUSED_MULTIPLY_ADD``; with
    reassociation allowed, the cached build differed from the fresh one in the last bits)."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba_cache")}
    root = Path(__file__).resolve().parents[2]
    results = []
    for name in ("fresh", "cached"):
        results.append(tmp_path / f"{name}.npz")
        proc = subprocess.run([sys.executable, "-c", COMPILE_AND_SAVE, str(results[-1])], env=env,
                              capture_output=True, text=True, timeout=600, cwd=root)
        assert proc.returncode == 0, proc.stdout + proc.stderr
    here = build_and_operator_outputs()
    for result in results:
        with np.load(result) as other:
            assert sorted(other.files) == sorted(here)
            for name, value in here.items():
                assert np.array_equal(other[name], value), (result.name, name)
    for name in ("derivatives", "lap_c", "operator"):  # and one chunk = three chunks
        assert np.array_equal(here[f"{name}_1"], here[f"{name}_3"]), name


RUN_ON_ONE_AND_TWO_THREADS = """
import sys
import numpy as np
from airpuff_core import RunParams, simulate
from airpuff_core.threads import max_threads
assert max_threads() >= 2, max_threads()
params = RunParams(resolution="coarse", model="clinical", instrument="ora", t_end=16.0)
one = simulate(params, threads=1).to_dataset()
two = simulate(params, threads=2).to_dataset()
assert one.attrs["solver_threads"] == 1 and two.attrs["solver_threads"] == 2
assert one.attrs["solver_pulse_switch_off_ms"] < 16.0, one.attrs["solver_pulse_switch_off_ms"]
differ = [name for name in one.data_vars
          if not np.array_equal(one[name].values, two[name].values, equal_nan=True)]
differ += [name for name in ("solver_pulse_applanation_detected_ms", "solver_pulse_switch_off_ms")
           if one.attrs[name] != two.attrs[name]]
print("differ:", differ)
sys.exit(1 if differ else 0)
"""


@pytest.mark.slow
def test_a_run_does_not_depend_on_the_threads():
    """A coarse clinical run (shear shell, viscoelasticity, compliant globe, consistent
    hyperviscosity) under the ORA's pulse, switched off by the applanation it detects, on one
    thread and on two: every history, snapshot and metric and the switch-off the same.  In a
    process of its own with two threads allowed (this one keeps to one: tests/conftest.py)."""
    from airpuff_core.threads import _fast_layer_available

    if not _fast_layer_available():
        pytest.skip("no OpenMP or TBB threading layer here: runs keep to one thread")
    env = {**os.environ, "NUMBA_NUM_THREADS": "2"}
    proc = subprocess.run([sys.executable, "-c", RUN_ON_ONE_AND_TWO_THREADS], env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr


@pytest.mark.parametrize("bad", [0, -1, 1.5, "x", True, 10 ** 6])
def test_bad_threads_name_the_parameter_and_the_range(bad):
    with pytest.raises(ParameterError, match=r"invalid threads=.*accepted an integer in \[1, "):
        check_threads(bad)


def test_cli_rejects_bad_threads_with_one_line():
    proc = subprocess.run([sys.executable, "-m", "api.cli", "run", "--threads", "0"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "threads" in lines[0] and "[1, " in lines[0], proc.stderr
