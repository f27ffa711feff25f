"""``ehss simulate``: one closed-loop run, written as PNG, NPZ and CSV, with a printed summary.

Exit codes: 0 the run tracked; 2 bad arguments; 3 the run diverged (a non-finite value or a state bound);
4 it lost track without diverging (the windowed RMS error above the reference's amplitude, see
``Scenario.lost_track``). The files are written in every case.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from ehss_gym.core.metrics import format_summary
from ehss_gym.core.response import frequency_response, reference_model_response
from ehss_gym.core.settings import UNITS
from ehss_gym.core.sim import simulate
from ehss_gym.infra.util import atomic_write, atomic_write_text, out_paths
from ehss_gym.reporting.plotting import plot_frequency_response, plot_trajectory

from .args import add_loop_arguments, scenario_from_args

EXIT_DIVERGED = 3
EXIT_LOST_TRACK = 4
EPILOG = f"""exit codes: 0 the run tracked; 2 bad arguments; {EXIT_DIVERGED} the run diverged (non-finite value or a
state bound: |x2| > omega_max, |x3| > 1.5 P_s); {EXIT_LOST_TRACK} it lost track without diverging (windowed RMS
error above the reference's amplitude). The PNG, NPZ and CSV are written in every case.

examples:
  ehss simulate --out runs/default                      # the recommended loop on the paper's run: tracks
  ehss simulate --preset paper --t-end 0.05 --out runs/paper   # the printed law: diverges (exit {EXIT_DIVERGED})
  ehss simulate --reference step --amplitude 0.5 --t-end 2 --friction none --out runs/step
  ehss simulate --reference chirp --omega-end 300 --t-end 20 --friction none --bode --out runs/chirp"""


def _command(argv) -> str:
    return "ehss " + " ".join(argv) if argv else "ehss simulate"


def _write_outputs(traj, base: str, made_by: str) -> None:
    """PATH.npz (plain names), PATH.csv (a header with units, e.g. ``t [s]``) and PATH.png."""
    arrays = traj.arrays()
    units = traj.units()
    atomic_write(base + ".npz", lambda f: np.savez(f, **arrays))
    header = ",".join(f"{k} [{units[k]}]" for k in arrays)
    table = np.column_stack(list(arrays.values()))
    atomic_write(base + ".csv", lambda f: np.savetxt(f, table, delimiter=",", header=header, comments="", fmt="%.10g"))
    plot_trajectory(traj, base + ".png", made_by=made_by)


def _write_bode(traj, base: str, made_by: str) -> str:
    """The closed loop's r -> y frequency response of a chirp or multi-sine run: PATH_bode.png and .csv."""
    fr = frequency_response(traj.t, traj.r, traj.y)
    rows = np.column_stack([fr.freq, fr.magnitude_db, fr.phase_deg, fr.coherence])
    atomic_write_text(base + "_bode.csv", "frequency [Hz],magnitude [dB],phase [deg],coherence [-]\n"
                      + "\n".join(",".join(f"{v:.8g}" for v in row) for row in rows) + "\n")
    sc = traj.scenario
    target = (fr.freq, reference_model_response(sc.order, sc.ref_model_hz, fr.freq))
    plot_frequency_response(fr, base + "_bode.png", sc, made_by=made_by, reference=target)
    return base + "_bode.png, " + base + "_bode.csv"


def cmd_simulate(args) -> int:
    """Run, write the files, print the summary; returns the exit code (module docstring)."""
    prog = "ehss simulate"
    try:
        sc = scenario_from_args(args)
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    if args.bode and sc.reference.family not in ("chirp", "multisine"):
        print(f"{prog}: error: --bode needs a broadband reference (--reference chirp or multisine), got "
              f"{sc.reference.family}", file=sys.stderr)
        return 2
    traj = simulate(sc)
    base = out_paths(args.out)
    made_by = _command(getattr(args, "argv", None))
    _write_outputs(traj, base, made_by)
    lim = "none" if sc.current_limit is None else f"{sc.current_limit:g} mA"
    print(f"{sc.task} task ({args.preset} preset), n={sc.n}, f_r={sc.fr:g} Hz, sigma={sc.sigma:g}, "
          f"smoothing={sc.smoothing:g}, h={sc.control_period:g} s, substeps={sc.substeps}, limit={lim}, "
          f"estimator={sc.estimator} at {sc.estimator_hz:g} Hz, reference model {sc.ref_model_hz:g} Hz, "
          f"t_end={sc.t_end:g} s; {sc.reference.description}")
    m = traj.metrics()
    print(format_summary(m, UNITS[sc.task]))
    written = [base + ".png", base + ".npz", base + ".csv"]
    if args.bode and not traj.diverged:
        written.append(_write_bode(traj, base, made_by))
    print("wrote " + ", ".join(written))
    if m["diverged"]:
        return EXIT_DIVERGED
    return EXIT_LOST_TRACK if m["lost_track"] else 0


def register(sub):
    p = sub.add_parser("simulate", help="simulate one closed-loop run and write PNG, NPZ, CSV and a summary",
                       description="One closed-loop run of the EHSS loop. With no settings: the env's recommended "
                                   "loop on the paper's 20 s run (it tracks); --preset paper gives the law as "
                                   "printed (it diverges).", epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    add_loop_arguments(p)
    p.add_argument("--bode", action="store_true",
                   help="also estimate the closed loop's r -> y frequency response (needs --reference chirp or "
                        "multisine): PATH_bode.png and PATH_bode.csv")
    p.add_argument("--out", required=True, help="output path prefix (PATH.png, PATH.npz, PATH.csv)")
    p.set_defaults(func=cmd_simulate)
