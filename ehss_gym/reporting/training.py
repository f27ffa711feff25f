"""The training report (``ehss training-report``): ``TRAINING.md`` with its prose in templates/training.md.j2, the
learning curves, ``episodes.csv`` and ``results.json``, rendered from the training study
(:func:`ehss_gym.study.training.run_training_study`, which evaluates the runs and ships the models).

    ehss training-report --runs runs/final runs/final_ppo --out reports/training --episodes 48 --ship ehss_gym/models
"""

from __future__ import annotations

import csv
import io
import json
import os

import matplotlib
import numpy as np

from ehss_gym.agents.specs import AGENTS
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
CURVES = (("figure", "validation figure (ref. CLF n=2 = 1)"), ("rel_tracking", "tracking / base law"),
          ("rel_disturbance", "disturbance / base law"))  # the learning curves' rows: history field, y label


def cell(x, d: int = 3) -> str:
    """A table cell (:func:`ehss_gym.infra.fmt.fmt_cell`): ``d`` decimals, significant digits below 0.01 and from
    1e4."""
    return fmt_cell(x, d, decimals=True)

def cells(rows) -> list[list[str]]:
    """Every value of ``rows`` through :func:`cell`."""
    return [[cell(v) for v in row] for row in rows]


# ---------------------------------------------------------------------------------------------------
# Figure


def plot_curves(groups: dict, path: str, made_by: str = COMMAND) -> None:
    """The learning curves (validation figure, and the tracking and disturbance figures against the base law's, over
    training steps, one line per seed, one column per group) as a PNG."""
    keys = list(groups)
    fig, axes = plt.subplots(3, len(keys), figsize=(4.2 * len(keys), 8.0), squeeze=False, sharex="col")
    for j, k in enumerate(keys):
        for i, (field, ylabel) in enumerate(CURVES):
            ax = axes[i][j]
            for r in groups[k]:
                h = r["history"]
                ax.plot([x["step"] / 1e3 for x in h], [np.nan if x[field] is None else x[field] for x in h], lw=1,
                        marker=".",
                        label=f"seed {r['config']['seed']}")
            ax.axhline(1.0, color="k", lw=0.8, ls="--")
            ax.set_ylabel(ylabel, fontsize=8)
            if i == 0:
                ax.set_title(an.label(k), fontsize=9)
            if i == len(CURVES) - 1:
                ax.set_xlabel("agent steps [thousands]")
            ax.tick_params(labelsize=7)
        axes[0][j].legend(fontsize=6)
    fig.suptitle(f"Learning curves on the validation scenarios (lower is better); made by: {made_by}", fontsize=8)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110))
    plt.close(fig)


# ---------------------------------------------------------------------------------------------------
# The report's numbers and tables


def runs_context(groups: dict) -> list[dict]:
    """Per group: the ``ehss train`` settings that made its runs."""
    out = []
    for k, rs in groups.items():
        c = rs[0]["config"]
        hp = "".join(f" --hp '{key}={json.dumps(v)}'" for key, v in sorted((c.get("hp") or {}).items()))
        out.append({"label": an.label(k), "agent": c["agent"], "task": c["task"], "n": c["n"],
                    "seeds": ",".join(str(r["config"]["seed"]) for r in rs), "timesteps": c["timesteps"],
                    "eval_freq": c["eval_freq"], "eval_episodes": c["eval_episodes"], "hp": hp})
    return out


def hyperparameter_rows() -> list[list[str]]:
    """One row per AgentSpec field (the name aside), one column per agent, values as JSON."""
    fields = [f for f in AGENTS["residual-ppo"].as_dict() if f != "name"]
    return cells([[f] + [json.dumps(AGENTS[a].as_dict()[f]) for a in AGENTS] for f in fields])


def exploration_rows(noise: dict) -> list[list[str]]:
    """The initial-exploration-noise study (``exploration_noise.json``), one row per candidate log_std_init."""
    return cells([[r["log_std_init"], r["std_mA"], r["explore_figure"],
                   "; ".join(", ".join(f"{x:.3f}" for x in v) for v in r["early_figures"].values()),
                   r["mean_early_figure"], r["worst_early_figure"], "yes" if r["below_base"] else "no"]
                  for r in noise["rows"]])


def cost_rows(groups: dict) -> list[list[str]]:
    """Training cost per seed: steps, wall time [min] in all and to the kept policy, kept step and its figure."""
    return cells([[an.label(k), r["config"]["seed"], r["summary"]["timesteps"], r["summary"]["wall_s"] / 60,
                   an.wall_to_best(r) / 60, r["summary"]["best_step"], r["summary"]["best_validation"]["figure"]]
                  for k, rs in groups.items() for r in rs])


def summary_rows(res) -> list[list[str]]:
    """The harness's summary: one row per (suite, policy) with the overall figure's CI over seeds and episodes."""
    rows = []
    for d in res.summary:
        lo = d.get("figure_lo_both", d["figure_lo"])
        hi = d.get("figure_hi_both", d["figure_hi"])
        rows.append([d["suite"], d["policy"], d["n_runs"], d["n_episodes"], d["figure"],
                     f"[{cell(lo)}, {cell(hi)}]", d["figure_iqm"], d["trk_rmse"], d["dst_peak"], d["tv_u_rate"],
                     "FAILED" if d["failed"] else "", d["rank"] or "earlier loop"])
    return cells(rows)


def comparison_rows(res) -> list[list[str]]:
    """The learned policies against the best CLF law and against their own base law."""
    return cells([[c["suite"], c["policy"], c["n_runs"], c["figure"], c["best_clf"], c["best_clf_figure"],
                   c["improvement"], f"[{cell(c['improvement_lo'])}, {cell(c['improvement_hi'])}]", c["base_law"],
                   c["tracking_ratio"], c["disturbance_ratio"], c["effort_ratio"], c["chatter_ratio"]]
                  for c in res.comparisons])


def tv_rows(tv: list) -> list[list[str]]:
    """Where each residual group's added control TV comes from (:func:`ehss_gym.study.training.tv_sources`)."""
    return cells([[lab, ts["policies"], ts["episodes"], ts["tv_ratio"], ts["own_share_of_added"],
                   ts["own_share_of_total"], ts["crossings_ratio"], ts["rmse_ratio"]] for lab, ts in tv])


def task_context(t: dict, res) -> dict:
    """Everything the report's section on task ``t["task"]`` shows, from its analyses (:class:`TrainingStudy`)."""
    return {"task": t["task"], "summary_rows": summary_rows(res), "comparison_rows": comparison_rows(res),
            "targets": t["targets"], "seed_rows": cells(t["seed_scores"]), "diag": t["diag"], "eb": t["eb"],
            "fa": t["fa"], "tv_rows": tv_rows(t["tv"]), "wall": t["wall"]}


def shipped_context(groups: dict, shipped: list[str], folder: str) -> dict | None:
    """The shipped models: the chosen variant per (task, n) with the others' figures, the files and their size."""
    if not shipped:
        return None
    chosen = [{"base": an.label(b + ("",)), "label": an.label(k), "figure": an.mean_validation(groups[k]),
               "others": [{"label": an.label(o), "figure": an.mean_validation(groups[o])} for o in groups
                          if o[:3] == b and o != k]} for b, k in sorted(an.choose_variants(groups).items())]
    total = sum(os.path.getsize(p + ext) for p in shipped for ext in (".safetensors", ".json"))
    return {"chosen": chosen, "count": len(shipped), "folder": folder, "kb": total / 1e3,
            "names": [os.path.basename(p) for p in shipped]}


def markdown(command: str, groups: dict, tasks: list[dict], exploration: dict | None, shipped: dict | None,
             figure: str, episodes: int) -> str:
    """TRAINING.md: the template filled with the numbers and tables above."""
    return render("training.md.j2", command=command, runs=runs_context(groups), agents=list(AGENTS),
                  hyperparameter_rows=hyperparameter_rows(), exploration=exploration,
                  exploration_command=EXPLORATION_COMMAND,
                  exploration_rows=exploration_rows(exploration) if exploration else [],
                  agent_log_std=AGENTS["residual-ppo"].log_std_init,
                  has_variants=any("log_std_init" in k[3] for k in groups), cost_rows=cost_rows(groups),
                  figure=os.path.basename(figure), made_by=COMMAND, tasks=tasks, episodes=episodes,
                  shipped=shipped, onset_peak=an.ONSET_PEAK, target_improvement=an.TARGET_IMPROVEMENT,
                  target_seeds=an.TARGET_SEEDS, target_friction=an.TARGET_FRICTION, cell=cell, fmt=format)


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


def results_json(results: dict) -> str:
    """The harness's summary and comparisons per task."""
    summary = {task: {"summary": res.summary, "comparisons": res.comparisons} for task, res in results.items()}
    return json.dumps(summary, indent=1, default=str) + "\n"


def command_line(runs: list[str], out: str, episodes: int, ship: str | None) -> str:
    """The command that writes the report with these settings (printed at the top of TRAINING.md)."""
    return (f"{COMMAND} --runs {' '.join(runs)} --out {out} --episodes {episodes}"
            + (f" --ship {ship}" if ship else ""))


def write_report(study, out: str, command: str) -> list[str]:
    """Write the report of a :class:`~ehss_gym.study.training.TrainingStudy` to ``out``; the paths written.

    Args:
        study: the training study (evaluated runs, analyses, shipped models).
        out: output folder (TRAINING.md, learning_curves.png, episodes.csv, results.json).
        command: the command line that made it (printed at the top of TRAINING.md).
    """
    os.makedirs(out, exist_ok=True)
    figure = os.path.join(out, "learning_curves.png")
    plot_curves(study.groups, figure)
    sections = [task_context(t, study.results[t["task"]]) for t in study.tasks]
    shipped = shipped_context(study.groups, study.shipped, study.models_dir)
    files = {"TRAINING.md": markdown(command, study.groups, sections, study.exploration, shipped, figure,
                                     study.episodes),
             "episodes.csv": episodes_csv(study.results), "results.json": results_json(study.results)}
    for name, text in files.items():
        atomic_write_text(os.path.join(out, name), text)
    return [figure] + [os.path.join(out, name) for name in files]


__all__ = ["COMMAND", "cell", "plot_curves", "markdown", "episodes_csv", "results_json", "command_line",
           "write_report"]
