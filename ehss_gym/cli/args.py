"""argparse types and shared arguments: bad values exit with code 2 and a message naming the parameter and its range."""

from __future__ import annotations

import argparse
import math

from ehss_gym.core.layout import ESTIMATORS
from ehss_gym.core.sim import PAPER_FRICTION, Scenario


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


def parse_limit(text: str) -> float | None:
    """'none' or a positive current [mA]."""
    if text.lower() == "none":
        return None
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
        v = int(text)
    except ValueError:
        v = -1
    if v < 2 or v % 2:
        raise argparse.ArgumentTypeError(f"--n must be an even integer >= 2 (2, 4, 6, ...), got {text!r}")
    return v


def add_loop_arguments(p: argparse.ArgumentParser, *, t_end: float = 20.0):
    """Arguments shared by commands that build a Scenario."""
    p.add_argument("--task", choices=("velocity", "position"), default="velocity")
    p.add_argument("--n", type=_even_n, default=2, help="CLF power factor (even, >= 2)")
    p.add_argument("--fr", type=_finite("--fr", 0.0), default=100.0, help="combined-error cutoff [Hz]")
    p.add_argument("--sigma", type=_finite("--sigma", 0.0), default=1.0, help="CLF scale (1 = paper)")
    p.add_argument("--smoothing", type=_finite("--smoothing", 0.0, low_open=False), default=0.0,
                   help="sign(s) smoothing width (0 = plain law)")
    p.add_argument("--control-period", type=_finite("--control-period", 0.0), default=1e-4, help="[s]")
    p.add_argument("--substeps", type=int_at_least("--substeps", 1), default=10, help="RK4 steps per period")
    p.add_argument("--current-limit", type=parse_limit, default=None, help="[mA] or 'none' (default none)")
    p.add_argument("--t-end", type=_finite("--t-end", 0.0), default=t_end, help="[s]")
    p.add_argument("--friction", type=parse_friction, nargs="*", default=None, metavar="AMP:START:END",
                   action=FrictionAction,
                   help="friction events [N*m:s:s]; default the paper's 1.8:8:10; give none to disable")
    p.add_argument("--estimator", choices=ESTIMATORS, default="foh",
                   help="how the reference model and derivative estimator run: foh (default; first-order-hold "
                        "digital filters), zoh (wave 1's biased scheme) or analog (continuous filters)")


def scenario_from_args(args):
    friction = PAPER_FRICTION if args.friction is None else tuple(args.friction)
    return Scenario(task=args.task, n=args.n, fr=args.fr, sigma=args.sigma, smoothing=args.smoothing,
                    control_period=args.control_period, substeps=args.substeps, current_limit=args.current_limit,
                    t_end=args.t_end, friction=friction, estimator=args.estimator)


