"""``ehss simulate``: one closed-loop run, written as PNG, NPZ and CSV, with a printed summary."""

from __future__ import annotations

import sys

import numpy as np

from ehss_gym.core.metrics import format_summary
from ehss_gym.core.sim import UNITS, simulate
from ehss_gym.core.util import atomic_write, out_paths
from ehss_gym.reporting.plotting import plot_trajectory

from .args import add_loop_arguments, scenario_from_args


def cmd_simulate(args) -> int:


    try:
        sc = scenario_from_args(args)
    except ValueError as exc:
        print(f"ehss simulate: error: {exc}", file=sys.stderr)
        return 2
    traj = simulate(sc)
    base = out_paths(args.out)
    arrays = traj.arrays()
    atomic_write(base + ".npz", lambda f: np.savez(f, **arrays))
    header = ",".join(arrays)
    table = np.column_stack(list(arrays.values()))
    atomic_write(base + ".csv", lambda f: np.savetxt(f, table, delimiter=",", header=header, comments="", fmt="%.10g"))
    cmdline = "ehss " + " ".join(sys.argv[1:]) if sys.argv and sys.argv[0].endswith("ehss") else "ehss simulate"
    plot_trajectory(traj, base + ".png", made_by=cmdline)
    print(f"{sc.task} task, n={sc.n}, f_r={sc.fr:g} Hz, sigma={sc.sigma:g}, h={sc.control_period:g} s, "
          f"substeps={sc.substeps}, limit={sc.current_limit or 'none'} mA, estimator={sc.estimator}, "
          f"t_end={sc.t_end:g} s")
    print(format_summary(traj.metrics(), UNITS[sc.task]))
    print(f"wrote {base}.png, {base}.npz, {base}.csv")
    return 0


def register(sub):
    p = sub.add_parser("simulate", help="simulate one closed-loop run and write PNG, NPZ, CSV and a summary")
    add_loop_arguments(p)
    p.add_argument("--out", required=True, help="output path prefix (PATH.png, PATH.npz, PATH.csv)")
    p.set_defaults(func=cmd_simulate)


