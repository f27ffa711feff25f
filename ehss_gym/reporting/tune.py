"""``ehss tune``'s report: the search's trials, its best config, and that config against the shipped recipe on
the held-out validation figure (``TUNE.md``, ``trials.csv``, ``compare.csv`` next to ``best_config.json``)."""

from __future__ import annotations

import csv
import io
import math
import os
import statistics

from ehss_gym._version import __version__
from ehss_gym.infra.util import atomic_write_text


def _csv(rows: list[dict]) -> str:
    buf = io.StringIO()
    if rows:
        w = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    return buf.getvalue()


def _fmt(v) -> str:
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.4g}"
    return str(v)


def _table(rows: list[dict], keys: list[str]) -> list[str]:
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(_fmt(r.get(k)) for k in keys) + " |" for r in rows]
    return lines


def summary_lines(compare: list[dict]) -> list[str]:
    """Mean (min..max) kept-policy validation figure per recipe; lower is better, the base law scores 1."""
    lines = []
    for recipe in ("tuned", "shipped"):
        vals = [r["validation_figure"] for r in compare if r["recipe"] == recipe]
        if vals:
            lines.append(f"- {recipe}: mean validation figure {statistics.fmean(vals):.4f} "
                         f"(min {min(vals):.4f}, max {max(vals):.4f}) over {len(vals)} seed(s)")
    return lines


def write_report(result: dict, settings, out: str, command: str, wall_s: float) -> str:
    """Write TUNE.md, trials.csv and compare.csv into ``out``; returns TUNE.md's path.

    Args:
        result: what :func:`ehss_gym.train.tune.run_search` returned.
        settings: its :class:`~ehss_gym.train.tune.TuneSettings`.
        out: the report folder.
        command: the command line that made it (each table names it).
        wall_s: the command's wall time [s].
    """
    trials, best, compare = result["trials"], result["best_config"], result["compare"]
    hp_keys = [k for k in trials[0] if k not in ("trial", "status", "steps", "best_objective", "figure", "train_s")]
    made = f"Made by `{command}` (ehss-gym {__version__}); do not edit: rerun the command."
    lines = ["# Hyperparameter search for the residual agent", "", made, "",
             f"Ray Tune with Optuna's TPE sampler (seed {settings.seed}) and ASHA (reduction factor 3, grace "
             f"{settings.grace} steps, rungs on the validation evaluations every {settings.eval_freq} steps): "
             f"{settings.trials} trials of residual PPO on the {settings.task} task (n = {settings.n}), at most "
             f"{settings.timesteps} agent steps each, {settings.concurrent} at a time. Metric: the best held-out "
             f"validation so far ({settings.eval_episodes} validation scenarios of {settings.eval_seconds:g} s): the "
             "overall figure G against the n = 2 law (lower is better, the base law scores 1; inf for a failed "
             "gate: divergence, lost track or saturation above 10 %), the policy "
             f"a run keeps. Wall time of this command: {wall_s:.0f} s (a rerun restores the finished search and takes "
             f"the comparison from its store; the trials' own times are the train_s column: "
             f"{sum(t['train_s'] for t in trials if math.isfinite(t['train_s'])):.0f} s in all).", "",
             "## Trials (best first)", "", made, "", *_table(trials, ["trial", "status", "steps", "best_objective",
                                                                      "figure", "train_s", *hp_keys]), "",
             "## Best config", "", "`best_config.json` (train it with `ehss train --config best_config.json "
             "--seed S`):", "", *_table([{**best["hp"]}], list(best["hp"])), "",
             "The shipped recipe's values:", "", *_table([result["shipped"]], list(result["shipped"])), ""]
    if compare:
        lines += ["## Tuned config against the shipped recipe", "", made, "",
                  f"Both trained at the search's budget ({settings.timesteps} steps) on fresh seeds (not the "
                  "search's), scored on the held-out validation block (the kept policy: the run's best "
                  "evaluation). The search chose its config on this same validation block, so the comparison "
                  "favours it; the held-out test block of `ehss evaluate` is the unbiased check.", "",
                  *_table(compare, ["recipe", "seed", "steps", "best_step", "validation_figure", "final_figure",
                                    "wall_s"]), "", *summary_lines(compare), ""]
    os.makedirs(out, exist_ok=True)
    atomic_write_text(os.path.join(out, "trials.csv"), _csv(trials))
    if compare:
        atomic_write_text(os.path.join(out, "compare.csv"), _csv(compare))
    path = os.path.join(out, "TUNE.md")
    atomic_write_text(path, "\n".join(lines))
    return path


__all__ = ["summary_lines", "write_report"]
