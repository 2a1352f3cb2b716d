"""Where a flow-distorted node cloud turns the fluid's acoustics unstable, and which
stabilisation holds it (docs/model.md section 4, "The late blow-ups at fine resolution").

A run's snapshot (default: its last state) gives the node positions; the cornea and the walls
are put at rest, so take a state after the puff (the late blow-ups come there).  For that cloud the study
lists the nodes where the undamped acoustics are anti-diffusive, (D G)_ii > 0
(``stability.acoustic_self_coupling``), and for the worst of them the growth rates of the
linearised step map of the whole solver on a patch of nodes around it (``stability.linearised_step``
with ``positions`` and ``patch``: the fluid at rest on that cloud, c fixed) for each
stabilisation asked for.

    airpuff run --model clinical --thickness 0.54 --resolution fine --c0 40 --c-slope 80 \\
        --hyperviscosity-speed 15 --hyperviscosity-divergence 0.5 --t-end 28.26 --out RUN.nc
    python -m studies.cloud_saddle RUN.nc --c 61 \\
        --variant hyperviscosity_speed=15,hyperviscosity_divergence=0.5 \\
        --variant hyperviscosity_speed=15,hyperviscosity_divergence=2

or, running the case itself to its blow-up (or its end) and analysing the cloud ``--before``
steps before it, with the fluid's largest speed, where it is, over the last steps:

    python -m studies.cloud_saddle --params model=clinical,thickness=0.54,resolution=fine,c0=40,\\
        c_slope=80,hyperviscosity_speed=15,hyperviscosity_divergence=0.5 --c 61
"""

from __future__ import annotations

import argparse
import collections
import time

import numpy as np

from airpuff_core.blowup import BlowUpCheck
from airpuff_core.coupling import CoupledModel
from airpuff_core.errors import SimulationError
from airpuff_core.dataset import open_dataset, params_from_dataset
from airpuff_core.kernels.nodes import AXIS, INTERIOR
from airpuff_core.params import RunParams
from airpuff_core.stability import acoustic_self_coupling, linearised_step

NOISE = 1.0  # 1/s, as studies/stability_threshold.py


def cloud_of(path, label):
    """(params, (x, y) [m], time [ms]) of the snapshot ``label`` of the run kept in ``path``."""
    with open_dataset(path) as ds:
        labels = [str(v) for v in ds["snapshot_label"].values]
        k = labels.index(label)
        x = ds["fluid_x"].values[k] * 1e-3
        y = ds["fluid_y"].values[k] * 1e-3
        return params_from_dataset(ds), (x, y), float(ds["snapshot_time"].values[k])


def record_to_blowup(params, before):
    """Run ``params`` to its end or its blow-up; returns (params, (x, y) [m], time [ms]) of the
    state ``before`` steps before the last, and prints the fluid's largest speed [m/s], its node
    and the node's kind over the last 2 ``before`` steps."""
    model = CoupledModel(params)
    check = BlowUpCheck()
    clouds = collections.deque(maxlen=before + 1)
    speeds = collections.deque(maxlen=2 * before)
    t_end = model.si.t_end_s
    try:
        while model.t < t_end - 1e-15:
            model.step(t_stop=t_end, observers=(check,))
            speed = np.hypot(model.vx, model.vy)
            i = int(np.argmax(speed))
            speeds.append((model.t * 1e3, float(speed[i]), i, int(model.fluid.kind[i])))
            clouds.append((model.t * 1e3, model.x.copy(), model.y.copy()))
    except SimulationError as err:
        print(err)
    print("t [ms], largest fluid speed [m/s], its node (kind) over the last steps:")
    for t_ms, v, i, kind in list(speeds)[::max(1, len(speeds) // 20)] + [speeds[-1]]:
        print(f"  {t_ms:.5f} {v:.4g} {i} ({kind})")
    t_ms, x, y = clouds[0]
    return params, (x, y), t_ms


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", nargs="?", help="a run's netCDF file")
    ap.add_argument("--snapshot", default="end")
    ap.add_argument("--params", help="NAME=VALUE,...: run this case to its blow-up instead")
    ap.add_argument("--before", type=int, default=40,
                    help="with --params: analyse the cloud this many steps before the last")
    ap.add_argument("--c", type=float, required=True, help="sound speed [m/s] of the analysis")
    ap.add_argument("--radius", type=float, default=6.0,
                    help="patch radius in node spacings about the worst node")
    ap.add_argument("--variant", action="append", default=[],
                    help="NAME=VALUE,... run parameters of one stabilisation (default: the run's)")
    args = ap.parse_args(argv)
    if (args.run is None) == (args.params is None):
        ap.error("give a run's file or --params")
    if args.run is not None:
        params, (x, y), t_ms = cloud_of(args.run, args.snapshot)
        source = f"{args.run}, snapshot {args.snapshot}"
    else:
        params, (x, y), t_ms = record_to_blowup(
            RunParams.from_dict(dict(kv.split("=", 1) for kv in args.params.split(","))),
            args.before)
        source = f"{args.before} steps before the last"
    params = params.replace(c0=args.c, c_rule="fixed")
    model = CoupledModel(params)
    free = (model.fluid.kind == INTERIOR) | (model.fluid.kind == AXIS)
    model.x[free], model.y[free] = x[free], y[free]
    model.refresh_derivatives()
    self_coupling = acoustic_self_coupling(model)
    h = model.chamber.h
    worst = np.argsort(self_coupling * h ** 2)[::-1][:5]
    print(f"{source} (t = {t_ms:.4f} ms), c = {args.c:g} m/s")
    print("nodes with the largest (D G)_ii h^2 (> 0: anti-diffusive):")
    for i in worst:
        d = np.hypot(x - x[i], y - y[i])
        d[i] = np.inf
        print(f"  node {i} (kind {model.fluid.kind[i]}) at x {x[i] * 1e3:.3f}, y {y[i] * 1e3:.3f} mm: "
              f"{self_coupling[i] * h[i] ** 2:+.3f}, growth without damping c sqrt = "
              f"{args.c * np.sqrt(max(self_coupling[i], 0.0)):.3g} /s, nearest node at "
              f"{d.min() / h[i]:.2f} h")
    centre = worst[0]
    patch = np.flatnonzero(np.hypot(x - x[centre], y - y[centre]) < args.radius * h[centre])
    print(f"patch of {patch.size} nodes within {args.radius:g} h of node {centre}:")
    for variant in args.variant or [""]:
        extra = dict(kv.split("=", 1) for kv in variant.split(",") if kv)
        run_params = RunParams.from_dict({**params.to_dict(), **extra})
        t0 = time.perf_counter()
        report = linearised_step(run_params, positions=(x, y), patch=patch)
        rates = report.growth_rates
        label = variant or "the run's stabilisation"
        print(f"  {label}: largest growth rate {rates[0]:.4g} /s, "
              f"{int(np.count_nonzero(rates > NOISE))} growing modes ({report.n_dof} DOFs, "
              f"dt {report.dt * 1e6:.3f} us, {time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
