"""The ablation report (``ehss ablation``): ``ABLATION.md`` with its prose in templates/ablation.md.j2, the cells'
validation curves (``curves.png``) and ``ablation.csv`` (every validation row of every cell), rendered from the
ablation study (:func:`ehss_gym.study.ablation.run_ablation`).

    ehss ablation --runs runs/ablation --out reports/training/ablation
"""

from __future__ import annotations

import csv
import io
import os

import matplotlib

from ehss_gym.infra.util import atomic_write, atomic_write_text
from ehss_gym.study import ablation as ab

from .render import render
from .training import cell

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the Agg backend: no screen needed)

COMMAND = "ehss ablation"
CSV_COLUMNS = ("cell", "reward", "action", "exploration", "base", "distribution", "step", "figure", "failed",
               "n_failed", "tracking", "disturbance", "effort", "chatter", "wall_s", "cpu_s")


def plot_curves(study: ab.Ablation, path: str, made_by: str = COMMAND) -> None:
    """Each cell's validation figure over training steps, one panel per stage, with clf-n2 (1) and dcomp-n2."""
    stages = [(name, rs) for name, rs in (("stage 1: reward x action", study.stage1),
                                          ("stage 2: exploration x base", study.stage2),
                                          ("stage 3: the leader's distributions", study.stage3)) if rs]
    fig, axes = plt.subplots(1, max(len(stages), 1), figsize=(6.5 * max(len(stages), 1), 4.6), squeeze=False)
    for ax, (title, rs) in zip(axes[0], stages):
        for r in rs:
            h = r["history"]
            ax.plot([x["step"] / 1e3 for x in h], [x["figure"] for x in h], lw=1, marker=".", ms=3, label=r["label"])
        ax.axhline(1.0, color="k", lw=0.8, ls="--", label="clf-n2 (the ruler's reference)")
        ax.axhline(study.dcomp["U"]["figure"], color="k", lw=0.8, ls=":", label="dcomp-n2 on U (best scripted)")
        ax.set_yscale("log")
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("agent steps [thousands]", fontsize=8)
        ax.set_ylabel("validation figure (lower is better)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=6)
    fig.suptitle(f"Validation curves of the ablation's cells ({ab.TASK}, n = {ab.N}, unmodelled effects, seed "
                 f"{ab.SEED}); made by: {made_by}", fontsize=8)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110))
    plt.close(fig)


def _figure_cell(row: dict) -> str:
    """A set's figure with the failure gate's verdict."""
    return cell(row["figure"]) + (f" FAILED ({row['n_failed']})" if row["failed"] else "")


def cell_rows(results: list[dict], order: list[dict]) -> list[list[str]]:
    """One row per cell: its place by the rule, its choices, U at step 0 and final, the final's U classes, H at step
    0 and final, whether it is admissible and beats step 0, the best figure of its validation curve, its CPU and
    wall time."""
    place = {r["label"]: i + 1 for i, r in enumerate(order)}
    rows = []
    for r in results:
        c, u = r["cell"], r["U"]
        rows.append([place[r["label"]], c.reward, c.action, c.exploration, c.base, c.distribution,
                     _figure_cell(r["U0"]), _figure_cell(u), cell(u["tracking"]), cell(u["disturbance"]),
                     cell(u["effort"]), cell(u["chatter"]), _figure_cell(r["H0"]), _figure_cell(r["H"]),
                     "yes" if ab.admissible(r) else "no", "yes" if r["beats_step0"] else "no",
                     f"{cell(r['best'])} @{r['best_step'] // 1000}k", f"{r['cpu_s'] / 60:.1f}",
                     f"{r['wall_s'] / 60:.1f}"])
    return rows


def ablation_csv(study: ab.Ablation) -> str:
    """Every validation row of every finished cell (:data:`CSV_COLUMNS`)."""
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(CSV_COLUMNS)
    for r in study.stage1 + study.stage2 + study.stage3:
        c = r["cell"]
        for x in r["history"]:
            w.writerow([r["label"], c.reward, c.action, c.exploration, c.base, c.distribution]
                       + [x.get(k) for k in CSV_COLUMNS[6:]])
    return buf.getvalue()


def markdown(study: ab.Ablation, command: str, figure: str) -> str:
    """ABLATION.md: the template filled with the tables above."""
    order = study.order
    header = ["place", "reward", "action", "exploration", "base", "distribution", "U step 0", "U final",
              "U final: tracking", "disturbance", "effort", "chatter", "H step 0", "H final", "admissible",
              "beats step 0", "curve's best @step", "CPU [min]", "wall [min]"]
    all_cells = study.stage1 + study.stage2 + study.stage3
    return render("ablation.md.j2", command=command, made_by=COMMAND, ab=ab, header=header,
                  stage1_rows=cell_rows(study.stage1, order), stage2_rows=cell_rows(study.stage2, order),
                  stage3_rows=cell_rows(study.stage3, order),
                  winner=order[0] if order else None, beaten=[r for r in all_cells if r["beats_step0"]],
                  below_dcomp=[r for r in all_cells if r["final"] is not None and study.dcomp["U"]["figure"] is not None
                               and r["final"] < study.dcomp["U"]["figure"]],
                  all_cells=all_cells, missing=study.missing, dcomp=study.dcomp, commands=study.commands,
                  figure=os.path.basename(figure), cell=cell,
                  cpu_mean=sum(r["cpu_s"] for r in all_cells) / len(all_cells) if all_cells else 0.0)


def command_line(runs: str, out: str, timesteps: int) -> str:
    """The command that writes the report with these settings (printed at the top of ABLATION.md)."""
    return f"{COMMAND} --runs {runs} --out {out}" + (f" --timesteps {timesteps}" if timesteps != ab.TIMESTEPS else "")


def write_report(study: ab.Ablation, out: str, command: str) -> list[str]:
    """Write ABLATION.md, curves.png and ablation.csv of ``study`` to ``out``; the paths written."""
    os.makedirs(out, exist_ok=True)
    figure = os.path.join(out, "curves.png")
    plot_curves(study, figure)
    files = {"ABLATION.md": markdown(study, command, figure), "ablation.csv": ablation_csv(study)}
    for name, text in files.items():
        atomic_write_text(os.path.join(out, name), text)
    return [figure] + [os.path.join(out, name) for name in files]


__all__ = ["COMMAND", "CSV_COLUMNS", "plot_curves", "cell_rows", "ablation_csv", "markdown", "command_line",
           "write_report"]
