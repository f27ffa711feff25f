"""The training report (``ehss training-report``): ``TRAINING.md`` with its prose in templates/training.md.j2, a
learning-curve PNG per group, ``episodes.csv`` and ``results.json``, rendered from the training study
(:func:`ehss_gym.study.training.run_training_study`, which evaluates the runs and ships the models).

    ehss training-report --runs runs/res_p_n2 runs/ppo_p_n2 --out reports/training --episodes 48 --ship ehss_gym/models
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re

import matplotlib
import numpy as np

from ehss_gym.agents.specs import AGENTS, PPO_KEYS, sac_kwargs
from ehss_gym.infra.fmt import fmt_cell
from ehss_gym.infra.util import atomic_write, atomic_write_text
from ehss_gym.study import training as an
from ehss_gym.study.exploration import COMMAND as EXPLORATION_COMMAND

from .render import render

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the Agg backend: no screen needed)

COMMAND = "ehss training-report"
EPISODE_COLUMNS = ("task", "suite", "policy", "run", "episode", "q_overall", "q_tracking", "q_disturbance", "q_effort",
                   "q_chatter", "trk_rmse", "dst_peak", "tv_u_rate", "diverged", "lost_track")


def cell(x, d: int = 3) -> str:
    """A table cell (:func:`ehss_gym.infra.fmt.fmt_cell`): ``d`` decimals, significant digits below 0.01 and from
    1e4."""
    return fmt_cell(x, d, decimals=True)

def cells(rows) -> list[list[str]]:
    """Every value of ``rows`` through :func:`cell`."""
    return [[cell(v) for v in row] for row in rows]


# ---------------------------------------------------------------------------------------------------
# Figures


def curve_file(key: tuple) -> str:
    """The learning-curve PNG's file name of a group."""
    return "curve_" + re.sub(r"[^A-Za-z0-9_.-]+", "_", an.label(key)).strip("_") + ".png"


def plot_curve(key: tuple, rs: list[dict], path: str, made_by: str = COMMAND) -> None:
    """A group's learning curves as a PNG: the validation figure (clf-n2 = 1; a residual agent's step-0 policy is its
    base law) over training steps, one line per seed, on a log axis when the figures span more than a decade."""
    fig, ax = plt.subplots(figsize=(6.0, 3.4))
    ys = []
    for r in rs:
        h = r["history"]
        y = [np.nan if x["figure"] is None else x["figure"] for x in h]
        ys += [v for v in y if np.isfinite(v)]
        ax.plot([x["step"] / 1e3 for x in h], y, lw=1, marker=".", label=f"seed {r['config']['seed']}")
    ax.axhline(1.0, color="k", lw=0.8, ls="--", label="clf-n2")
    if ys and min(ys) > 0 and max(ys) / min(ys) > 10:
        ax.set_yscale("log")
    ax.set_xlabel("agent steps [thousands]")
    ax.set_ylabel("validation figure G (lower is better)", fontsize=8)
    ax.set_title(f"{an.label(key)}; made by: {made_by}", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=6)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110))
    plt.close(fig)


# ---------------------------------------------------------------------------------------------------
# The report's numbers and tables


# run settings with flags of their own (config key, ehss train flag), absent from a run's config when not given
RUN_FLAGS = (("n_envs", "n-envs"), ("plant", "plant"), ("law_settings", "law-settings"))


def runs_context(groups: dict) -> list[dict]:
    """Per group: the ``ehss train`` settings that made its runs."""
    out = []
    for k, rs in groups.items():
        c = rs[0]["config"]
        # the run settings a command needs beyond the usual ones, where the runs were given them, then the overrides
        flags = "".join(f" --{flag} {c[key]}" for key, flag in RUN_FLAGS if c.get(key) is not None)
        hp = flags + "".join(f" --hp '{key}={json.dumps(v)}'" for key, v in sorted((c.get("hp") or {}).items()))
        out.append({"label": an.label(k), "agent": c["agent"], "task": c["task"], "n": c["n"],
                    "seeds": ",".join(str(r["config"]["seed"]) for r in rs), "timesteps": c["timesteps"],
                    "eval_freq": c["eval_freq"], "eval_episodes": c["eval_episodes"], "hp": hp})
    return out


def hyperparameter_rows() -> list[list[str]]:
    """One row per AgentSpec field of any agent (the name aside), one column per agent, values as JSON ("-" where an
    agent has no such field)."""
    specs = {a: AGENTS[a].as_dict() for a in AGENTS}
    fields = list(dict.fromkeys(f for d in specs.values() for f in d if f != "name"))

    def value(a, f):  # SAC does not read PPO's own settings
        unused = f not in specs[a] or (AGENTS[a].algo != "ppo" and f in PPO_KEYS and f not in sac_kwargs(AGENTS[a]))
        return None if unused else json.dumps(specs[a][f])
    return cells([[f] + [value(a, f) for a in AGENTS] for f in fields])


def exploration_rows(noise: dict) -> list[list[str]]:
    """The initial-exploration-noise study (``exploration_noise.json``), one row per candidate log_std_init."""
    return cells([[r["log_std_init"], r["std_mA"], r["explore_figure"],
                   "; ".join(", ".join(f"{x:.3f}" for x in v) for v in r["early_figures"].values()),
                   r["mean_early_figure"], r["worst_early_figure"], "yes" if r["below_base"] else "no"]
                  for r in noise["rows"]])


def seed_rows(rows: list[dict]) -> list[list[str]]:
    """A group's per-seed table (:func:`ehss_gym.study.training.seed_table`)."""
    return cells([[r["seed"], r["step0"], r["best"], r["best_step"], r["final"], "yes" if r["untrained"] else "no",
                   r.get("heldout"), r.get("unmodelled"), r["wall_s"] / 60] for r in rows])


def summary_rows(res) -> list[list[str]]:
    """The harness's summary: one row per (suite, policy) with the overall figure's CI over seeds and episodes."""
    rows = []
    for d in res.summary:
        rows.append([d["suite"], d["policy"], d["n_runs"], d["n_episodes"], d["figure"],
                     f"[{cell(an.ci_lo(d))}, {cell(an.ci_hi(d))}]", d["figure_iqm"], d["trk_rmse"], d["dst_peak"],
                     d["tv_u_rate"], "FAILED" if d["failed"] else "", d["rank"] or "earlier loop"])
    return cells(rows)


def comparison_rows(res) -> list[list[str]]:
    """The learned policies against the best CLF law and against their own base law."""
    return cells([[c["suite"], c["policy"], c["n_runs"], c["figure"], c["best_clf"], c["best_clf_figure"],
                   c["improvement"], f"[{cell(c['improvement_lo'])}, {cell(c['improvement_hi'])}]", c["base_law"],
                   c.get("ratio_to_base", math.nan),
                   f"[{cell(c.get('ratio_to_base_lo', math.nan))}, {cell(c.get('ratio_to_base_hi', math.nan))}]",
                   c["tracking_ratio"], c["disturbance_ratio"], c["effort_ratio"], c["chatter_ratio"]]
                  for c in res.comparisons])


def standing(name: str, res) -> list[dict]:
    """Where a learned policy stands on each evaluated suite: its G with its CI, the best scripted policy's G,
    ``loses`` (a failed gate, or a G above the best scripted one's) and ``beats`` (its CI's upper end below the best
    scripted G); neither is a tie within its CI."""
    out = []
    scripted = {s.name for s in res.specs if not s.learned}
    for suite in an.SUITES:
        mine = an.best_row(res.summary, suite, {name})
        best = an.best_row(res.summary, suite, scripted)
        if mine is None or best is None:
            continue
        out.append({"suite": suite, "g": mine["figure"], "lo": an.ci_lo(mine), "hi": an.ci_hi(mine),
                    "failed": bool(mine["failed"]), "scripted": best["policy"], "g_scripted": best["figure"],
                    "earlier_loop": bool(mine.get("earlier_loop")),
                    "loses": bool(mine["failed"] or mine["figure"] > best["figure"]),
                    "beats": bool(not mine["failed"] and an.ci_hi(mine) < best["figure"])})
    return out


def group_context(key: tuple, study) -> dict:
    """Everything a group's section shows: its curve, the seeds' table, the validation target, its standing."""
    res = study.results.get(key[1])
    return {"label": an.label(key), "figure": curve_file(key), "seed_rows": seed_rows(study.seeds[key]),
            "validation": study.validation[key], "standing": standing(an.label(key), res) if res else []}


def task_context(t: dict, res) -> dict:
    """Everything the report's section on task ``t["task"]`` shows (:func:`ehss_gym.study.training.task_analyses`)."""
    return {"task": t["task"], "summary_rows": summary_rows(res), "comparison_rows": comparison_rows(res),
            "unmodelled": t["unmodelled"], "heldout": t["heldout"], "diag": t["diag"], "wall": t["wall"]}


def shipped_context(groups: dict, shipment, folder: str | None) -> dict | None:
    """The shipment: the group chosen per (agent, task, n) with the other variants' validation figures, the files
    written and their size, the models retired, the groups not shipped."""
    if shipment is None:
        return None
    chosen = [{"base": an.label(b + ("",)), "label": an.label(k), "figure": an.mean_validation(groups[k]),
               "others": [{"label": an.label(o), "figure": an.mean_validation(groups[o])} for o in groups
                          if o[:3] == b and o != k]} for b, k in sorted(an.choose_variants(groups).items())]
    total = sum(os.path.getsize(p + ext) for p in shipment.written for ext in (".safetensors", ".json"))
    return {"chosen": chosen, "count": len(shipment.written), "folder": folder, "kb": total / 1e3,
            "names": [os.path.basename(p) for p in shipment.written], "retired": shipment.retired,
            "skipped": shipment.skipped}


def markdown(command: str, study, exploration: dict | None = None) -> str:
    """TRAINING.md: the template filled with the numbers and tables above (an exploration study of an earlier loop is
    named, not shown)."""
    earlier = exploration is not None and not an.exploration_is_current(exploration)
    exploration = None if earlier else exploration
    sections = [task_context(t, study.results[t["task"]]) for t in study.tasks]
    return render("training.md.j2", command=command, runs=runs_context(study.groups), agents=list(AGENTS),
                  hyperparameter_rows=hyperparameter_rows(), exploration=exploration,
                  exploration_command=EXPLORATION_COMMAND,
                  exploration_rows=exploration_rows(exploration) if exploration else [], exploration_earlier=earlier,
                  agent_log_std=AGENTS["residual-ppo"].log_std_init,
                  groups=[group_context(k, study) for k in study.groups], made_by=COMMAND, tasks=sections,
                  episodes=study.episodes, shipped=shipped_context(study.groups, study.shipment, study.models_dir),
                  target_ratio=an.TARGET_UNMODELLED_RATIO, target_hi=an.TARGET_HELDOUT_HI,
                  target_trained=an.TARGET_TRAINED_SEEDS, target_seeds=an.TARGET_SEEDS,
                  unmodelled_met_somewhere=any(t["unmodelled"] and t["unmodelled"]["met"] for t in sections),
                  cell=cell, fmt=format)


# ---------------------------------------------------------------------------------------------------
# Files


def episodes_csv(results: dict) -> str:
    """One row per evaluated episode of every task (:data:`EPISODE_COLUMNS`)."""
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(EPISODE_COLUMNS)
    for task, res in results.items():
        for r in res.rows:
            w.writerow([task] + [r[c] for c in EPISODE_COLUMNS[1:]])
    return buf.getvalue()


def results_json(study) -> str:
    """The harness's summary and comparisons and the targets per task, the per-seed rows and the validation target
    per group."""
    out = {"tasks": {t["task"]: {"summary": study.results[t["task"]].summary,
                                 "comparisons": study.results[t["task"]].comparisons,
                                 "unmodelled_target": t["unmodelled"], "heldout_targets": t["heldout"]}
                     for t in study.tasks},
           "groups": {an.label(k): {"seeds": study.seeds[k], "validation_target": study.validation[k]}
                      for k in study.groups}}
    return json.dumps(out, indent=1, default=str) + "\n"


def command_line(runs: list[str], out: str, episodes: int, ship: str | None, archive: str | None = None) -> str:
    """The command that writes the report with these settings (printed at the top of TRAINING.md)."""
    return (f"{COMMAND} --runs {' '.join(runs)} --out {out} --episodes {episodes}"
            + (f" --ship {ship}" if ship else "") + (f" --archive {archive}" if archive else ""))


def write_report(study, out: str, command: str) -> list[str]:
    """Write the report of a :class:`~ehss_gym.study.training.TrainingStudy` to ``out``; the paths written.

    Args:
        study: the training study (evaluated runs, analyses, shipped models).
        out: output folder (TRAINING.md, a learning-curve PNG per group, episodes.csv, results.json).
        command: the command line that made it (printed at the top of TRAINING.md).
    """
    os.makedirs(out, exist_ok=True)
    figures = [os.path.join(out, curve_file(k)) for k in study.groups]
    for k, path in zip(study.groups, figures):
        plot_curve(k, study.groups[k], path)
    files = {"TRAINING.md": markdown(command, study, study.exploration),
             "episodes.csv": episodes_csv(study.results), "results.json": results_json(study)}
    for name, text in files.items():
        atomic_write_text(os.path.join(out, name), text)
    return figures + [os.path.join(out, name) for name in files]


__all__ = ["COMMAND", "cell", "curve_file", "plot_curve", "markdown", "episodes_csv", "results_json", "command_line",
           "write_report"]
