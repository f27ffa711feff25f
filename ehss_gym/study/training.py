"""The training study behind ``ehss training-report`` (:func:`run_training_study`; its report is
:mod:`ehss_gym.reporting.training`): finished runs of today's learned agents, their evaluation beside the scripted
laws, the targets they are judged by, and the shipped models.

Reads every run folder under the ``--runs`` folders (those with ``summary.json``), groups them by
(agent, task, n, settings variant), and:

1. evaluates each group's kept (best-on-validation) policy of every seed with the evaluation harness
   (:func:`ehss_gym.evaluation.harness.evaluate`) on its held-out suite (seeds disjoint from training and from the
   validation block used for model selection) and on its unmodelled suite (the same distribution with the valve and
   sensor effects the law's model leaves out), next to the scripted policies of
   :data:`ehss_gym.evaluation.specs.SCRIPTED_DEFAULT` (:func:`evaluate_groups`). A policy trained with the unmodelled
   effects is scored on the episodes as the suite pins them: the held-out ones without the effects, the unmodelled
   ones with them, exactly as the scripted laws are;
2. judges the targets (:func:`unmodelled_target`, :func:`heldout_targets`, :func:`validation_target`) and gives each
   seed's figures (:func:`seed_table`);
3. ships every group's kept policies to the models folder as ``<agent>-<task>-n<n>-seed<k>`` and retires the model
   files there that the shipment does not write (:func:`ship`).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from dataclasses import dataclass, field

import numpy as np

from ehss_gym.agents.safeweights import load_policy, model_paths
from ehss_gym.agents.specs import AGENTS, env_kwargs_for, resolved_env_kwargs
from ehss_gym.evaluation import harness as ev
from ehss_gym.evaluation.scoring import Block, figure_of, rank_key
from ehss_gym.infra.util import atomic_write, atomic_write_text

SUITES = ("heldout", "unmodelled")  # the suites the learned agents are judged on (the paper run: `ehss evaluate`)
# The retrained recipe's targets, stated before the runs they judge (the release plan of the residual recipe trained
# with the unmodelled effects, the schedule action and the physical reward):
TARGET_UNMODELLED_RATIO = 0.80  # [-] unmodelled suite, per task: the best learned G <= this x the best scripted G,
#                                  and the learned G's 95 % CI upper end below the scripted G
TARGET_HELDOUT_HI = 1.05  # [-] held-out suite: every residual-PPO group's 95 % CI upper end of G (clf-n2 = 1) <= this
TARGET_TRAINED_SEEDS = 4  # [-] validation curves: per group, seeds whose kept policy is not the step-0 one, >= this ...
TARGET_SEEDS = 5  # ... of this many training seeds


def read_json(path: str):
    """The JSON value in file ``path``."""
    with open(path, encoding="utf-8") as f:
        return json.load(f)


# ---------------------------------------------------------------------------------------------------
# Runs


def kept_model(run: dict) -> str | None:
    """The kept (best-on-validation) model of a run: its safe-weights stem ``best/policy``, else its SB3
    ``best/model.zip`` (a SAC run trained before SAC runs wrote safe weights); None if it has neither."""
    stem = os.path.join(run["dir"], "best", "policy")
    if all(os.path.isfile(p) for p in model_paths(stem)):
        return stem
    z = os.path.join(run["dir"], "best", "model.zip")
    return z if os.path.isfile(z) else None


def load_runs(folder: str) -> list[dict]:
    """Every finished run under ``folder`` (config, summary, validation history and a kept model)."""
    out = []
    if not os.path.isdir(folder):
        raise ValueError(f"--runs folder {folder!r} does not exist")
    for name in sorted(os.listdir(folder)):
        d = os.path.join(folder, name)
        paths = [os.path.join(d, f) for f in ("config.json", "summary.json", "evaluations.json")]
        if not all(os.path.isfile(p) for p in paths) or kept_model({"dir": d}) is None:
            continue
        cfg, summ, hist = (read_json(p) for p in paths)
        out.append({"dir": d, "config": cfg, "summary": summ, "history": hist})
    return out


def variant(config: dict) -> str:
    """A run's settings variant: "" when its agent settings are today's (:data:`ehss_gym.agents.specs.AGENTS`, however
    they were given), else its --hp overrides as compact JSON; without any (settings given as their own flags, such as
    --n-envs, or an agent whose defaults have changed since), the settings that differ from today's agent as compact
    JSON (a dict setting: its differing entries), or a hash of them where the agent is gone."""
    spec = config["agent_spec"]
    today = AGENTS.get(config["agent"])
    now = json.loads(json.dumps(today.as_dict())) if today is not None else None
    if now == spec:
        return ""
    hp = config.get("hp") or {}
    if hp:
        return _compact(hp)
    if now is None:
        return "settings #" + hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:8]
    diff = {}
    for k in sorted(set(spec) | set(now)):
        a, b = spec.get(k), now.get(k)
        if a != b:
            diff[k] = ({e: a[e] for e in sorted(a) if a[e] != b.get(e)} if isinstance(a, dict) and isinstance(b, dict)
                       else a)
    return _compact(diff)


def _compact(d: dict) -> str:
    """Settings as compact JSON (keys sorted): a group label's variant."""
    return json.dumps(d, sort_keys=True, separators=(",", ":"))


def group_key(run: dict) -> tuple:
    """(agent, task, n, :func:`variant`)."""
    c = run["config"]
    return c["agent"], c["task"], int(c["n"]), variant(c)


def group_runs(runs: list[dict]) -> dict[tuple, list[dict]]:
    """Runs by :func:`group_key`, each group sorted by seed; ValueError if a group mixes settings or repeats a
    seed."""
    groups: dict[tuple, list[dict]] = {}
    for r in runs:
        groups.setdefault(group_key(r), []).append(r)
    for k, rs in groups.items():
        rs.sort(key=lambda r: r["config"]["seed"])
        specs = {json.dumps({**r["config"]["agent_spec"], "timesteps": r["config"]["timesteps"]}, sort_keys=True)
                 for r in rs}
        if len(specs) > 1:
            raise ValueError(f"runs of {k} were trained with different settings; put them in separate --runs folders")
        seeds = [r["config"]["seed"] for r in rs]
        if len(set(seeds)) < len(seeds):
            raise ValueError(f"runs of {label(k)} repeat a seed ({seeds}); put them in separate --runs folders")
    return dict(sorted(groups.items()))


def label(key: tuple) -> str:
    """``<agent>-<task>-n<n>`` of a group key, with its settings variant if any."""
    agent, task, n, var = key
    return f"{agent}-{task}-n{n}" + (f" {var}" if var else "")


def learned_kind(run: dict) -> str:
    """The harness's spec kind of a run (:data:`ehss_gym.evaluation.specs.LEARNED_KINDS`): a kept model in safe
    weights (PPO or SAC) is "residual-ppo" or "ppo-direct" by its mode (the harness's kinds name the mode), an SB3 zip
    "sb3" (the mode from the env settings saved with it)."""
    if kept_model(run).endswith(".zip"):
        return "sb3"
    return "residual-ppo" if run["config"]["env_kwargs"]["mode"] == "residual" else "ppo-direct"


def group_spec(key: tuple, rs: list[dict]):
    """The harness's :class:`~ehss_gym.evaluation.specs.PolicySpec` of a group: its kept models, one run per seed.

    Raises:
        ValueError: seeds whose models act in different env settings.
    """
    kind = learned_kind(rs[0])
    specs = [ev.learned_spec(kind, kept_model(r), name=label(key)) for r in rs]
    if any(s.env_kwargs != specs[0].env_kwargs for s in specs):
        raise ValueError(f"the seeds of {label(key)} act in different env settings; evaluate them apart")
    spec = specs[0]
    spec.runs = [s.runs[0] for s in specs]
    return spec


# ---------------------------------------------------------------------------------------------------
# Evaluation


def evaluate_groups(groups: dict, episodes: int, workers: int, progress: bool, command: str) -> dict:
    """Run the evaluation harness on every task that has runs: the scripted policies (:data:`SCRIPTED_DEFAULT
    <ehss_gym.evaluation.specs.SCRIPTED_DEFAULT>`) and every group's kept policies (a run per seed) on ``episodes``
    episodes of each of :data:`SUITES`.

    Args:
        groups: :func:`group_runs` output.
        episodes: episodes per suite and task.
        workers: evaluation worker processes.
        progress: show the harness's progress bar.
        command: the command line recorded with the results.

    Returns:
        {task: :class:`ehss_gym.evaluation.harness.Results`}.
    """
    out = {}
    for task in sorted({k[1] for k in groups}):
        specs = ev.scripted_specs(ev.SCRIPTED_DEFAULT, (task,))
        specs += [group_spec(k, rs) for k, rs in groups.items() if k[1] == task]
        cfg = ev.EvalConfig(suites=SUITES, tasks=(task,), heldout_episodes=episodes)
        out[task] = ev.evaluate(specs, cfg, workers=workers, progress=progress, command=command)
    return out


def ci_hi(row: dict) -> float:
    """The upper end of a summary row's 95 % CI of G (over seeds and episodes where it has several seeds)."""
    return float(row.get("figure_hi_both", row["figure_hi"]))


def ci_lo(row: dict) -> float:
    """The lower end of a summary row's 95 % CI of G (as :func:`ci_hi`)."""
    return float(row.get("figure_lo_both", row["figure_lo"]))


def run_figures(res, suite: str, name: str) -> list[float]:
    """G of each run (training seed) of policy ``name`` on ``suite``: its class figures over the episodes that every
    run and the reference finished, combined as the harness combines them."""
    task = res.cfg.tasks[0]
    blk = Block(res.rows, [name], suite, task)
    n_runs = blk.overall[name].shape[0]
    return [figure_of({c: m[i][np.isfinite(m[i])] for c, m in blk.logs[name].items()})[0] for i in range(n_runs)]


# ---------------------------------------------------------------------------------------------------
# Targets


def best_row(summary: list[dict], suite: str, names) -> dict | None:
    """The best of the policies ``names`` on ``suite`` by the harness's ranking order (no failed gate, then fewest
    failed episodes, then lowest G), earlier-loop policies included (the harness scores them on the same episodes,
    only leaves them out of its ranks); None if none of them ran."""
    rows = [d for d in summary if d["suite"] == suite and d["policy"] in names]
    return min(rows, key=lambda d: rank_key(d["failed"], d["n_failed"], d["figure"], d["policy"]), default=None)


def unmodelled_target(summary: list[dict], learned: set[str]) -> dict | None:
    """Target (a) on one task's summary: the best learned policy against the best scripted one on the unmodelled
    suite (best = first in the harness's rank order: no failed gate, then lowest G).

    Returns:
        ``learned``/``scripted`` (names), ``g_learned``, ``g_scripted``, ``hi`` (the learned G's CI upper end),
        ``ratio`` (g_learned / g_scripted), ``earlier_loop`` (of the learned one), ``met``; None without a learned or
        a scripted row.
    """
    scripted = {d["policy"] for d in summary} - set(learned)
    best_l, best_s = best_row(summary, "unmodelled", learned), best_row(summary, "unmodelled", scripted)
    if best_l is None or best_s is None:
        return None
    ratio = best_l["figure"] / best_s["figure"]
    hi = ci_hi(best_l)
    met = (not best_l["failed"] and ratio <= TARGET_UNMODELLED_RATIO and hi < best_s["figure"])
    return {"learned": best_l["policy"], "scripted": best_s["policy"], "g_learned": best_l["figure"],
            "g_scripted": best_s["figure"], "hi": hi, "ratio": ratio,
            "earlier_loop": bool(best_l.get("earlier_loop")), "met": bool(met)}


def heldout_targets(summary: list[dict], names: list[str]) -> list[dict]:
    """Target (b) on one task's summary: each of the residual-PPO groups ``names`` on the held-out suite, its G
    (clf-n2 = 1) with its CI; met if its gate passes and the CI's upper end is <= TARGET_HELDOUT_HI."""
    by = {d["policy"]: d for d in summary if d["suite"] == "heldout"}
    out = []
    for n in names:
        d = by.get(n)
        if d is None:
            continue
        out.append({"policy": n, "g": d["figure"], "lo": ci_lo(d), "hi": ci_hi(d), "failed": bool(d["failed"]),
                    "earlier_loop": bool(d.get("earlier_loop")),
                    "met": bool(not d["failed"] and ci_hi(d) <= TARGET_HELDOUT_HI)})
    return out


def is_trained(run: dict) -> bool:
    """True if a run's kept policy is a trained one: its validation figure fell below the step-0 policy's
    (``best_is_untrained`` false); a run whose best policy is the untrained one is the base law, not a learned one."""
    s = run["summary"]
    return not s.get("best_is_untrained", s["best_step"] == 0)


def validation_target(rs: list[dict]) -> dict:
    """Target (c) of one group: the seeds whose kept policy is a trained one (:func:`is_trained`)."""
    trained = sum(1 for r in rs if is_trained(r))
    return {"trained": trained, "seeds": len(rs), "met": trained >= TARGET_TRAINED_SEEDS}


def history_figure(run: dict, step: int | None = None) -> float:
    """The validation figure of a run's evaluation at ``step`` (None: the last one); NaN where there is none."""
    rows = run["history"] if step is None else [h for h in run["history"] if h["step"] == step]
    v = rows[-1]["figure"] if rows else None
    return math.nan if v is None else float(v)


def seed_table(groups: dict, results: dict) -> dict[tuple, list[dict]]:
    """Per group, one row per seed: the step-0, best (with its step) and final validation figures, whether the kept
    policy is the step-0 one, the kept policy's G on each evaluated suite and the run's wall time [s]."""
    out = {}
    for k, rs in groups.items():
        res = results.get(k[1])
        per_suite = {s: run_figures(res, s, label(k)) for s in SUITES} if res is not None else {}
        rows = []
        for i, r in enumerate(rs):
            s = r["summary"]
            rows.append({"seed": r["config"]["seed"], "run": os.path.basename(r["dir"]),
                         "step0": history_figure(r, 0), "best": s["best_validation"]["figure"],
                         "best_step": s["best_step"], "final": s["final_validation"]["figure"],
                         "untrained": not is_trained(r),
                         **{suite: (v[i] if i < len(v) else math.nan) for suite, v in per_suite.items()},
                         "wall_s": s["wall_s"]})
        out[k] = rows
    return out


def base_law_diagnostics(results, suite: str) -> dict:
    """The reference law (clf-n2) on ``suite``, the level every figure there is a ratio to: its median tracking RMSE
    [output unit], mean saturation share, and median control TV [mA/s] on the episodes with and without sensor
    noise."""
    rows = [r for r in results.rows if r["suite"] == suite and r["policy"] == ev.REFERENCE_POLICY]
    tv_noisy = [r["tv_u_rate"] for r in rows if r["noisy"]]
    tv_clean = [r["tv_u_rate"] for r in rows if not r["noisy"]]
    return {"suite": suite, "episodes": len(rows), "noisy_episodes": len(tv_noisy),
            "tv_rate_median_noisy": float(np.median(tv_noisy)) if tv_noisy else math.nan,
            "tv_rate_median_clean": float(np.median(tv_clean)) if tv_clean else math.nan,
            "saturation_mean": float(np.mean([r["saturation"] for r in rows])),
            "trk_rmse_median": float(np.median([r["trk_rmse"] for r in rows]))}


# ---------------------------------------------------------------------------------------------------
# Shipping


def mean_validation(rs: list[dict]) -> float:
    """Mean validation score of a group's kept policies (the selection data; never the evaluation's suites)."""
    return float(np.mean([r["summary"]["best_validation"]["figure"] for r in rs]))


def choose_variants(groups: dict) -> dict[tuple, tuple]:
    """Per (agent, task, n): the group key (settings variant) with the best mean validation score."""
    best: dict[tuple, tuple] = {}
    for k, rs in groups.items():
        base = k[:3]
        if base not in best or mean_validation(rs) < mean_validation(groups[best[base]]):
            best[base] = k
    return best


def _holds(path: str, blob: bytes) -> bool:
    """True if file ``path`` exists and holds exactly ``blob``."""
    if not os.path.isfile(path):
        return False
    with open(path, "rb") as f:
        return f.read() == blob


def _same_model(dst: str, blob: bytes, cfg: dict) -> bool:
    """True if ``dst`` already holds these weights and this config (its ``made_by`` aside)."""
    st, js = model_paths(dst)
    if not (_holds(st, blob) and os.path.isfile(js)):
        return False
    old = read_json(js)
    meta = {k: v for k, v in old.get("metadata", {}).items() if k != "made_by"}
    return {**old, "metadata": meta} == {**cfg, "metadata": {k: v for k, v in cfg["metadata"].items()
                                                               if k != "made_by"}}


def ship_run(run: dict, name: str, models_dir: str, made_by: str) -> str:
    """Copy one run's kept safe weights to ``models_dir/name`` (left as it is if it holds the same weights and
    settings already); the stem written."""
    stem = kept_model(run)
    load_policy(stem)  # refuse to ship anything that does not load
    st, js = model_paths(stem)
    with open(st, "rb") as f:
        blob = f.read()
    cfg = read_json(js)
    cfg["name"] = name  # (env_kwargs as the run recorded them: every setting pinned)
    c, s = run["config"], run["summary"]
    cfg["metadata"] = {"run_name": s["run_name"], "seed": c["seed"], "hp_overrides": c.get("hp") or {},
                       "step": s["best_step"], "validation": s["best_validation"], "agent_spec": c["agent_spec"],
                       "timesteps": c["timesteps"],
                       "made_by": f"ehss train (run {s['run_name']}); shipped by {made_by}"}
    dst = os.path.join(models_dir, name)
    if not _same_model(dst, blob, cfg):
        atomic_write(dst + ".safetensors", lambda f: f.write(blob))
        atomic_write_text(dst + ".json", json.dumps(cfg, indent=1, sort_keys=True) + "\n")
        load_policy(dst)
    return dst


@dataclass
class Shipment:
    """What :func:`ship` did: the stems written (or already there), the model names retired (their files deleted),
    and the groups not shipped with the reason."""

    written: list = field(default_factory=list)
    retired: list = field(default_factory=list)
    skipped: list = field(default_factory=list)  # (group label, reason)


def ship(groups: dict, models_dir: str, made_by: str) -> Shipment:
    """Ship the kept policies of every seed of each (agent, task, n)'s chosen group (:func:`choose_variants`) to
    ``models_dir`` as ``<agent>-<task>-n<n>-seed<k>`` (the names :func:`ehss_gym.evaluation.specs.shipped_specs`
    groups into one policy per ``<agent>-<task>-n<n>``), and retire every other model there (its ``.json`` and
    ``.safetensors`` deleted): the models folder then holds this shipment only.

    Only learned policies ship: a group ships if its validation target is met (:func:`validation_target`: at least
    ``TARGET_TRAINED_SEEDS`` seeds whose validation figure fell below the step-0 policy's), and then only its trained
    seeds (:func:`is_trained`); a seed whose best policy is the untrained one is the base law under another name.
    A model already there with the same weights and settings is left as it is, so re-running the report does not
    rewrite the package's model files (``metadata.made_by`` keeps the command that first shipped it). A group
    without safe weights (a SAC run trained before SAC runs wrote them) is not shipped; a shipment that writes
    nothing retires nothing.

    Args:
        groups: :func:`group_runs` output.
        models_dir: the models folder (``ehss_gym/models`` for the package).
        made_by: the shipping command, recorded in each model's metadata.
    """
    out = Shipment()
    os.makedirs(models_dir, exist_ok=True)
    for base, k in sorted(choose_variants(groups).items()):
        rs = groups[k]
        if any(kept_model(r).endswith(".zip") for r in rs):
            out.skipped.append((label(k), "no safe weights in best/ (ehss_gym.agents.export.export_saved_model("
                                          "'<run>/best', algo='sac') writes them); its models stay in its run folders "
                                          "(sb3:<run>/best/model.zip)"))
            continue
        v = validation_target(rs)
        if not v["met"]:
            out.skipped.append((label(k), f"the validation figure of {v['trained']} of its {v['seeds']} seeds fell "
                                          f"below the step-0 policy's (the rule ships a group with at least "
                                          f"{TARGET_TRAINED_SEEDS}); the others kept the untrained policy"))
            continue
        out.written += [ship_run(r, f"{label(base + ('',))}-seed{r['config']['seed']}", models_dir, made_by)
                        for r in rs if is_trained(r)]
    if out.written:
        keep = {os.path.basename(p) for p in out.written}
        for fn in sorted(os.listdir(models_dir)):
            stem, ext = os.path.splitext(fn)
            if ext in (".json", ".safetensors") and stem not in keep:
                os.remove(os.path.join(models_dir, fn))
                if stem not in out.retired:
                    out.retired.append(stem)
    return out


# ---------------------------------------------------------------------------------------------------
# The runs' records


RUN_RECORD = ("config.json", "summary.json", "evaluations.json")  # a run's files the report reads (with its model)
SB3_KEPT = ("model.zip", "vecnormalize.pkl", "model.json")  # a kept SB3 model without safe weights (best/)


def record_files(run: dict) -> list[str]:
    """The files of a run the report reads, relative to its folder: :data:`RUN_RECORD` and its kept model (the safe
    weights ``best/policy.*``, else the SB3 files of ``best/``)."""
    stem = kept_model(run)
    if stem.endswith(".zip"):
        kept = [os.path.join("best", f) for f in SB3_KEPT if os.path.isfile(os.path.join(run["dir"], "best", f))]
    else:
        kept = [os.path.relpath(p, run["dir"]) for p in model_paths(stem)]
    return [*RUN_RECORD, *kept]


def archive(groups: dict, folder: str) -> list[str]:
    """Keep the records of every run of ``groups`` in ``folder/<run folder's name>``: what the report reads
    (:func:`record_files`), not the checkpoints, logs or the final model, so that ``ehss training-report --runs
    <folder>`` gives the same report once the run folders are gone (about 45 kB per run). A file already there with
    the same bytes is left as it is. Returns the folders written.

    Raises:
        ValueError: two runs with the same folder name (archive them apart).
    """
    by_name: dict[str, dict] = {}
    for rs in groups.values():
        for r in rs:
            name = os.path.basename(os.path.normpath(r["dir"]))
            if name in by_name:
                raise ValueError(f"two runs are named {name!r} ({by_name[name]['dir']} and {r['dir']}): archive "
                                 f"them to different folders")
            by_name[name] = r
    out = []
    for name, r in sorted(by_name.items()):
        dst = os.path.join(folder, name)
        for rel in record_files(r):
            with open(os.path.join(r["dir"], rel), "rb") as f:
                blob = f.read()
            to = os.path.join(dst, rel)
            if not _holds(to, blob):  # (also when the archive is the runs' own folder)
                os.makedirs(os.path.dirname(to), exist_ok=True)
                atomic_write(to, lambda f, b=blob: f.write(b))
        out.append(dst)
    return out


def exploration_is_current(study: dict) -> bool:
    """True if an exploration-noise study's JSON (:mod:`ehss_gym.study.exploration`) measured today's residual agent:
    its rows in today's format and its env settings today's recipe's for its task and n."""
    kw = study.get("env_kwargs") or {}
    if not study.get("rows") or "explore_figure" not in study["rows"][0] or "task" not in kw:
        return False
    today = resolved_env_kwargs(env_kwargs_for(AGENTS["residual-ppo"], kw["task"], kw.get("n", 2)))
    return json.loads(json.dumps(today)) == kw


# ---------------------------------------------------------------------------------------------------
# The study


@dataclass
class TrainingStudy:
    """What the training report shows, computed (:func:`run_training_study`).

    Attributes:
        groups: the finished runs by group (:func:`group_runs`).
        results: per task, the harness's :class:`~ehss_gym.evaluation.harness.Results`.
        tasks: per task (in order), its analyses (:func:`task_analyses`) and ``wall``, the evaluation's wall time [s].
        seeds: per group, :func:`seed_table`'s rows.
        validation: per group, :func:`validation_target`.
        shipment: what :func:`ship` did, or None without ``ship_to``.
        exploration: the exploration-noise study's JSON (:mod:`ehss_gym.study.exploration`), or None.
        episodes: episodes per suite and task.
        models_dir: the folder the models were shipped to, or None.
    """

    groups: dict
    results: dict
    tasks: list
    seeds: dict
    validation: dict
    shipment: Shipment | None
    exploration: dict | None
    episodes: int
    models_dir: str | None = None


def task_analyses(task: str, res, groups: dict) -> dict:
    """One task's analyses: ``targets`` (a: :func:`unmodelled_target`, b: :func:`heldout_targets`) and ``diag``
    (:func:`base_law_diagnostics` per suite)."""
    learned = {label(k) for k in groups if k[1] == task}
    residual = [label(k) for k in groups if k[1] == task and k[0] == "residual-ppo"]
    return {"task": task, "unmodelled": unmodelled_target(res.summary, learned),
            "heldout": heldout_targets(res.summary, residual),
            "diag": [base_law_diagnostics(res, s) for s in SUITES]}


def run_training_study(runs: list[str], episodes: int = 48, exploration: str | None = None, ship_to: str | None = None,
                       workers: int = 2, progress: bool = True, made_by: str = "ehss training-report",
                       archive_to: str | None = None) -> TrainingStudy:
    """Evaluate the finished runs under the ``runs`` folders and judge them; optionally ship their policies.

    Args:
        runs: folders of run folders (each run folder as ``ehss train`` writes it).
        episodes: episodes per suite and task.
        exploration: the exploration-noise study's JSON, or None (a missing file is left out too).
        ship_to: ship the policies to this folder (e.g. ``ehss_gym/models``; :func:`ship`), or None.
        workers: evaluation worker processes.
        progress: show progress bars.
        made_by: the command, recorded with the evaluation and in the shipped models.
        archive_to: keep the runs' records in this folder (:func:`archive`; e.g. ``reports/training/runs``), or None.

    Raises:
        ValueError: a missing ``runs`` folder, runs of one group with different settings, or no finished runs.
    """
    groups = group_runs([r for folder in runs for r in load_runs(folder)])
    if not groups:
        raise ValueError(f"no finished runs under {runs}")
    if archive_to:
        archive(groups, archive_to)
    results, tasks = {}, []
    for task in sorted({k[1] for k in groups}):
        t0 = time.perf_counter()
        results.update(evaluate_groups({k: v for k, v in groups.items() if k[1] == task}, episodes, workers,
                                       progress, made_by))
        tasks.append({"wall": time.perf_counter() - t0, **task_analyses(task, results[task], groups)})
    shipment = ship(groups, ship_to, made_by) if ship_to else None
    study = read_json(exploration) if exploration and os.path.isfile(exploration) else None
    return TrainingStudy(groups, results, tasks, seed_table(groups, results),
                         {k: validation_target(rs) for k, rs in groups.items()}, shipment, study, episodes, ship_to)


__all__ = ["TrainingStudy", "Shipment", "run_training_study", "task_analyses", "SUITES", "TARGET_UNMODELLED_RATIO",
           "TARGET_HELDOUT_HI", "TARGET_TRAINED_SEEDS", "TARGET_SEEDS", "read_json", "kept_model", "is_trained",
           "load_runs", "variant", "group_key", "group_runs", "label", "learned_kind", "group_spec", "evaluate_groups",
           "ci_hi", "ci_lo", "run_figures", "best_row", "unmodelled_target", "heldout_targets", "validation_target",
           "history_figure", "seed_table", "base_law_diagnostics", "mean_validation", "choose_variants", "ship_run",
           "ship", "RUN_RECORD", "record_files", "archive", "exploration_is_current"]
