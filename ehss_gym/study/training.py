"""The training study behind ``ehss training-report`` (:func:`run_training_study`; its report is
:mod:`ehss_gym.reporting.training`): finished runs, their evaluation and the diagnostics of the residuals.

Reads every run folder under the ``--runs`` folders (those with ``summary.json``), groups them by
(agent, task, n, --hp variant), and:

1. the training cost per seed (wall time of the whole run and to the kept policy): :func:`wall_to_best`;
2. evaluates each group's kept (best-on-validation) policies, loaded from their safe weights, with the
   evaluation harness (:func:`ehss_gym.evaluation.harness.evaluate`) on its held-out suite (seeds disjoint from
   training and from the validation block used for model selection) and on the paper's scenario, next
   to the scripted CLF laws n = 2, 4, 6 (:func:`evaluate_groups`), with the targets of the residual policies
   (:func:`residual_targets`) and each seed's figure (:func:`seed_scores`);
3. what the reference law's error is made of (:func:`base_law_diagnostics`, :func:`error_budget`), how much of
   the friction peak a residual can reach (:func:`friction_authority`) and where a residual's added control TV
   comes from (:func:`tv_sources`);
4. chooses and copies the residual policies' safe weights to the models folder as
   ``<agent>-<task>-n<n>-seed<k>`` (:func:`choose_variants`, :func:`ship`; every seed, so the harness reports
   them with CIs over seeds).
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass

import numpy as np

from ehss_gym.agents.safeweights import load_policy, model_paths
from ehss_gym.agents.specs import env_kwargs_for, get_spec, resolved_env_kwargs
from ehss_gym.core.scenarios import heldout_scenarios
from ehss_gym.core.sim import simulate_batch
from ehss_gym.envs import EHSSTrackingEnv
from ehss_gym.envs.config import in_legacy_loop
from ehss_gym.evaluation import harness as ev
from ehss_gym.infra.util import atomic_write, atomic_write_text

ONSET_PEAK = 0.01  # [s] a friction-window peak this soon after the switch-on is the torque step's transient
TARGET_IMPROVEMENT = 0.2  # [-] the residuals' target: 1 - G/G_best (overall figures) >= this, ...
TARGET_SEEDS = 5  # ... its CI excluding 0, over at least this many training seeds
TARGET_FRICTION = 0.5  # [-] and the disturbance figure at most this times the base law's (halved)


def read_json(path: str):
    """The JSON value in file ``path``."""
    with open(path, encoding="utf-8") as f:
        return json.load(f)


# ---------------------------------------------------------------------------------------------------
# Runs


def load_runs(folder: str) -> list[dict]:
    """Every finished run under ``folder``: config, summary and evaluation history."""
    out = []
    if not os.path.isdir(folder):
        raise ValueError(f"--runs folder {folder!r} does not exist")
    for name in sorted(os.listdir(folder)):
        d = os.path.join(folder, name)
        paths = [os.path.join(d, f) for f in ("config.json", "summary.json", "evaluations.json")]
        if not all(os.path.isfile(p) for p in paths) or not os.path.isfile(os.path.join(d, "best", "policy.json")):
            continue
        cfg, summ, hist = (read_json(p) for p in paths)
        out.append({"dir": d, "config": cfg, "summary": summ, "history": hist})
    return out


def group_key(run: dict) -> tuple:
    """(agent, task, n, variant): variant is the run's --hp overrides as compact JSON ("" for none)."""
    c = run["config"]
    hp = c.get("hp") or {}
    return c["agent"], c["task"], int(c["n"]), json.dumps(hp, sort_keys=True, separators=(",", ":")) if hp else ""


def group_runs(runs: list[dict]) -> dict[tuple, list[dict]]:
    """Runs by :func:`group_key`, each group sorted by seed; ValueError if a group mixes settings."""
    groups: dict[tuple, list[dict]] = {}
    for r in runs:
        groups.setdefault(group_key(r), []).append(r)
    for k, rs in groups.items():
        rs.sort(key=lambda r: r["config"]["seed"])
        specs = {json.dumps({**r["config"]["agent_spec"], "timesteps": r["config"]["timesteps"]}, sort_keys=True)
                 for r in rs}
        if len(specs) > 1:
            raise ValueError(f"runs of {k} were trained with different settings; put them in separate --runs folders")
    return dict(sorted(groups.items()))


def label(key: tuple) -> str:
    """``<agent>-<task>-n<n>`` of a group key, with its --hp variant if any."""
    agent, task, n, variant = key
    return f"{agent}-{task}-n{n}" + (f" {variant}" if variant else "")


def wall_to_best(run: dict) -> float:
    """Training wall time [s] up to the evaluation that produced the kept policy."""
    best = run["summary"]["best_step"]
    for row in run["history"]:
        if row["step"] == best:
            return float(row["wall_s"])
    return math.nan


# ---------------------------------------------------------------------------------------------------
# Evaluation


def evaluate_groups(groups: dict, episodes: int, workers: int, progress: bool, command: str) -> dict:
    """Run the evaluation harness on every task that has runs: the groups' kept policies (every seed) and the
    scripted CLF laws n = 2, 4, 6 on the paper's scenario and ``episodes`` held-out episodes.

    Args:
        groups: :func:`group_runs` output.
        episodes: held-out episodes per task.
        workers: evaluation worker processes.
        progress: show the harness's progress bar.
        command: the command line recorded with the results.

    Returns:
        {task: :class:`ehss_gym.evaluation.harness.Results`}.
    """
    out = {}
    for task in sorted({k[1] for k in groups}):
        specs = [ev.scripted_spec(f"clf-n{n}") for n in (2, 4, 6)]
        for k, rs in groups.items():
            if k[1] != task:
                continue
            kind = "residual-ppo" if rs[0]["config"]["env_kwargs"]["mode"] == "residual" else "ppo-direct"
            spec = ev.learned_spec(kind, os.path.join(rs[0]["dir"], "best", "policy.json"), name=label(k))
            spec.runs = [os.path.join(r["dir"], "best", "policy") for r in rs]
            specs.append(spec)
        cfg = ev.EvalConfig(suites=("paper", "heldout"), tasks=(task,), heldout_episodes=episodes)
        out[task] = ev.evaluate(specs, cfg, workers=workers, progress=progress, command=command)
    return out


def residual_targets(res) -> list[dict]:
    """The residual policies' targets on the held-out suite, from the harness's comparisons.

    Returns one dict per residual policy: ``policy``, ``n_runs``, ``best_clf``, ``improvement`` (1 - G/G_best, the
    overall figures) with its CI ``improvement_lo``/``_hi`` and ``improvement_met`` (>= TARGET_IMPROVEMENT, CI
    excluding 0, >= TARGET_SEEDS seeds); ``tv_ratio`` (the effort figure over the base law's: control TV and RMS
    current on the noise-free episodes) and ``friction_ratio`` (the disturbance figure over the base law's) with
    ``tv_met`` (<= 1) and ``friction_met`` (<= TARGET_FRICTION); ``rmse_vs_best`` and ``tv_vs_best`` (means over the
    episodes of the tracking RMSE and the control TV, against the best CLF itself).
    """
    means = {(d["suite"], d["policy"]): d for d in res.summary}
    out = []
    for c in res.comparisons:
        if c["suite"] != "heldout" or not c["policy"].startswith("residual-ppo"):
            continue
        tv = c.get("effort_ratio", math.nan)
        fr = c.get("disturbance_ratio", math.nan)
        pol, best = means[("heldout", c["policy"])], means[("heldout", c["best_clf"])]
        out.append({"policy": c["policy"], "n_runs": c["n_runs"], "best_clf": c["best_clf"],
                    "improvement": c["improvement"], "improvement_lo": c["improvement_lo"],
                    "improvement_hi": c["improvement_hi"],
                    "improvement_met": c["improvement"] >= TARGET_IMPROVEMENT and c["improvement_lo"] > 0
                    and c["n_runs"] >= TARGET_SEEDS, "tv_ratio": tv, "tv_met": tv <= 1, "friction_ratio": fr,
                    "friction_met": fr <= TARGET_FRICTION, "rmse_vs_best": pol["trk_rmse"] / best["trk_rmse"],
                    "tv_vs_best": pol["tv_u_rate"] / best["tv_u_rate"]})
    return out


def seed_scores(res) -> list[tuple[str, str, float]]:
    """(policy, run folder name, held-out overall figure) of every training seed of the learned policies: the
    geometric mean of its per-episode overall ratios (the episodes it finished)."""
    out = []
    for d in res.specs:
        if not d.learned:
            continue
        for i in range(len(d.runs)):
            q = [r["q_overall"] for r in res.rows if r["policy"] == d.name and r["run"] == i
                 and r["suite"] == "heldout" and math.isfinite(r["q_overall"])]
            if q:
                out.append((d.name, os.path.basename(os.path.dirname(os.path.dirname(str(d.runs[i])))),
                            float(np.exp(np.mean(np.log(q))))))
    return out


# ---------------------------------------------------------------------------------------------------
# Diagnostics


def has_noise(noise_std) -> bool:
    """True if any of the four measurement channels has sensor noise."""
    return any(v > 0 for v in noise_std)


def base_law_diagnostics(results) -> dict:
    """What the reference law's error is made of on the held-out suite (where a residual could gain)."""
    rows = [r for r in results.rows if r["suite"] == "heldout" and r["policy"] == ev.REFERENCE_POLICY]
    noisy = {ep.episode_id for ep in results.episodes
             if ep.suite == "heldout" and has_noise(ep.physical["noise_std"])}
    tv_noisy = [r["tv_u_rate"] for r in rows if r["episode"] in noisy]
    tv_clean = [r["tv_u_rate"] for r in rows if r["episode"] not in noisy]
    return {"episodes": len(rows), "noisy_episodes": len(tv_noisy),
            "tv_rate_median_noisy": float(np.median(tv_noisy)) if tv_noisy else math.nan,
            "tv_rate_median_clean": float(np.median(tv_clean)) if tv_clean else math.nan,
            "saturation_mean": float(np.mean([r["saturation"] for r in rows])),
            "rmse_nominal_over_rmse": float(np.mean([r["rmse_nominal"] / max(r["rmse"], 1e-12) for r in rows])),
            "tv_rate_median": float(np.median([r["tv_u_rate"] for r in rows])),
            "tv_rate_min": float(np.min([r["tv_u_rate"] for r in rows])),
            "tv_rate_max": float(np.max([r["tv_u_rate"] for r in rows]))}


def agent_env_kwargs(task: str) -> dict:
    """The residual agent's env settings for ``task`` (n = 2) in the loop the shipped runs were trained in: the
    loop its diagnostics must be measured in.

    The runs this report reads were trained in the legacy loop (:data:`ehss_gym.envs.config.LEGACY_LOOP`: before
    the law, the adaptive layer and the estimator defaults of the noise study), so, as when their policies are
    loaded (:func:`ehss_gym.envs.config.in_legacy_loop`), the settings the agent spec leaves to the env are the
    legacy loop's, not today's env defaults.
    """
    # (the paper's SVF, "foh", was every task's estimator in the legacy loop; safe weights pin theirs)
    return in_legacy_loop({"estimator": "foh", **env_kwargs_for(get_spec("residual-ppo"), task, 2)})


def agent_heldout_scenarios(task: str, episodes: int) -> list:
    """The harness's held-out scenarios with the residual agent's controller settings, logged every period."""
    tmpl = EHSSTrackingEnv(**{k: v for k, v in agent_env_kwargs(task).items() if k != "mode"}).scenario_template
    return [sc.replace(log_interval=sc.control_period) for sc in heldout_scenarios(episodes, tmpl)]


def friction_authority(task: str, episodes: int) -> dict:
    """How much a residual *could* lower the friction-window peak: the reference law's applied current
    between each friction switch-on and the event's largest |e|, on the harness's held-out suite at the
    residual agent's settings (noise-free copies, so the law's own action is what is measured).

    While the applied current sits at the current limit in the direction that opposes the error, the
    valve already gets all the current it can take: no residual, learned or not, can add any. Only events
    whose peak comes within ``ONSET_PEAK`` of the switch-on are counted (a later peak is not the torque
    step's doing). Returns the median over those events of the share of rise-interval control steps at the
    limit in that direction (``at_limit_share``), the median rise time [s], the number of such events and
    of all events.
    """
    scs = [sc.replace(noise_std=(0.0, 0.0, 0.0, 0.0)) for sc in agent_heldout_scenarios(task, episodes)]
    shares, rise, total = [], [], 0
    for sc, tr in zip(scs, simulate_batch(scs)):
        if sc.current_limit is None:
            continue
        t, e, u = tr.t, tr.e, tr.u_applied
        for amp, t0, t1 in sc.friction:
            on = np.flatnonzero((t > t0) & (t < t1))
            if amp <= 0 or len(on) < 2:
                continue
            total += 1
            ipk = on[int(np.argmax(np.abs(e[on])))]
            seg = np.arange(on[0], ipk)  # from the first sample after switch-on up to the peak
            if len(seg) == 0 or t[ipk] - t0 > ONSET_PEAK:
                continue
            shares.append(float(np.mean(-np.sign(e[ipk]) * u[seg] >= 0.999 * sc.current_limit)))
            rise.append(float(t[ipk] - t0))
    return {"at_limit_share": float(np.median(shares)) if shares else math.nan,
            "rise_median": float(np.median(rise)) if rise else math.nan, "events": len(rise), "all_events": total}


def error_budget(task: str, episodes: int) -> dict:
    """Where the reference law's squared error lies on the harness's held-out suite, and how fast the error
    peaks after a friction switch-on (simulated at the control rate with :func:`ehss_gym.simulate_batch`).

    Returns shares of sum(e^2) in the first 50 ms (start-up transient), within friction events (+50 ms
    after each), and elsewhere, and the median delay [s] from a friction switch-on to the largest |e| of
    that event.
    """
    scs = agent_heldout_scenarios(task, episodes)
    start = fric = total = 0.0
    delays, sat_start = [], []
    for sc, tr in zip(scs, simulate_batch(scs)):
        t, e2 = tr.t, tr.e ** 2
        mask = np.zeros(t.shape, dtype=bool)
        for amp, t0, t1 in sc.friction:
            if amp <= 0:
                continue
            win = (t >= t0) & (t < t1 + 0.05)
            mask |= win
            on = (t >= t0) & (t < t1)
            if on.any():
                delays.append(float(t[on][np.argmax(np.abs(tr.e[on]))] - t0))
        first = t < 0.05
        if sc.current_limit is not None:
            sat_start.append(float(np.mean(np.abs(tr.u_applied[first]) >= 0.999 * sc.current_limit)))
        start += e2[first].sum()
        fric += e2[mask & ~first].sum()
        total += e2.sum()
    return {"start_share": float(start / total), "friction_share": float(fric / total),
            "other_share": float(1 - (start + fric) / total),
            "start_saturation": float(np.mean(sat_start)) if sat_start else math.nan,
            "peak_delay_median": float(np.median(delays)) if delays else math.nan, "events": len(delays)}


def period_log(policy, scenario, base_only: bool = False) -> dict:
    """One episode of ``policy`` (a :class:`~ehss_gym.agents.safeweights.SafePolicy`) in its own loop, logged at
    every control period: the env is rebuilt with ``agent_period=1`` and the policy acts on every
    ``agent_period``-th period (the loop is the same: the observation and the held action do not depend on
    the agent period). ``base_only`` holds the action at 0: the base law alone.

    Returns the control TV sum |u_k - u_(k-1)| of the applied current [mA] (as the metrics count it), the
    residual's own share sum |r_k - r_(k-1)| [mA], the number of sign changes of the combined error s, and
    the RMSE [output unit].
    """
    period = int(policy.env_kwargs["agent_period"])
    env = policy.make_env(agent_period=1)
    obs, _ = env.reset(options={"scenario": scenario})
    a = np.zeros(policy.action_space.shape, dtype=np.float32)
    s, u, r = [], [], []
    k = 0
    while True:
        if k % period == 0 and not base_only:
            a, _ = policy.predict(obs)
        obs, _, term, trunc, info = env.step(a)
        s.append(info["s"])
        u.append(info["u_applied"])
        r.append(info["u_residual"])
        k += 1
        if term or trunc:
            break
    s, u, r = np.array(s), np.array(u), np.array(r)
    return {"tv": float(np.abs(np.diff(u)).sum()), "tv_own": float(np.abs(np.diff(r)).sum()),
            "crossings": int(np.count_nonzero(np.signbit(s[1:]) != np.signbit(s[:-1]))),
            "rmse": info["metrics"]["rmse"], "metrics_tv": info["metrics"]["tv_u"]}


def tv_sources(policy_paths: list[str], episodes: int) -> dict:
    """Where a residual's added control TV comes from, on the held-out episodes with sensor noise (where the
    TV is; the suite's TV ratio is a ratio of means): the policies' total TV against their base law's on the
    same episodes, the residual's own steps as a share of the added TV, and the ratio of sign changes of the
    combined error s (the base law's sign(s) term switches there). Ratios of sums over seeds and episodes."""
    pols = [load_policy(p) for p in policy_paths]
    tmpl = pols[0].make_env().unwrapped.scenario_template
    scs = [sc for sc in heldout_scenarios(episodes, tmpl) if has_noise(sc.noise_std)]
    base = [period_log(pols[0], sc, base_only=True) for sc in scs]
    runs = [period_log(p, sc) for p in pols for sc in scs]

    def total(logs, key):
        return float(sum(d[key] for d in logs))

    added = total(runs, "tv") - len(pols) * total(base, "tv")
    return {"episodes": len(scs), "policies": len(pols),
            "tv_ratio": total(runs, "tv") / (len(pols) * total(base, "tv")),
            "own_share_of_added": total(runs, "tv_own") / added if added > 0 else math.nan,
            "own_share_of_total": total(runs, "tv_own") / total(runs, "tv"),
            "crossings_ratio": total(runs, "crossings") / (len(pols) * total(base, "crossings")),
            "rmse_ratio": total(runs, "rmse") / (len(pols) * total(base, "rmse"))}


# ---------------------------------------------------------------------------------------------------
# Shipping


def mean_validation(rs: list[dict]) -> float:
    """Mean validation score of a group's kept policies (the selection data; never the held-out test suite)."""
    return float(np.mean([r["summary"]["best_validation"]["figure"] for r in rs]))


def choose_variants(groups: dict) -> dict[tuple, tuple]:
    """Per (agent, task, n) of the residual agent: the group key (variant) with the best mean validation score."""
    best: dict[tuple, tuple] = {}
    for k, rs in groups.items():
        if k[0] != "residual-ppo":
            continue
        base = k[:3]
        if base not in best or mean_validation(rs) < mean_validation(groups[best[base]]):
            best[base] = k
    return best


def _same_model(dst: str, blob: bytes, cfg: dict) -> bool:
    """True if ``dst`` already holds these weights and this config (its ``made_by`` aside)."""
    st, js = model_paths(dst)
    if not (os.path.isfile(st) and os.path.isfile(js)):
        return False
    with open(st, "rb") as f:
        if f.read() != blob:
            return False
    old = read_json(js)
    meta = {k: v for k, v in old.get("metadata", {}).items() if k != "made_by"}
    return {**old, "metadata": meta} == {**cfg, "metadata": {k: v for k, v in cfg["metadata"].items()
                                                               if k != "made_by"}}


def ship(groups: dict, models_dir: str, made_by: str) -> list[str]:
    """Copy the kept policies of every seed of the chosen residual groups (:func:`choose_variants`) to
    ``models_dir`` as ``<agent>-<task>-n<n>-seed<k>``; the stems shipped.

    A model already there with the same weights and settings is left as it is, so re-running the report does not
    rewrite the package's model files (``metadata.made_by`` keeps the command that first shipped it).

    Args:
        groups: :func:`group_runs` output.
        models_dir: the models folder (``ehss_gym/models`` for the package).
        made_by: the shipping command, recorded in each model's metadata.
    """
    written = []
    os.makedirs(models_dir, exist_ok=True)
    for base, k in sorted(choose_variants(groups).items()):
        for r in groups[k]:
            stem = os.path.join(r["dir"], "best", "policy")
            load_policy(stem)  # refuse to ship anything that does not load
            st, js = model_paths(stem)
            name = f"{label(base + ('',))}-seed{r['config']['seed']}"
            with open(st, "rb") as f:
                blob = f.read()
            cfg = read_json(js)
            cfg["name"] = name
            # pin the env settings it was trained with: a run recorded before the loop settings of LEGACY_LOOP
            # existed lacks them (in_legacy_loop fills in the loop of then, not today's defaults)
            cfg["env_kwargs"] = resolved_env_kwargs(in_legacy_loop(cfg["env_kwargs"]))
            cfg["metadata"] = {"run_name": r["summary"]["run_name"], "seed": r["config"]["seed"],
                               "hp_overrides": r["config"].get("hp") or {},
                               "step": r["summary"]["best_step"], "validation": r["summary"]["best_validation"],
                               "agent_spec": r["config"]["agent_spec"], "timesteps": r["config"]["timesteps"],
                               "made_by": f"ehss train (run {r['summary']['run_name']}); shipped by {made_by}"}
            dst = os.path.join(models_dir, name)
            if not _same_model(dst, blob, cfg):
                atomic_write(dst + ".safetensors", lambda f, b=blob: f.write(b))
                atomic_write_text(dst + ".json", json.dumps(cfg, indent=1, sort_keys=True) + "\n")
                load_policy(dst)
            written.append(dst)
    return written


# ---------------------------------------------------------------------------------------------------
# The study


@dataclass
class TrainingStudy:
    """What the training report shows, computed (:func:`run_training_study`).

    Attributes:
        groups: the finished runs by group (:func:`group_runs`).
        results: per task, the harness's :class:`~ehss_gym.evaluation.harness.Results`.
        tasks: per task (in order), its analyses: ``task``, ``wall`` (the evaluation's wall time [s]),
            ``targets`` (:func:`residual_targets`), ``seed_scores``, ``diag`` (:func:`base_law_diagnostics`),
            ``eb`` (:func:`error_budget`), ``fa`` (:func:`friction_authority`) and ``tv``: (group label,
            :func:`tv_sources`) per residual group.
        shipped: the model stems shipped (empty without ``ship``).
        exploration: the exploration-noise study's JSON (:mod:`ehss_gym.study.exploration`), or None.
        episodes: held-out episodes per task.
        models_dir: the folder the models were shipped to, or None.
    """

    groups: dict
    results: dict
    tasks: list
    shipped: list
    exploration: dict | None
    episodes: int
    models_dir: str | None = None


def task_analyses(task: str, res, groups: dict, episodes: int) -> dict:
    """The analyses of one task's section (see :class:`TrainingStudy`), ``wall`` aside."""
    tv = [(label(k), tv_sources([os.path.join(r["dir"], "best", "policy") for r in rs], episodes))
          for k, rs in groups.items() if k[1] == task and rs[0]["config"]["env_kwargs"]["mode"] == "residual"]
    return {"task": task, "targets": residual_targets(res), "seed_scores": seed_scores(res),
            "diag": base_law_diagnostics(res), "eb": error_budget(task, episodes),
            "fa": friction_authority(task, episodes), "tv": tv}


def run_training_study(runs: list[str], episodes: int = 48, exploration: str | None = None, ship_to: str | None = None,
                       workers: int = 2, progress: bool = True, made_by: str = "ehss training-report") -> TrainingStudy:
    """Evaluate the finished runs under the ``runs`` folders and analyse them; optionally ship the chosen policies.

    Args:
        runs: folders of run folders (each run folder as ``ehss train`` writes it).
        episodes: held-out episodes per task.
        exploration: the exploration-noise study's JSON, or None (a missing file is left out too).
        ship_to: copy the chosen residual policies' safe weights to this folder (e.g. ``ehss_gym/models``), or None.
        workers: evaluation worker processes.
        progress: show progress bars.
        made_by: the command, recorded with the evaluation and in the shipped models.

    Raises:
        ValueError: a missing ``runs`` folder, runs of one group with different settings, or no finished runs.
    """
    groups = group_runs([r for folder in runs for r in load_runs(folder)])
    if not groups:
        raise ValueError(f"no finished runs under {runs}")
    results, tasks = {}, []
    for task in sorted({k[1] for k in groups}):
        t0 = time.perf_counter()
        results.update(evaluate_groups({k: v for k, v in groups.items() if k[1] == task}, episodes, workers,
                                       progress, made_by))
        tasks.append({"wall": time.perf_counter() - t0, **task_analyses(task, results[task], groups, episodes)})
    shipped = ship(groups, ship_to, made_by) if ship_to else []
    study = read_json(exploration) if exploration and os.path.isfile(exploration) else None
    return TrainingStudy(groups, results, tasks, shipped, study, episodes, ship_to)


__all__ = ["TrainingStudy", "run_training_study", "task_analyses", "ONSET_PEAK", "TARGET_IMPROVEMENT",
           "TARGET_SEEDS", "TARGET_FRICTION", "read_json", "load_runs",
           "group_key", "group_runs", "label", "wall_to_best", "evaluate_groups", "residual_targets", "seed_scores",
           "has_noise", "base_law_diagnostics", "agent_env_kwargs", "agent_heldout_scenarios", "friction_authority",
           "error_budget", "period_log", "tv_sources", "mean_validation", "choose_variants", "ship"]
