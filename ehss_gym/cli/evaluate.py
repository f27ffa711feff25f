"""``ehss evaluate``: the evaluation harness (:mod:`ehss_gym.evaluation`) on the command line, then its report
(:mod:`ehss_gym.reporting.comparison`). Its options: :func:`ehss_gym.cli.options.add_evaluate`."""

from __future__ import annotations

import math
import os
import sys
import time
import warnings
from dataclasses import replace

from ehss_gym.evaluation import SUITES, TASKS, EvalConfig, PolicyWarning, default_specs, evaluate, parse_policies
from ehss_gym.evaluation.specs import SCRIPTED_DEFAULT, scripted_specs
from ehss_gym.infra.execution import Executor
from ehss_gym.reporting.comparison import DEFAULT_OUT, prefetch_bounds, write_report

from .common import backend_from_args, plant_note, plant_out_folder, store_from_args


def _command_line(args) -> str:
    """The command line as the report records it (the real one when run as ``ehss evaluate``)."""
    if sys.argv and os.path.basename(sys.argv[0]) == "ehss" and len(sys.argv) > 1 and sys.argv[1] == "evaluate":
        return "ehss " + " ".join(sys.argv[1:])
    parts = ["ehss evaluate"]
    if args.policies:
        parts.append("--policies " + " ".join(args.policies))
    if args.suite != "all":
        parts.append(f"--suite {args.suite}")
    if tuple(args.task) != TASKS:
        parts.append("--task " + ",".join(args.task))
    if args.plant is not None:
        parts.append(f"--plant {args.plant.source or args.plant.name}")
    if args.law_settings is not None:
        parts.append(f"--law-settings {args.law_settings.source}")
    for flag, v in (("--episodes", args.episodes), ("--sweep-episodes", args.sweep_episodes),
                    ("--workers", args.workers), ("--n-boot", args.n_boot)):
        if v is not None:
            parts.append(f"{flag} {v}")
    if args.seed:
        parts.append(f"--seed {args.seed}")
    if args.out is not None:
        parts.append(f"--out {args.out}")
    if args.quick:
        parts.append("--quick")
    return " ".join(parts)


def config_from_args(args) -> EvalConfig:
    """The evaluation's sizes from the options (``--quick`` first, the explicit sizes on top)."""
    changes = {"suites": SUITES if args.suite == "all" else (args.suite,), "tasks": tuple(args.task),
               "seed": args.seed, "plant": args.plant, "law_settings": args.law_settings}
    for key, v in (("heldout_episodes", args.episodes), ("sweep_episodes", args.sweep_episodes),
                   ("n_boot", args.n_boot)):
        if v is not None:
            changes[key] = v
    return EvalConfig.quick(**changes) if args.quick else replace(EvalConfig(), **changes)


def default_policies(args, cfg) -> list:
    """The policies evaluated without --policies: every shipped one on Table I; the scripted laws on another plant (the
    shipped learned policies were trained on Table I: name them with --policies to see them there)."""
    if args.plant is None:
        return default_specs(cfg.tasks)
    print("ehss evaluate: note: with --plant and no --policies the scripted laws are evaluated ("
          f"{', '.join(SCRIPTED_DEFAULT)}); the shipped learned policies were trained on Table I", file=sys.stderr)
    return scripted_specs(SCRIPTED_DEFAULT, cfg.tasks, cfg.law_settings)


def run(args) -> int:
    """Evaluate, write the report, print the rankings.

    Returns:
        0 on success, 2 for a policy or setting that cannot be evaluated, 1 for a policy that failed while running.
    """
    prog = "ehss evaluate"
    try:
        with warnings.catch_warnings(record=True) as caught:  # printed below as the CLI's own warnings
            warnings.simplefilter("always", PolicyWarning)
            cfg = config_from_args(args)
            plant_note(prog, args.plant, args.law_settings)
            specs = default_policies(args, cfg) if args.policies is None else parse_policies(args.policies)
            for w in caught:
                print(f"{prog}: warning: {w.message}", file=sys.stderr)
            with Executor(backend_from_args(args, args.workers), store_from_args(args),
                          progress=not args.no_progress) as executor:
                res = evaluate(specs, cfg, workers=args.workers, progress=not args.no_progress,
                               command=_command_line(args), executor=executor)
                t0 = time.perf_counter()
                # the step suite's bounds not shipped with the package: computed over the workers, kept in the store
                prefetch_bounds(res, executor, progress=not args.no_progress)
                res.timings["bounds"] = time.perf_counter() - t0
    except ValueError as exc:  # PolicyError, SafeWeightsError, ExecutionError (backend, address), bad settings
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # a policy that misbehaved while running (e.g. a NaN action)
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 1
    print(f"{prog}: {executor.computed} job(s) computed, {executor.skipped} from the store", file=sys.stderr)
    print(cfg.rig.summary() + ("" if cfg.law_settings is None else f"; {cfg.law_settings.describe()}"))
    for note in res.notes:
        print(f"{prog}: note: {note}", file=sys.stderr)
    started = getattr(args, "started", math.nan)
    if math.isfinite(started):  # the command's imports and parsing before the evaluation began
        res.timings = {"start-up": res.started - started, **res.timings}
        res.started = started
    path = write_report(res, plant_out_folder(args.out, args.quick, DEFAULT_OUT, args.plant))
    print(f"{len(res.rows)} episodes in {res.wall_time:.1f} s ({res.workers} workers; "
          + ", ".join(f"{k} {v:.1f} s" for k, v in res.timings.items()) + f"); wrote {path}")
    for suite in SUITES:
        for task in TASKS:
            block = [d for d in res.summary if d["suite"] == suite and d["task"] == task]
            if block:
                ranking = ", ".join(f"{d['policy']} {d['figure']:.3g}" + (" FAILED" if d["failed"] else "")
                                    + (" (earlier loop)" if d["earlier_loop"] else "") for d in block)
                print(f"  {suite}/{task}: {ranking}")
    return 0


__all__ = ["run", "config_from_args"]
