"""Before/after timings in one process, alternating: another commit's solver against this tree's.

    python -m benchmarks.interleaved REF run [coarse|paper|fine] [--model paper|clinical]
                                      [--repeat N] [--threads N] [--set NAME=VALUE ...]
                                      [--new-set NAME=VALUE ...]
    python -m benchmarks.interleaved REF mfpm [--rounds N] [--threads N]

REF is a git revision (``main``, a commit); its ``airpuff_core`` is exported with ``git archive``
into a temporary directory under another package name, so both solvers live in this process and
take turns: run A, run B, run A, ... (or round A, round B for the MFPM operator).  The machine's
speed changes from minute to minute (docs/performance.md), so only figures taken in the same
minutes compare; the per-pair ratios new/old are printed with the metrics of each run.  Both
the wall time and the process's CPU time are measured: on a machine shared with other work, the
CPU time leaves out the time the process waited for a core (not the slower caches).  Each run
is bracketed by the yardstick (``benchmarks/yardstick.py``, a fixed loop of about 1 s), and its
wall time divided by the mean of the two yardsticks around it is printed too: a figure of the
code that the machine's speed of the moment cancels out of (largely), comparable across days.
``--threads`` (default 1) sets the threads of both codes' kernels (``airpuff_core/threads.py``);
a revision from before them runs on one thread whatever it says.  ``--set NAME=VALUE``
(repeatable) sets a numeric run parameter of both codes' runs, e.g. ``--set
hyperviscosity_divergence=0.5``; ``--new-set NAME=VALUE`` one of this tree's runs only, e.g. an
option against the same code without it: ``python -m benchmarks.interleaved HEAD run paper
--model clinical --new-set hyperviscosity_interval=2``.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import inspect
import io
import json
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

from airpuff_core.params import INT_PARAMETERS, PARAMETERS
from benchmarks.yardstick import yardstick_data, yardstick_seconds

ROOT = Path(__file__).resolve().parent.parent
SHOWN = ("P1", "P2", "CH", "t_A1", "t_A2", "DA")


def import_revision(ref: str, into: Path):
    """``airpuff_core`` of git revision ``ref``, imported as the package ``airpuff_ref``."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref, "airpuff_core"],
                             check=True, capture_output=True).stdout
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        tar.extractall(into, filter="data")
    package = into / "airpuff_core"
    spec = importlib.util.spec_from_file_location("airpuff_ref", package / "__init__.py",
                                                  submodule_search_locations=[str(package)])
    module = importlib.util.module_from_spec(spec)
    sys.modules["airpuff_ref"] = module  # its relative imports resolve to airpuff_ref.*
    spec.loader.exec_module(module)
    return module


def compare_runs(old, resolution, repeat, threads=1, model="paper", settings=None,
                 new_settings=None):
    """``repeat`` pairs of runs (old, new) of the ``model`` preset at ``resolution`` with the
    run parameters ``settings`` (name -> value), and ``new_settings`` in the new code's runs
    only; returns the figures printed: per code the wall and CPU times [s] and the yardstick
    ratios."""
    settings = settings or {}
    import airpuff_core as new
    walls = {"old": [], "new": []}
    cpus = {"old": [], "new": []}
    ratios = {"old": [], "new": []}  # wall time / yardstick
    # both codes' runs on ``threads`` threads; a revision from before the thread setting on one,
    # whatever it says (one that has it would take all cores without it)
    has_threads = "threads" in inspect.signature(old.simulate).parameters
    options = {old: {"threads": threads} if has_threads else {}, new: {"threads": threads}}
    run_settings = {old: settings, new: {**settings, **(new_settings or {})}}
    for pkg in (old, new):
        pkg.simulate(pkg.RunParams(resolution=resolution, model=model, **run_settings[pkg],
                                   t_end=0.05), **options[pkg])
    data = yardstick_data()
    stick = yardstick_seconds(data)
    for _ in range(repeat):
        for name, pkg in (("old", old), ("new", new)):
            t0, c0 = time.perf_counter(), time.process_time()
            r = pkg.simulate(pkg.RunParams(resolution=resolution, model=model,
                                           **run_settings[pkg]), **options[pkg])
            walls[name].append(time.perf_counter() - t0)
            cpus[name].append(time.process_time() - c0)
            stick_before, stick = stick, yardstick_seconds(data)
            ratios[name].append(walls[name][-1] / (0.5 * (stick_before + stick)))
            d = r.diagnostics
            print(json.dumps({"code": name, "model": model, "resolution": resolution,
                              "wall_s": round(walls[name][-1], 2),
                              "cpu_s": round(cpus[name][-1], 2),
                              "yardstick_ratio": round(ratios[name][-1], 3),
                              "steps": d["steps"],
                              "coupling_iterations_per_step":
                                  round(d["mean_coupling_iterations"], 3),
                              "hyperviscous_applications_per_step":
                                  round(d["mean_hyperviscous_substeps"], 3),
                              **{k: r.metrics[k] for k in SHOWN}}), flush=True)
    for label, t in (("wall", walls), ("CPU", cpus), ("yardstick ratio", ratios)):
        pairs = [b / a for a, b in zip(t["old"], t["new"])]
        unit = "" if label == "yardstick ratio" else " s"
        print(f"{model} {resolution}, {label}: old {min(t['old']):.2f}{unit} fastest, "
              f"{statistics.median(t['old']):.2f} median; new {min(t['new']):.2f} / "
              f"{statistics.median(t['new']):.2f}; new/old per pair "
              f"{', '.join(f'{x:.3f}' for x in pairs)}", flush=True)
    return {"wall": walls, "cpu": cpus, "yardstick_ratio": ratios}


def compare_mfpm(old, rounds, repeats=200):
    from airpuff_core.fluid import KAPPA, Operators
    from benchmarks.bench_mfpm import moving_clouds
    ch, clouds, fields, parity = moving_clouds("paper")
    out = np.empty((4, ch.n, 5))
    rates = {"old": [], "new": []}  # per CPU second
    operators = {"old": old.fluid.Operators(ch.h, ch.area, KAPPA),
                 "new": Operators(ch.h, ch.area, KAPPA)}
    for ops in operators.values():
        ops.derivatives(*clouds[0], fields, parity, out)
    for _ in range(rounds):
        for name, ops in operators.items():
            c0 = time.process_time()
            for k in range(repeats):
                ops.derivatives(*clouds[k % 8], fields, parity, out)
            rates[name].append(ch.n * repeats / (time.process_time() - c0) / 1e6)
    ratios = [b / a for a, b in zip(rates["old"], rates["new"])]
    print(f"MFPM build + derivatives of 4 fields (paper), M particle-evaluations per CPU second "
          f"in {rounds} alternating rounds: old fastest {max(rates['old']):.2f}, median "
          f"{statistics.median(rates['old']):.2f}; new fastest {max(rates['new']):.2f}, median "
          f"{statistics.median(rates['new']):.2f}; new/old median of the rounds' ratios "
          f"{statistics.median(ratios):.3f}")


def interleaved_runs(ref, resolution="paper", repeat=2, threads=1, model="paper",
                     settings=None, new_settings=None):
    """``compare_runs`` of git revision ``ref`` against this tree (on ``threads`` threads)."""
    from airpuff_core.threads import solver_threads

    with tempfile.TemporaryDirectory() as tmp, solver_threads(threads):
        old = import_revision(ref, Path(tmp))
        print(f"interleaved runs: old = {ref}, new = this tree; {model} preset, {resolution} "
              f"resolution, {threads} thread(s)"
              + "".join(f", {k} = {v:g}" for k, v in (settings or {}).items())
              + "".join(f", new code's {k} = {v:g}" for k, v in (new_settings or {}).items()),
              flush=True)
        return compare_runs(old, resolution, repeat, threads, model, settings, new_settings)


def parse_settings(ap, flag, items):
    """{name: number} of the NAME=VALUE ``items`` of ``flag``; a bad one is the parser's error."""
    settings = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        try:
            number = float(value)
        except ValueError:
            ap.error(f"{flag} {item}: expected NAME=VALUE with a number")
        if not sep or not name:
            ap.error(f"{flag} {item}: expected NAME=VALUE with a number")
        if name not in PARAMETERS and name not in INT_PARAMETERS:
            ap.error(f"{flag} {item}: no run parameter {name!r}")
        if name in INT_PARAMETERS and number != int(number):
            ap.error(f"{flag} {item}: {name} is an integer")
        settings[name] = int(number) if name in INT_PARAMETERS else number
    return settings


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("ref", help="git revision to compare against, e.g. main")
    ap.add_argument("what", choices=("run", "mfpm"))
    ap.add_argument("resolution", nargs="?", default="paper", choices=("coarse", "paper", "fine"))
    ap.add_argument("--model", default="paper", choices=("paper", "clinical"),
                    help="model preset of the runs (default paper)")
    ap.add_argument("--repeat", type=int, default=2, help="runs of each (default 2)")
    ap.add_argument("--rounds", type=int, default=21, help="MFPM rounds of each (default 21)")
    ap.add_argument("--threads", type=int, default=1,
                    help="threads of this tree's kernels (default 1)")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="a numeric run parameter of both codes' runs (repeatable)")
    ap.add_argument("--new-set", action="append", default=[], metavar="NAME=VALUE",
                    help="a numeric run parameter of this tree's runs only (repeatable)")
    args = ap.parse_args(argv)
    settings = parse_settings(ap, "--set", args.set)
    new_settings = parse_settings(ap, "--new-set", args.new_set)
    if args.what == "run":
        interleaved_runs(args.ref, args.resolution, args.repeat, args.threads, args.model,
                         settings, new_settings)
        return
    from airpuff_core.threads import solver_threads

    with tempfile.TemporaryDirectory() as tmp, solver_threads(args.threads):  # the MFPM rounds
        old = import_revision(args.ref, Path(tmp))
        importlib.import_module("airpuff_ref.fluid")
        compare_mfpm(old, args.rounds)


if __name__ == "__main__":
    main()
