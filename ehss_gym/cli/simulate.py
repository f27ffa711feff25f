"""``ehss simulate``: one closed-loop run, written as PNG, NPZ and CSV, with a printed summary.

Exit codes: 0 the run tracked; 2 bad arguments; 3 the run diverged (a non-finite value or a state bound);
4 it lost track without diverging (the windowed RMS error above the reference's amplitude, see
``Scenario.lost_track``). The files are written in every case. Its options: :func:`ehss_gym.cli.options.add_simulate`
(every loop setting of :class:`~ehss_gym.core.settings.Scenario` has its flag).
"""

from __future__ import annotations

import math
import sys

import numpy as np

from ehss_gym.core.metrics import format_summary
from ehss_gym.core.params import PlantParams
from ehss_gym.core.response import frequency_response, reference_model_response
from ehss_gym.core.rig import TABLE_I, Rig
from ehss_gym.core.settings import LOOP_SETTINGS, PAPER_FRICTION, UNITS, Scenario
from ehss_gym.core.signals import chirp, multisine, sine, step
from ehss_gym.core.sim import simulate
from ehss_gym.envs.config import EnvConfig
from ehss_gym.infra.util import atomic_write, atomic_write_text, out_paths
from ehss_gym.reporting.trajectory_figures import plot_frequency_response, plot_trajectory

from .common import plant_note
from .options import NONE

EXIT_DIVERGED = 3
EXIT_LOST_TRACK = 4


def _reference(args, t_end: float):
    """The reference the arguments ask for (``ValueError`` from the signal builders names a bad value)."""
    kind = args.reference
    if kind == "sine":
        return sine(args.amplitude, args.omega, args.phase, args.offset)
    if kind == "step":
        return step(args.amplitude, args.t_step, args.offset)
    if kind == "chirp":
        t0, t1 = args.sweep or (0.0, t_end)
        return chirp(args.amplitude, args.omega_start, args.omega_end, t0, t1, args.phase, args.offset)
    return multisine(args.amplitudes, args.omegas, args.phases, args.offset)


def preset_scenario(preset: str, task: str, rig: Rig = TABLE_I, law_settings=None) -> Scenario:
    """The loop of a preset on the rig: the env's defaults ("recommended": the rig's rated current as the limit, the
    law's settings from ``law_settings`` if given) or the law as printed ("paper")."""
    if preset == "recommended":
        return EnvConfig.from_kwargs({"task": task, "plant": rig, "law_settings": law_settings}).template()
    return Scenario(task=task, plant=rig.plant, model=rig.model, rated_current=rig.rated_current)


def default_friction(reference: str) -> tuple:
    """The friction events a reference family gets when ``--friction`` is not given: the paper's (1.8 N*m from 8 to
    10 s) belong to the paper's sine run; a step, chirp or multi-sine response is measured without them."""
    return PAPER_FRICTION if reference == "sine" else ()


def scenario_from_args(args) -> Scenario:
    """The Scenario of ``ehss simulate``'s arguments: the preset's loop with every loop setting given on top.

    Raises:
        ValueError: a setting the Scenario refuses (the message names it).
    """
    rig = rig_of(args)
    base = preset_scenario(args.preset, args.task, rig, getattr(args, "law_settings", None))
    changes = {k: getattr(args, k) for k in LOOP_SETTINGS if k != "task" and getattr(args, k, None) is not None}
    for k, v in changes.items():
        if v == NONE or (k == "current_limit" and v == math.inf):  # the setting switched off
            changes[k] = None
    plant = rig.plant.scaled(**args.mismatch) if args.mismatch else rig.plant  # the controller keeps the rig's model
    return base.replace(**changes, t_end=args.t_end, reference=_reference(args, args.t_end),
                        friction=default_friction(args.reference) if args.friction is None else tuple(args.friction),
                        noise_std=args.noise or (0.0, 0.0, 0.0, 0.0), seed=args.seed, plant=plant,
                        model=rig.controller_model if args.mismatch else rig.model)


def rig_of(args) -> Rig:
    """The rig of ``--plant`` (Table I without it)."""
    return getattr(args, "plant", None) or TABLE_I


def _command(argv) -> str:
    return "ehss " + " ".join(argv) if argv else "ehss simulate"


def plant_arrays(rig: Rig) -> dict[str, np.ndarray]:
    """The rig as NPZ entries: its label (name, file, hash of its values), the plant's and the controller's model's
    values in the order of ``plant_fields`` (SI units, :data:`ehss_gym.core.params.FIELDS`), the rated current [mA]."""
    return {"plant": np.array(rig.label), "plant_hash": np.array(rig.hash),
            "plant_fields": np.array(PlantParams._fields), "plant_values": rig.plant.as_array(),
            "model_values": rig.controller_model.as_array(), "rated_current_mA": np.array(rig.rated_current)}


def _write_outputs(traj, base: str, made_by: str, rig: Rig) -> None:
    """PATH.npz (plain names, and the plant: :func:`plant_arrays`), PATH.csv (a first line ``# plant: ...``, then a
    header with units, e.g. ``t [s]``) and PATH.png."""
    arrays = traj.arrays()
    units = traj.units()
    atomic_write(base + ".npz", lambda f: np.savez(f, **arrays, **plant_arrays(rig)))
    header = f"# {rig.summary()}\n" + ",".join(f"{k} [{units[k]}]" for k in arrays)
    table = np.column_stack(list(arrays.values()))
    atomic_write(base + ".csv", lambda f: np.savetxt(f, table, delimiter=",", header=header, comments="", fmt="%.10g"))
    plot_trajectory(traj, base + ".png", made_by=f"{made_by}; plant {rig.label}")


def _write_bode(traj, base: str, made_by: str, rig: Rig) -> str:
    """The closed loop's r -> y frequency response of a chirp or multi-sine run: PATH_bode.png and .csv (its first
    line ``# plant: ...``, as the run's CSV)."""
    fr = frequency_response(traj.t, traj.r, traj.y)
    rows = np.column_stack([fr.freq, fr.magnitude_db, fr.phase_deg, fr.coherence])
    header = f"# {rig.summary()}\nfrequency [Hz],magnitude [dB],phase [deg],coherence [-]\n"
    atomic_write_text(base + "_bode.csv", header + "\n".join(",".join(f"{v:.8g}" for v in row) for row in rows) + "\n")
    sc = traj.scenario
    target = (fr.freq, reference_model_response(sc.order, sc.ref_model_hz, fr.freq))
    plot_frequency_response(fr, base + "_bode.png", sc, made_by=made_by, reference=target)
    return base + "_bode.png, " + base + "_bode.csv"


def run(args) -> int:
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
    plant_note(prog, args.plant, args.law_settings)
    traj = simulate(sc)
    base = out_paths(args.out)
    made_by = _command(getattr(args, "argv", None))
    rig = rig_of(args)
    _write_outputs(traj, base, made_by, rig)
    print(rig.summary() + (f"; the plant's {', '.join(args.mismatch)} scaled by --mismatch" if args.mismatch else "")
          + ("" if getattr(args, "law_settings", None) is None else f"; {args.law_settings.describe()}"))
    lim = "none" if sc.current_limit is None else f"{sc.current_limit:g} mA"
    print(f"{sc.task} task ({args.preset} preset), n={sc.n}, f_r={sc.fr:g} Hz, sigma={sc.sigma:g}, "
          f"smoothing={sc.smoothing:g}, h={sc.control_period:g} s, substeps={sc.substeps}, limit={lim}, "
          f"estimator={sc.estimator} at {sc.estimator_hz:g} Hz, reference model {sc.ref_model_hz:g} Hz, "
          f"t_end={sc.t_end:g} s; {sc.reference.description}; friction "
          + (", ".join(f"{a:g} N*m from {t0:g} to {t1:g} s" for a, t0, t1 in sc.friction) or "none"))
    m = traj.metrics()
    print(format_summary(m, UNITS[sc.task]))
    written = [base + ".png", base + ".npz", base + ".csv"]
    if args.bode and not traj.diverged:
        written.append(_write_bode(traj, base, made_by, rig))
    print("wrote " + ", ".join(written))
    if m["diverged"]:
        return EXIT_DIVERGED
    return EXIT_LOST_TRACK if m["lost_track"] else 0


__all__ = ["run", "scenario_from_args", "preset_scenario", "plant_arrays", "rig_of", "EXIT_DIVERGED",
           "EXIT_LOST_TRACK"]
