"""argparse types and shared arguments: bad values exit with code 2 and a message naming the parameter and its range."""

from __future__ import annotations

import argparse
import math

from ehss_gym.core.params import PlantParams
from ehss_gym.core.registry import ESTIMATORS, names
from ehss_gym.core.settings import PAPER_FRICTION, Scenario
from ehss_gym.core.signals import FAMILIES, chirp, multisine, sine, step
from ehss_gym.core.validate import check_even_n
from ehss_gym.envs.config import EnvConfig


def parse_friction(text: str) -> tuple[float, float, float] | None:
    """AMP:START:END -> (amplitude [N*m], start [s], end [s]); 'none' -> None (no friction)."""
    if text.strip().lower() == "none":
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


def parse_limit(text: str) -> float:
    """'none' (returned as inf: unlimited) or a positive current [mA]."""
    if text.lower() == "none":
        return math.inf
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not math.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError(f"--current-limit must be 'none' or a finite number > 0 (mA), got {text!r}")
    return v


def _finite(name, low=None, low_open=True):
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


def int_at_least(name, low):
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


def _even_n(text):
    try:
        return check_even_n(int(text), "--n")
    except ValueError:  # int() of a non-number, or check_even_n's own message
        raise argparse.ArgumentTypeError(f"--n must be an even integer >= 2 (2, 4, 6, ...), got {text!r}") from None


PRESETS = ("recommended", "paper")
LOOP_FIELDS = ("n", "fr", "sigma", "smoothing", "control_period", "substeps", "current_limit", "estimator",
               "estimator_hz", "ref_model_hz")
NOISE_MAX = (1e-5, 1e-4, 2e3, 1e-10)  # the randomised scenarios' largest sensor-noise std (x1..x4): --noise 1


def add_loop_arguments(p: argparse.ArgumentParser, *, t_end: float = 20.0):
    """The controller's settings: a preset, and each setting on its own (overriding the preset)."""
    g = p.add_argument_group("loop (each unset value comes from --preset)")
    g.add_argument("--preset", choices=PRESETS, default="recommended",
                   help="recommended (default): the env's defaults (the reproduction study's recommendation: "
                        "sigma 1e5, 10 mA limit, h = 50 us, smoothing; tracks); paper: the law as printed (sigma "
                        "1, no limit, f_r 100 Hz, h = 100 us, 10 substeps; diverges within a millisecond)")
    g.add_argument("--task", choices=("velocity", "position"), default="velocity")
    g.add_argument("--n", type=_even_n, default=None, help="CLF power factor (even, >= 2)")
    g.add_argument("--fr", type=_finite("--fr", 0.0), default=None, help="combined-error cutoff [Hz]")
    g.add_argument("--sigma", type=_finite("--sigma", 0.0), default=None, help="CLF scale (1 = paper)")
    g.add_argument("--smoothing", type=_finite("--smoothing", 0.0, low_open=False), default=None,
                   help="sign(s) smoothing width (0 = plain law)")
    g.add_argument("--control-period", type=_finite("--control-period", 0.0), default=None, help="[s]")
    g.add_argument("--substeps", type=int_at_least("--substeps", 1), default=None, help="RK4 steps per period")
    g.add_argument("--current-limit", type=parse_limit, default=None, help="[mA] or 'none' (unlimited)")
    g.add_argument("--estimator", choices=names(ESTIMATORS), default=None,
                   help="how the reference model and derivative estimator run: foh (first-order-hold digital "
                        "filters), zoh (wave 1's biased scheme) or analog (continuous filters)")
    g.add_argument("--estimator-hz", type=_finite("--estimator-hz", 0.0), default=None,
                   help="output-derivative estimator cutoff [Hz]")
    g.add_argument("--ref-model-hz", type=_finite("--ref-model-hz", 0.0), default=None,
                   help="reference-model cutoff [Hz] (Table I: 20)")
    e = p.add_argument_group("episode")
    e.add_argument("--t-end", type=_finite("--t-end", 0.0), default=t_end, help="[s]")
    e.add_argument("--friction", type=parse_friction, nargs="*", default=None, metavar="AMP:START:END",
                   action=FrictionAction,
                   help="friction events [N*m:s:s]; default the paper's 1.8:8:10; give none to disable")
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
    r.add_argument("--reference", choices=FAMILIES, default="sine")
    r.add_argument("--amplitude", type=_finite("--amplitude"), default=1.0, help="[U] (sine, step, chirp)")
    r.add_argument("--omega", type=_finite("--omega", 0.0, low_open=False), default=2.0, help="sine [rad/s]")
    r.add_argument("--phase", type=_finite("--phase"), default=0.0, help="sine, chirp [rad]")
    r.add_argument("--offset", type=_finite("--offset"), default=0.0, help="[U]")
    r.add_argument("--t-step", type=_finite("--t-step", 0.0, low_open=False), default=0.5, help="step time [s]")
    r.add_argument("--omega-start", type=_finite("--omega-start", 0.0, low_open=False), default=1.0,
                   help="chirp start frequency [rad/s]")
    r.add_argument("--omega-end", type=_finite("--omega-end", 0.0, low_open=False), default=200.0,
                   help="chirp end frequency [rad/s]")
    r.add_argument("--sweep", type=_sweep, default=None, metavar="START:END",
                   help="chirp sweep interval [s] (default the whole run)")
    r.add_argument("--amplitudes", type=_floats("--amplitudes"), default=(0.5, 0.3, 0.2), help="multisine [U]")
    r.add_argument("--omegas", type=_floats("--omegas"), default=(2.0, 15.0, 60.0), help="multisine [rad/s]")
    r.add_argument("--phases", type=_floats("--phases"), default=None, help="multisine [rad] (default 0)")


def _floats(name):
    def conv(text):
        try:
            vals = tuple(float(v) for v in text.split(","))
        except ValueError:
            vals = ()
        if not vals or not all(math.isfinite(v) for v in vals):
            raise argparse.ArgumentTypeError(f"{name} must be comma-separated finite numbers, got {text!r}")
        return vals

    return conv


def _sweep(text: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in text.split(":"))
    except ValueError:
        a = b = float("nan")
    if not (math.isfinite(a) and math.isfinite(b) and 0 <= a < b):
        raise argparse.ArgumentTypeError(f"--sweep must be START:END [s] with 0 <= START < END, got {text!r}")
    return a, b


def parse_noise(text: str) -> tuple[float, float, float, float]:
    """'none', K (times the randomised scenarios' largest noise) or four stds X1,X2,X3,X4."""
    if text.strip().lower() == "none":
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


def preset_scenario(preset: str, task: str) -> Scenario:
    """The loop of a preset: the env's defaults ("recommended") or the law as printed ("paper")."""
    if preset == "recommended":
        return EnvConfig.from_kwargs({"task": task}).template()
    return Scenario(task=task)


def scenario_from_args(args) -> Scenario:
    """The Scenario of ``ehss simulate``'s arguments: the preset's loop with every given setting on top.

    Raises:
        ValueError: a setting the Scenario refuses (the message names it).
    """
    base = preset_scenario(args.preset, args.task)
    changes = {k: getattr(args, k) for k in LOOP_FIELDS if getattr(args, k) is not None}
    if changes.get("current_limit") == math.inf:
        changes["current_limit"] = None
    plant = PlantParams().scaled(**args.mismatch) if args.mismatch else PlantParams()
    return base.replace(**changes, t_end=args.t_end, reference=_reference(args, args.t_end),
                        friction=PAPER_FRICTION if args.friction is None else tuple(args.friction),
                        noise_std=args.noise or (0.0, 0.0, 0.0, 0.0), seed=args.seed, plant=plant,
                        model=PlantParams() if args.mismatch else None)
