"""Every option of every ``ehss`` sub-command, and the argparse types behind them.

Light on purpose: ``ehss --help`` and a bad argument answer from this module alone, which reads the extension-point
tables (:mod:`ehss_gym.core.registry`), the loop settings (:mod:`ehss_gym.core.settings`) and the settings records
of the commands, never the simulator, the env or the learned agents. One name per concept across the commands:
``--task`` (a comma-separated list where a command takes several), ``--workers`` (parallel jobs), ``--backend``,
``--address``, ``--store``/``--no-store``, ``--out``, ``--quick``, ``--no-progress``. Renamed options keep their old
name for one release (:func:`add_deprecated`): it still works and prints a deprecation warning. Bad values exit with
code 2 and a message naming the option and the accepted range (argparse's convention).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import typing

from ehss_gym.core.params import PlantParams
from ehss_gym.core.registry import ESTIMATORS, LAWS, choices_help, names
from ehss_gym.core.rig import PlantFileError, as_rig, shipped_plants
from ehss_gym.core.settings import LOOP_SETTINGS, TASKS, Scenario
from ehss_gym.core.signals import FAMILIES
from ehss_gym.core.validate import check_even_n
from ehss_gym.envs.law_table import LawSettingsError, as_law_table
from ehss_gym.evaluation.suites import SUITES, EvalConfig
from ehss_gym.infra import BACKENDS, DEFAULT_STORE, RAY_INSTALL
from ehss_gym.train.config import build_parser as add_train_config
from ehss_gym.train.options import field_docs

NONE = "none"  # the command-line word for a setting's None (no current limit, no pressure domain, ...)


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Every option's default in its help (unless the help already says it), descriptions kept as written."""

    def _get_help_string(self, action):
        text = action.help or ""
        unset = action.default is None or action.default is False or action.default is argparse.SUPPRESS
        if "default" in text or unset or not action.option_strings:
            return text
        default = ",".join(map(str, action.default)) if isinstance(action.default, (tuple, list)) else action.default
        return f"{text} (default: {default})"


class Deprecated(argparse.Action):
    """An option's old name, kept for one release: it sets the new option and prints a deprecation warning."""

    def __init__(self, option_strings, dest, new: str, base: argparse.Action, **kwargs):
        self.new = new
        self.base = base
        super().__init__(option_strings, base.dest, nargs=base.nargs, const=base.const, type=base.type,
                         choices=base.choices, help=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{parser.prog}: warning: {option_string} is deprecated and will be removed in the next release; use "
              f"{self.new}", file=sys.stderr)
        self.base(parser, namespace, values, self.new)


def add_deprecated(p: argparse.ArgumentParser, old: str, new: str) -> None:
    """Accept ``old`` as a deprecated name of the existing option ``new`` of ``p``."""
    base = next(a for a in p._actions if new in a.option_strings)
    p.add_argument(old, action=Deprecated, new=new, base=base)


# --- argparse types: each names its option and the accepted range -----------------------------------------


def finite(name: str, low: float | None = None, low_open: bool = True):
    """argparse type: a finite number (above ``low``, or at least ``low`` unless ``low_open``)."""
    def conv(text):
        try:
            v = float(text)
        except ValueError:
            v = float("nan")
        bad = not math.isfinite(v) or (low is not None and (v < low or (low_open and v == low)))
        if bad:
            rng = "a finite number" if low is None else f"a finite number {'>' if low_open else '>='} {low:g}"
            raise argparse.ArgumentTypeError(f"{name} must be {rng}, got {text!r}")
        return v

    return conv


def or_none(name: str, conv):
    """argparse type: ``none`` (None, the setting switched off) or what ``conv`` accepts."""
    def parse(text):
        if text.strip().lower() == NONE:
            return NONE
        try:
            return conv(text)
        except argparse.ArgumentTypeError as exc:
            raise argparse.ArgumentTypeError(f"{exc} (or '{NONE}')") from None

    return parse


def int_at_least(name: str, low: int):
    """argparse type: an integer >= low, or an error naming the parameter."""
    def conv(text):
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be an integer >= {low}, got {text!r}") from None
        if v < low:
            raise argparse.ArgumentTypeError(f"{name} must be an integer >= {low}, got {text!r}")
        return v

    return conv


def even_n(text):
    """argparse type: the CLF power factor, an even integer >= 2."""
    try:
        return check_even_n(int(text), "--n")
    except ValueError:  # int() of a non-number, or check_even_n's own message
        raise argparse.ArgumentTypeError(f"--n must be an even integer >= 2 (2, 4, 6, ...), got {text!r}") from None


def parse_limit(text: str) -> float:
    """'none' (returned as inf: unlimited) or a positive current [mA]."""
    if text.lower() == NONE:
        return math.inf
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not math.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError(f"--current-limit must be 'none' or a finite number > 0 (mA), got {text!r}")
    return v


def parse_friction(text: str) -> tuple[float, float, float] | None:
    """AMP:START:END -> (amplitude [N*m], start [s], end [s]); 'none' -> None (no friction)."""
    if text.strip().lower() == NONE:
        return None
    parts = text.split(":")
    try:
        if len(parts) != 3:
            raise ValueError
        a, t0, t1 = (float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--friction must be AMP:START:END with numbers (e.g. 1.8:8:10), got {text!r}") from None
    if not all(math.isfinite(v) for v in (a, t0, t1)) or a < 0 or t0 < 0 or t1 <= t0:
        raise argparse.ArgumentTypeError(
            f"--friction needs AMP >= 0, START >= 0 and END > START (finite), got {text!r}")
    return a, t0, t1


class FrictionAction(argparse.Action):
    """``--friction``: events AMP:START:END, or ``none`` alone (no friction); stored as a tuple of events."""

    def __call__(self, parser, namespace, values, option_string=None):
        if any(v is None for v in values):
            if len(values) > 1:
                parser.error(f"argument {option_string}: --friction none cannot be combined with events")
            values = []
        setattr(namespace, self.dest, tuple(values))


NOISE_MAX = (1e-5, 1e-4, 2e3, 1e-10)  # the randomised scenarios' largest sensor-noise std (x1..x4): --noise 1


def parse_noise(text: str) -> tuple[float, float, float, float]:
    """'none', K (times the randomised scenarios' largest noise) or four stds X1,X2,X3,X4."""
    if text.strip().lower() == NONE:
        return (0.0, 0.0, 0.0, 0.0)
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) not in (1, 4) or not all(math.isfinite(v) and v >= 0 for v in vals):
        raise argparse.ArgumentTypeError(f"--noise must be 'none', one factor K >= 0 or four stds X1,X2,X3,X4 >= 0 "
                                         f"[rad, rad/s, Pa, m^2], got {text!r}")
    return tuple(vals[0] * m for m in NOISE_MAX) if len(vals) == 1 else tuple(vals)


def parse_mismatch(text: str) -> dict:
    """NAME=FACTOR,... (plant parameters scaled by positive factors)."""
    out = {}
    for part in text.split(","):
        name, _, val = part.partition("=")
        name = name.strip()
        try:
            f = float(val)
        except ValueError:
            f = float("nan")
        if name not in PlantParams._fields or not (math.isfinite(f) and f > 0):
            raise argparse.ArgumentTypeError(f"--mismatch must be NAME=FACTOR,... with NAME one of "
                                             f"{', '.join(PlantParams._fields)} and FACTOR > 0, got {text!r}")
        out[name] = f
    return out


def plant_file(text: str):
    """argparse type: a plant file (TOML) or a shipped plant's name, read and checked (the error names the file, the
    key, its unit and range)."""
    try:
        return as_rig(text)
    except PlantFileError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def law_settings_file(text: str):
    """argparse type: a law-settings file (``ehss baselines`` writes law_settings.json), read and checked."""
    try:
        return as_law_table(text)
    except LawSettingsError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def floats(name: str):
    """argparse type: comma-separated finite numbers."""
    def conv(text):
        try:
            vals = tuple(float(v) for v in text.split(","))
        except ValueError:
            vals = ()
        if not vals or not all(math.isfinite(v) for v in vals):
            raise argparse.ArgumentTypeError(f"{name} must be comma-separated finite numbers, got {text!r}")
        return vals

    return conv


def sweep(text: str) -> tuple[float, float]:
    """argparse type: a chirp's sweep interval START:END [s]."""
    try:
        a, b = (float(v) for v in text.split(":"))
    except ValueError:
        a = b = float("nan")
    if not (math.isfinite(a) and math.isfinite(b) and 0 <= a < b):
        raise argparse.ArgumentTypeError(f"--sweep must be START:END [s] with 0 <= START < END, got {text!r}")
    return a, b


def task_list(text: str) -> tuple:
    """argparse type: a comma-separated subset of the tasks."""
    got = tuple(t.strip() for t in text.split(",") if t.strip())
    if not got or any(t not in TASKS for t in got):
        raise argparse.ArgumentTypeError(f"--task must be a comma-separated subset of {','.join(TASKS)}, got {text!r}")
    return got


def only(known: tuple):
    """argparse type: a comma-separated subset of ``known``."""
    def conv(text: str) -> list[str]:
        got = [s.strip() for s in text.split(",") if s.strip()]
        if not got or any(n not in known for n in got):
            raise argparse.ArgumentTypeError(f"--only must be a comma-separated subset of {','.join(known)}, "
                                             f"got {text!r}")
        return got

    return conv


# --- option groups shared by several commands -------------------------------------------------------------


def add_out(p, what: str, shipped: str | None = None) -> None:
    """``--out``: the output folder; a ``--quick`` run writes under runs/quick unless told otherwise."""
    where = f"default {shipped}; with --quick runs/quick/{os.path.basename(shipped)}, so a quick run never " \
            "overwrites the shipped one" if shipped else None
    p.add_argument("--out", default=None, help=f"{what} ({where})" if where else what)


def add_quick(p, what: str) -> None:
    p.add_argument("--quick", action="store_true", help=what)


def add_progress(p) -> None:
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar (shown by default)")


def add_workers(p, what: str = "parallel jobs: worker processes on this machine, or the CPUs of a local Ray "
                              "instance (default: the usable cores)") -> None:
    p.add_argument("--workers", type=int_at_least("--workers", 1), default=None, help=what)


def add_backend_arguments(p) -> None:
    """``--backend``, ``--address``, ``--store`` and ``--no-store`` (the execution layer, docs/RAY.md)."""
    g = p.add_argument_group("execution (docs/RAY.md)")
    # the choices shown, checked by the execution layer (its message names them and how to install Ray)
    g.add_argument("--backend", default="local", metavar="{" + ",".join(BACKENDS) + "}",
                   help="where the jobs run: local (this machine, no Ray needed) or ray (a Ray cluster: --address, "
                        "else RAY_ADDRESS, else a local Ray instance; needs " + RAY_INSTALL + ")")
    g.add_argument("--address", default=None, metavar="HOST:PORT",
                   help="the Ray cluster to join (with --backend ray; default RAY_ADDRESS)")
    g.add_argument("--store", default=None, metavar="DIR",
                   help=f"where each job's result is kept under its content address, so a rerun (or a restart "
                        f"after an interruption) computes only the missing jobs (default {DEFAULT_STORE})")
    g.add_argument("--no-store", action="store_true", help="keep no job results: compute every job afresh")


def add_plant(p, what: str = "the rig", law_settings: bool = True) -> None:
    """``--plant``: a plant file (docs: "Your own servo"); default Table I. With ``law_settings``, also
    ``--law-settings``: the CLF law's settings tuned for it."""
    p.add_argument("--plant", type=plant_file, default=None, metavar="FILE",
                   help=f"{what}: a TOML plant file (a [plant] table of the model's parameters or a [datasheet] "
                        f"table; see 'Your own servo' in the docs) or a shipped plant "
                        f"({', '.join(shipped_plants())}); default Table I")
    if law_settings:
        p.add_argument("--law-settings", type=law_settings_file, default=None, metavar="JSON",
                       help="the scripted laws' settings tuned for the plant: the law_settings.json of `ehss "
                            "baselines --plant FILE` (per n the CLF law's sigma, f_r, smoothing, layer gain; "
                            "dob-n2's observer; the PID's gains); default: the built-in ones, tuned for Table I")


# --- ehss simulate: the loop settings, one flag each ---------------------------------------------------------

PRESETS = ("recommended", "paper")
# The loop settings whose flags need more than their type: the value 'none', choices, an even integer.
LOOP_TYPES = {
    "n": even_n,
    **{k: finite("--" + k.replace("_", "-"), 0.0) for k in ("fr", "sigma", "control_period", "ref_model_hz",
                                                           "estimator_hz", "observer_hz", "omega_max",
                                                           "pressure_bound")},
    "current_limit": parse_limit,
    "substeps": int_at_least("--substeps", 1),
    "smoothing": finite("--smoothing", 0.0, low_open=False),
    "layer_gain": finite("--layer-gain", 0.0, low_open=False),
    "ref_accel": finite("--ref-accel", 0.0, low_open=False),
    "dob_hz": finite("--dob-hz", 0.0, low_open=False),
    "pressure_domain": or_none("--pressure-domain", finite("--pressure-domain", 0.0)),
    "lyapunov_kappa": or_none("--lyapunov-kappa", finite("--lyapunov-kappa", 0.0, low_open=False)),
    **{k: finite("--" + k.replace("_", "-"), 0.0, low_open=False) for k in ("reference_delay", "inverse_threshold",
                                                                         "inverse_hysteresis")},
    "lost_track": or_none("--lost-track", finite("--lost-track", 0.0)),
}
LOOP_CHOICES = {"estimator": ESTIMATORS, "law": LAWS}


def _loop_flag(g, name: str, field: dataclasses.Field, doc: str) -> None:
    """One loop setting's flag, from the Scenario field: its type, its choices (from their table) and its doc."""
    flag = "--" + name.replace("_", "-")
    summary = doc.split(" See docs/")[0].replace("``", "").replace("None", NONE).rstrip(".")
    summary += " (default: the preset's)"
    base = typing.get_type_hints(Scenario)[name]
    base = next((a for a in typing.get_args(base) if a is not type(None)), base)
    if name in LOOP_CHOICES:
        g.add_argument(flag, choices=names(LOOP_CHOICES[name]), default=None,
                       help=f"{choices_help(LOOP_CHOICES[name])}")
    elif base is bool:
        g.add_argument(flag, action=argparse.BooleanOptionalAction, default=None, help=summary)
    else:
        # a setting without its own type gets its base type's; the Scenario checks its range
        conv = LOOP_TYPES.get(name) or {int: int, str: str}.get(base, finite(flag))
        g.add_argument(flag, type=conv, default=None, help=summary)


def add_loop_arguments(p: argparse.ArgumentParser, *, t_end: float = 20.0) -> None:
    """The controller's settings (a preset, and every loop setting on its own, overriding it) and the episode."""
    g = p.add_argument_group("loop (each setting not given comes from --preset)")
    g.add_argument("--preset", choices=PRESETS, default="recommended",
                   help="recommended: the env's defaults for the task (the table in docs/ENV.md; tracks); paper: the "
                        "law as printed "
                        "(sigma 1, no limit, f_r 100 Hz, h = 100 us, 10 substeps; diverges within a millisecond)")
    g.add_argument("--task", choices=tuple(TASKS), default="velocity", help="the output tracked")
    docs = field_docs(Scenario)
    for f in dataclasses.fields(Scenario):
        if f.name in LOOP_SETTINGS and f.name != "task":
            _loop_flag(g, f.name, f, docs.get(f.name, ""))
    e = p.add_argument_group("episode")
    e.add_argument("--t-end", type=finite("--t-end", 0.0), default=t_end, help="duration [s]")
    e.add_argument("--friction", type=parse_friction, nargs="*", default=None, metavar="AMP:START:END",
                   action=FrictionAction,
                   help="friction events [N*m:s:s]; default: the paper's 1.8:8:10 with the sine reference (the "
                        "paper's run), none for step, chirp and multisine (a step's settling time and a Bode plot "
                        "would be the friction's); give none to disable, or events to add them to any reference")
    e.add_argument("--noise", type=parse_noise, default=None, metavar="K | X1,X2,X3,X4",
                   help="sensor noise std: K times the randomised scenarios' largest (1e-5 rad, 1e-4 rad/s, 2e3 Pa, "
                        "1e-10 m^2), or the four stds [rad, rad/s, Pa, m^2]; default none")
    e.add_argument("--mismatch", type=parse_mismatch, default=None, metavar="NAME=FACTOR,...",
                   help="true plant parameters scaled, the controller keeping Table I (e.g. beta=0.8,J=1.2)")
    e.add_argument("--seed", type=int_at_least("--seed", 0), default=0, help="sensor-noise seed")
    add_reference_arguments(p)


def add_reference_arguments(p: argparse.ArgumentParser) -> None:
    """``--reference`` and its parameters (output unit U: rad/s velocity, rad position)."""
    r = p.add_argument_group("reference r(t) (default: the paper's 1 U, 2 rad/s sine)")
    r.add_argument("--reference", choices=FAMILIES, default="sine", help="the reference family")
    r.add_argument("--amplitude", type=finite("--amplitude"), default=1.0, help="[U] (sine, step, chirp)")
    r.add_argument("--omega", type=finite("--omega", 0.0, low_open=False), default=2.0, help="sine [rad/s]")
    r.add_argument("--phase", type=finite("--phase"), default=0.0, help="sine, chirp [rad]")
    r.add_argument("--offset", type=finite("--offset"), default=0.0, help="[U]")
    r.add_argument("--t-step", type=finite("--t-step", 0.0, low_open=False), default=0.5, help="step time [s]")
    r.add_argument("--omega-start", type=finite("--omega-start", 0.0, low_open=False), default=1.0,
                   help="chirp start frequency [rad/s]")
    r.add_argument("--omega-end", type=finite("--omega-end", 0.0, low_open=False), default=200.0,
                   help="chirp end frequency [rad/s]")
    r.add_argument("--sweep", type=sweep, default=None, metavar="START:END",
                   help="chirp sweep interval [s] (default the whole run)")
    r.add_argument("--amplitudes", type=floats("--amplitudes"), default=(0.5, 0.3, 0.2), help="multisine [U]")
    r.add_argument("--omegas", type=floats("--omegas"), default=(2.0, 15.0, 60.0), help="multisine [rad/s]")
    r.add_argument("--phases", type=floats("--phases"), default=None, help="multisine [rad] (default 0)")


SIMULATE_EPILOG = """exit codes: 0 the run tracked; 2 bad arguments; 3 the run diverged (non-finite value or a
state bound: |x2| > omega_max, |x3| > 1.5 P_s); 4 it lost track without diverging (windowed RMS
error above the reference's amplitude). The PNG, NPZ and CSV are written in every case.

examples:
  ehss simulate --out runs/default                      # the recommended loop on the paper's run: tracks
  ehss simulate --preset paper --t-end 0.05 --out runs/paper   # the printed law: diverges (exit 3)
  ehss simulate --reference step --amplitude 0.5 --t-end 2 --out runs/step   # no friction unless --friction
  ehss simulate --reference chirp --omega-end 300 --t-end 20 --friction none --bode --out runs/chirp"""


def add_simulate(p) -> None:
    add_plant(p, "the rig simulated (the controller's model is its file's; its rated current the recommended "
                 "preset's current limit)")
    add_loop_arguments(p)
    p.add_argument("--bode", action="store_true",
                   help="also estimate the closed loop's r -> y frequency response (needs --reference chirp or "
                        "multisine): PATH_bode.png and PATH_bode.csv")
    p.add_argument("--out", required=True, help="output path prefix (PATH.png, PATH.npz, PATH.csv)")


# --- the study and report commands ------------------------------------------------------------------------


def add_plant_command(p) -> None:  # ehss plant FILE
    p.add_argument("file", type=plant_file, metavar="FILE",
                   help=f"a TOML plant file or a shipped plant ({', '.join(shipped_plants())})")


def add_reproduce(p) -> None:
    p.add_argument("--plant", default=None, metavar="FILE",
                   help="not taken: the reproduction study is the paper's, on its rig (Table I); on your plant, `ehss "
                        "evaluate --plant FILE` runs the paper's scenario among its suites and compares n = 2/4/6 "
                        "(docs: 'Your own servo')")
    add_out(p, "output folder", os.path.join("reports", "paper"))
    add_quick(p, "tiny grids and durations (CI smoke run; numbers not meaningful)")
    add_progress(p)
    add_backend_arguments(p)


def add_noise(p) -> None:
    add_out(p, "output folder", os.path.join("reports", "noise"))
    add_quick(p, "tiny grids and durations (CI smoke run; numbers not meaningful)")
    add_progress(p)
    add_backend_arguments(p)


def add_fidelity(p) -> None:
    add_out(p, "report folder", os.path.join("reports", "fidelity"))
    p.add_argument("--docs", default=None,
                   help="markdown file whose fidelity-table block gets the main table (default docs/MODEL.md, "
                        "with --quick none; 'none' leaves docs alone)")
    add_quick(p, "closed loop at 30 and 10 us for 2 s only (a smoke test; seconds)")
    add_progress(p)


def add_bench(p) -> None:
    add_out(p, "output folder for PERF.md and the CSV files", os.path.join("reports", "perf"))
    add_quick(p, "shrunken problems (CI, well under a minute); checks the benchmarks run, asserts no speed")
    known = ("sim", "env", "train", "memory", "compile")
    p.add_argument("--only", default=None, type=only(known),
                   help=f"comma-separated subset of {','.join(known)} (default: all)")


def add_warmup(p) -> None:
    p.add_argument("--part", choices=("sim", "env"), default=None,
                   help="only the simulator's kernels (simulate, reproduce, the step bounds) or only the env's "
                        "(env, evaluate, train) (default: both)")
    add_progress(p)


def add_evaluate(p) -> None:
    quick = EvalConfig.quick()
    full = EvalConfig()
    p.add_argument("--policies", nargs="+", default=None, metavar="SPEC",
                   help="comma- or space-separated: clf-n2, clf-n4, clf-n6, the CLF variants <law>-n<k> and "
                        "<law>-<estimator>-n<k>, dob-n<k> (the CLF law with the disturbance observer), pid, "
                        "residual-ppo:PATH, ppo-direct:PATH, sb3:PATH (any SB3 algorithm, its mode from the env spec "
                        "saved with it; PATH may be an rl-zoo3 run folder), or a shipped model name; LABEL=SPEC "
                        "names one in the report (e.g. final=residual-ppo:RUN/final/policy "
                        "best=residual-ppo:RUN/best/policy) (default: every shipped policy)")
    add_plant(p, "the rig every suite runs on (the scripted laws act on it; without --policies only they are "
                 "evaluated, the shipped learned policies being Table I's)")
    p.add_argument("--suite", choices=(*SUITES, "all"), default="all", help="which suites to run")
    p.add_argument("--task", type=task_list, default=tuple(TASKS),
                   help=f"comma-separated subset of {','.join(TASKS)} (default: both)")
    add_deprecated(p, "--tasks", "--task")
    p.add_argument("--episodes", type=int_at_least("--episodes", 1), default=None,
                   help=f"held-out episodes per task (default {full.heldout_episodes}; --quick "
                        f"{quick.heldout_episodes})")
    p.add_argument("--sweep-episodes", type=int_at_least("--sweep-episodes", 1), default=None,
                   help=f"episodes per robustness level (default {full.sweep_episodes}; --quick "
                        f"{quick.sweep_episodes})")
    add_workers(p)
    p.add_argument("--n-boot", type=int_at_least("--n-boot", 100), default=None,
                   help=f"bootstrap replicates (default {full.n_boot}; --quick {quick.n_boot})")
    p.add_argument("--seed", type=int_at_least("--seed", 0), default=0, help="bootstrap seed")
    add_out(p, "output folder", os.path.join("reports", "comparison"))
    add_quick(p, f"small CI form: {quick.heldout_episodes} held-out episodes, {len(quick.friction_levels)}+"
                 f"{len(quick.mismatch_levels)} sweep levels of {quick.sweep_episodes} episode, paper run cut at "
                 f"{quick.paper_seconds:g} s, {len(quick.step_amplitudes)} steps")
    add_progress(p)
    add_backend_arguments(p)


def add_factors(p) -> None:
    p.add_argument("--episodes", type=int_at_least("--episodes", 1), default=None,
                   help="held-out (and unmodelled-suite) episodes per task (default 48; --quick 6; --learned 16, "
                        "--learned --quick 2)")
    p.add_argument("--task", type=task_list, default=tuple(TASKS),
                   help=f"comma-separated subset of {','.join(TASKS)} (default: both)")
    p.add_argument("--learned", action="store_true",
                   help="instead of the default law's table: the scripted laws clf-n2, dob-n2, dcomp-n2, vinv-n2, "
                        "eso-n2 and the shipped n = 2 learned groups on the held-out and unmodelled suites, each cause "
                        "removed in turn and the error split by time window; writes LEARNED.md and learned.csv")
    add_workers(p)
    add_out(p, "output folder", os.path.join("reports", "factors"))
    add_quick(p, "6 held-out episodes per task, a 2 s paper run and one level per robustness sweep in the rankings")
    add_progress(p)


def add_headroom(p) -> None:
    add_plant(p, "the rig the suites run on")
    p.add_argument("--episodes", type=int_at_least("--episodes", 1), default=None,
                   help="episodes per task and suite at most; a larger suite is subsampled evenly (default 32; "
                        "--quick 2)")
    p.add_argument("--task", type=task_list, default=tuple(TASKS),
                   help=f"comma-separated subset of {','.join(TASKS)} (default: both)")
    p.add_argument("--n-boot", type=int_at_least("--n-boot", 100), default=None,
                   help="bootstrap replicates (default 2000; --quick 500)")
    p.add_argument("--base", choices=("clf-n2", "dcomp-n2", "vinv-n2", "eso-n2"), default="clf-n2",
                   help="the loop every variant runs on: the env's tuned n = 2 law (default) or a scripted "
                        "compensator's, its row of each task under every variant's own settings, so that the oracles "
                        "measure what is left over that law (the base law's rows keep the label clf-n2)")
    p.add_argument("--causes", nargs="?", const="all", default=None, metavar="CAUSES",
                   help="instead of the headroom table: the unmodelled suite's variants (the base law, dob-n2, "
                        "dcomp-n2, vinv-n2, eso-n2 and the oracles that know the unmodelled effects or search the "
                        "width) with each cause removed in turn, judged by the rule of ehss factors --learned; writes "
                        "CAUSES.md and causes.csv. CAUSES: a comma-separated subset of friction,mismatch,noise,"
                        "valve,delay,quantisation (default: all of them)")
    add_workers(p)
    add_out(p, "output folder", os.path.join("reports", "headroom"))
    add_quick(p, "2 episodes per suite, short suites, agent periods 5 and 20, small searches (CI smoke run; numbers "
                 "not meaningful)")
    add_progress(p)
    add_backend_arguments(p)


def add_baselines(p) -> None:
    add_plant(p, "the rig the training scenarios are drawn around (its tuned settings go to law_settings.json)",
              law_settings=False)
    p.add_argument("--task", type=task_list, default=tuple(TASKS),
                   help=f"comma-separated subset of {','.join(TASKS)}: the tasks whose baselines are tuned "
                        "(default: both)")
    p.add_argument("--budget", type=int_at_least("--budget", 1), default=None,
                   help="evaluations per baseline (default 64; --quick 32)")
    p.add_argument("--episodes", type=int_at_least("--episodes", 1), default=None,
                   help="training scenarios, seeds 0..EPISODES-1 (default 48; --quick 12)")
    p.add_argument("--seconds", type=finite("--seconds", 0.0), default=None,
                   help="episode duration [s] (default 2)")
    p.add_argument("--check-episodes", type=int_at_least("--check-episodes", 0), default=None,
                   help="held-out episodes of the check of the tuned n = 2 law after the search (saturation, limit "
                        "cycles through the friction events; default 48; 0: no check)")
    p.add_argument("--compensator-episodes", type=int_at_least("--compensator-episodes", 0), default=None,
                   help="training scenarios with the unmodelled effects on which the compensators (dcomp-n2, "
                        "vinv-n2, eso-n2) are sized, seeds 0..N-1 (default 48, --quick too: fewer let noise pick a "
                        "size; 0: not sized)")
    add_out(p, "output folder", os.path.join("reports", "baselines"))
    add_quick(p, "12 training episodes of 2 s and 32 evaluations per baseline: a few minutes on two cores, "
                 "coarser than the full run")
    add_progress(p)


def add_train(p) -> None:
    add_train_config(p, launch=True)
    add_deprecated(p, "--jobs", "--workers")


def add_training_report(p) -> None:
    out = os.path.join("reports", "training")
    p.add_argument("--runs", nargs="+", default=[os.path.join("runs", "final")], metavar="FOLDER",
                   help="folders of run folders")
    p.add_argument("--out", default=out, help="output folder")
    p.add_argument("--episodes", type=int_at_least("--episodes", 1), default=48,
                   help="episodes per suite (held-out, unmodelled) and task")
    p.add_argument("--exploration", default=os.path.join(out, "exploration_noise.json"), metavar="JSON",
                   help="the initial-exploration-noise study's JSON (python -m ehss_gym.study.exploration); left out "
                        "if missing")
    add_deprecated(p, "--noise", "--exploration")
    p.add_argument("--ship", default=None, metavar="FOLDER",
                   help="ship every group's kept policies here as safe weights (e.g. ehss_gym/models), and "
                        "delete the models there that this shipment does not write")
    p.add_argument("--archive", default=None, metavar="FOLDER",
                   help="keep every run's records here (config, summary, validation history and kept model, about "
                        "45 kB per run; e.g. reports/training/runs), so that --runs FOLDER regenerates the report "
                        "once the run folders are gone")
    add_workers(p, "evaluation processes")
    p.set_defaults(workers=2)
    add_progress(p)


def add_ablation(p) -> None:
    p.add_argument("--runs", default=os.path.join("runs", "ablation"), metavar="FOLDER",
                   help="the cells' run folders' parent (a finished cell is not trained again)")
    p.add_argument("--out", default=os.path.join("reports", "training", "ablation"), help="output folder")
    p.add_argument("--timesteps", type=int_at_least("--timesteps", 1), default=300_000,
                   help="agent steps per cell (default 300000)")
    p.add_argument("--report-only", action="store_true",
                   help="train nothing: report the cells that have finished")
    add_workers(p, "cells trained at a time, one process each (default 2)")
    p.set_defaults(workers=2)
    add_progress(p)


def add_tune(p) -> None:
    p.add_argument("--task", choices=tuple(TASKS), default="velocity", help="the agent's task")
    p.add_argument("--n", type=even_n, default=2, help="power factor of the base law (even)")
    p.add_argument("--trials", type=int_at_least("--trials", 1), default=16, help="configurations tried")
    p.add_argument("--timesteps", type=int_at_least("--timesteps", 1), default=100_000,
                   help="agent steps of a trial ASHA does not stop (the best config's budget)")
    p.add_argument("--eval-freq", type=int_at_least("--eval-freq", 1), default=25_000,
                   help="agent steps between validation evaluations (ASHA's rungs)")
    p.add_argument("--grace", type=int_at_least("--grace", 1), default=None,
                   help="agent steps before ASHA may stop a trial (default --eval-freq)")
    p.add_argument("--eval-episodes", type=int_at_least("--eval-episodes", 1), default=8,
                   help="validation episodes per evaluation")
    p.add_argument("--eval-seconds", type=finite("--eval-seconds", 0.0), default=2.0,
                   help="validation episode duration [s]")
    p.add_argument("--n-envs", type=int_at_least("--n-envs", 1), default=None,
                   help="parallel envs per trial (default: the agent's)")
    p.add_argument("--seed", type=int_at_least("--seed", 0), default=0, help="training and sampler seed")
    p.add_argument("--concurrent", type=int_at_least("--concurrent", 1), default=2, help="trials at a time")
    p.add_argument("--compare-seeds", type=int_at_least("--compare-seeds", 0), default=0,
                   help="fresh seeds training the best config and the shipped recipe for the report's comparison")
    p.add_argument("--hp", action="append", default=None, metavar="KEY=JSON",
                   help="a hyperparameter every trial keeps (not searched), as for ehss train; repeatable")
    add_workers(p, "CPUs of a local Ray instance (default: the usable cores; a cluster's own decide there)")
    add_deprecated(p, "--cpus", "--workers")
    p.add_argument("--address", default=None, metavar="HOST:PORT", help="the Ray cluster (default RAY_ADDRESS)")
    p.add_argument("--out", default=os.path.join("runs", "tune"),
                   help="the search's folder: Tune's state, trial runs, trials.json, best_config.json")
    p.add_argument("--report", default=None, help="folder of TUNE.md, trials.csv, compare.csv (default --out)")


@dataclasses.dataclass(frozen=True)
class Command:
    """A sub-command: its name, one-line help, description, options and the module of ``ehss_gym.cli`` that runs it
    (its ``run(args)``, imported only when the command runs)."""

    name: str
    help: str
    description: str
    add_options: typing.Callable
    module: str
    epilog: str | None = None


COMMANDS = (
    Command("simulate", "simulate one closed-loop run and write PNG, NPZ, CSV and a summary",
            "One closed-loop run of the EHSS loop. With no settings: the env's recommended loop on the paper's 20 s "
            "run (it tracks); --preset paper gives the law as printed (it diverges).", add_simulate, "simulate",
            SIMULATE_EPILOG),
    Command("plant", "read a plant file and print the model's parameters it gives, with their derivation",
            "Read a plant file (a [plant] table of the model's parameters, or a [datasheet] table converted by the "
            "formulas of docs/MODEL.md, 'From a datasheet to the model's parameters') and print every parameter with "
            "its unit and, for a datasheet, the formula it came from; a bad file exits with 2 and names the key, its "
            "unit and range.", add_plant_command, "plant"),
    Command("reproduce", "regenerate the paper's study into a report folder",
            "Regenerate the paper's study: its runs (Figs. 5-13), its claims C1-C7 tested, sweeps of the settings it "
            "leaves out, lost-track checks, smoothing, and the recommended defaults; writes REPORT.md, figures, CSVs.",
            add_reproduce, "reproduce"),
    Command("noise", "the noise study: estimators, laws and start-up levers against sensor noise and the current bound",
            "The noise study: noise level x estimator x law x n for both tasks, start-up levers, and the coded rules "
            "that choose the env's default estimator and law; writes REPORT.md, figures, CSVs, recommended.json.",
            add_noise, "noise"),
    Command("evaluate", "compare CLF n=2/4/6, PID and learned policies on the same scenarios",
            "Measure scripted and learned policies against the reference law (clf-n2) by metric class (tracking, "
            "disturbance, effort, chatter) on the paper scenario, a held-out randomised suite, robustness sweeps, a "
            "step suite and a suite with the valve and sensor effects the law's model leaves out; write REPORT.md, "
            "CSVs and figures.", add_evaluate, "evaluate"),
    Command("factors", "the ruler's factor table: each metric class with friction, mismatch and noise removed",
            "The default law on the held-out suite with friction, model mismatch and sensor noise removed one at a "
            "time and all together: each metric class's level; writes FACTORS.md and factors.csv.", add_factors,
            "factors"),
    Command("baselines", "tune every scripted baseline (CLF n=2/4/6, observer, PID, compensators) on training "
            "scenarios",
            "One deterministic coordinate search on log grids (then halving refinement), the same budget for every "
            "baseline, on training scenarios only; the objective is the ruler's overall figure against the env's "
            "default law before tuning, with the failure gate. Applies the written defaults rule (which n is each "
            "task's default), then sizes the compensators of the unmodelled valve and sensors (dcomp-n2, "
            "vinv-n2, eso-n2) on the tuned n = 2 law over their whole grid. Writes tuned.json, law_settings.json, "
            "BASELINES.md and convergence figures.", add_baselines,
            "baselines"),
    Command("headroom", "the headroom table: what a residual on the n=2 law could gain, and what it must observe",
            "For each task, suite of ehss evaluate and metric class: the base law, the disturbance-observer residual "
            "and oracles (the true plant as the model, friction feed-forward knowing the events, the per-episode best "
            "constant current and boundary-layer width) at agent periods 1, 5 and 20, with 95 % CIs, and the rule "
            "that reads headroom off them; writes HEADROOM.md, headroom.csv and headroom.png.", add_headroom,
            "headroom"),
    Command("train", "train residual PPO, pure PPO or residual SAC (checkpoints, resume, held-out evaluation)",
            "Train residual PPO (or pure PPO, or residual SAC for comparison) on EHSSTracking-v0: one seed, or "
            "several (--seeds) in parallel processes or on Ray.", add_train, "train"),
    Command("training-report", "evaluate finished training runs and write reports/training",
            "Learning curves, per-seed figures, the held-out and unmodelled suites beside the scripted policies and "
            "the targets of the runs that ehss train wrote; optionally ship their policies (retiring the models "
            "this shipment does not write).", add_training_report, "training_report"),
    Command("ablation", "the residual recipe's ablation: reward x action, then exploration x base law, on one seed",
            "Train residual PPO on the position task with the unmodelled effects, one seed per cell: reward (class, "
            "physical) x action (current, reference, schedule, reference-schedule), then on stage 1's two best "
            "cells exploration (gsde, pink), the base law with its reference delayed (dcomp) and the mixture "
            "training distribution (half the episodes with the effects), then the leader of both on the "
            "distribution it was not trained on; rank the cells by the rule written in "
            "ehss_gym.study.ablation (final policies on validation episodes with and without the effects) and "
            "write ABLATION.md, its validation curves and CSV.", add_ablation, "ablation"),
    Command("tune", "hyperparameter search for the residual agent (Ray Tune, Optuna TPE, ASHA)",
            "Search residual PPO's hyperparameters on the held-out validation figure with Ray Tune, Optuna's TPE "
            "sampler and ASHA early stopping; resumable.", add_tune, "tune"),
    Command("bench", "run the performance benchmarks (source checkout) and write PERF.md + CSV",
            "Speed and memory against the tools a user would otherwise pick (solve_ivp, Pendulum-v1, ...); needs "
            "the source checkout's benchmarks/ folder.", add_bench, "bench"),
    Command("fidelity", "the digital filters against the analog ones, open and closed loop",
            "Measure the digital filters (zoh, foh) against the analog ones, open and closed loop, at h = 30, 10, "
            "3 us; writes reports/fidelity and the table in docs/MODEL.md.", add_fidelity, "fidelity"),
    Command("warmup", "compile the simulator's kernels into numba's cache now (a Docker image, a Ray node)",
            "Compile numba's kernels into its cache (NUMBA_CACHE_DIR, else beside the package's sources) by running "
            "what the commands run, tiny, so that the first real run loads them instead of compiling them for tens "
            "of CPU-seconds; prints the CPU time it took. With a warm cache it only loads them.", add_warmup,
            "warmup"),
)


def build_parser(version: str) -> argparse.ArgumentParser:
    """The ``ehss`` parser with every sub-command (each sets ``args.command`` and ``args.module``)."""
    parser = argparse.ArgumentParser(prog="ehss", description="EHSS servo loop with Sontag/CLF controllers.",
                                     formatter_class=HelpFormatter)
    parser.add_argument("--version", action="version", version=f"ehss-gym {version}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for c in COMMANDS:
        p = sub.add_parser(c.name, help=c.help, description=c.description, epilog=c.epilog,
                           formatter_class=HelpFormatter)
        c.add_options(p)
        p.set_defaults(module=c.module)
    return parser


__all__ = ["COMMANDS", "Command", "build_parser", "HelpFormatter", "add_deprecated", "add_backend_arguments",
           "add_loop_arguments", "int_at_least", "finite", "NONE"]
