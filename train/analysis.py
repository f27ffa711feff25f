"""``reports/training/TRAINING.md``: training cost, learning curves and held-out results of trained runs.

    python -m ehss_gym.train.analysis --runs runs/final runs/final_ppo --out reports/training --ship ehss_gym/models

Reads every run folder under the ``--runs`` folders (those with ``summary.json``), groups them by
(agent, task, n),
and:

1. tabulates the training cost per seed (wall time of the whole run and to the kept policy);
2. plots the learning curves (validation score, RMSE and control TV ratios to the base law) as a PNG;
3. evaluates each group's kept (best-on-validation) policies, loaded from their safe weights, with the
   evaluation harness (:func:`ehss_gym.evaluation.harness.evaluate`) on its held-out suite (seeds disjoint from
   training and from the validation block used for model selection) and on the paper's scenario, next
   to the scripted CLF laws n = 2, 4, 6; the primary score, its 95 % bootstrap CI (over seeds and
   episodes), the improvement over the best CLF with its CI, and the ratios of control TV, friction-window
   peak error and RMSE to the policy's base law;
4. with ``--ship``, copies the residual policies' safe weights to the models folder as
   ``<agent>-<task>-n<n>-seed<k>`` (every seed, so the harness reports them with CIs over seeds).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import os
import sys
import time

import numpy as np

from ehss_gym.core.util import atomic_write, atomic_write_text

COMMAND = "python -m ehss_gym.train.analysis"
ONSET_PEAK = 0.01  # [s] a friction-window peak this soon after the switch-on is the torque step's transient


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
        cfg, summ, hist = (json.load(open(p, encoding="utf-8")) for p in paths)
        out.append({"dir": d, "config": cfg, "summary": summ, "history": hist})
    return out


def group_key(run: dict) -> tuple:
    """(agent, task, n, variant): variant is the run's --hp overrides as compact JSON ("" for none)."""
    c = run["config"]
    hp = c.get("hp") or {}
    return c["agent"], c["task"], int(c["n"]), json.dumps(hp, sort_keys=True, separators=(",", ":")) if hp else ""


def group_runs(runs: list[dict]) -> dict[tuple, list[dict]]:
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
# Figure


def plot_curves(groups: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = list(groups)
    fig, axes = plt.subplots(3, len(keys), figsize=(4.2 * len(keys), 8.0), squeeze=False, sharex="col")
    rows = (("score", "validation score (ref. CLF n=2 = 1)"), ("rel_rmse", "RMSE / base law"),
            ("rel_tv", "control TV / base law"))
    for j, k in enumerate(keys):
        for i, (field_, ylabel) in enumerate(rows):
            ax = axes[i][j]
            for r in groups[k]:
                h = r["history"]
                ax.plot([x["step"] / 1e3 for x in h], [x[field_] for x in h], lw=1, marker=".",
                        label=f"seed {r['config']['seed']}")
            ax.axhline(1.0, color="k", lw=0.8, ls="--")
            ax.set_ylabel(ylabel, fontsize=8)
            if i == 0:
                ax.set_title(label(k), fontsize=9)
            if i == 2:
                ax.set_xlabel("agent steps [thousands]")
            ax.tick_params(labelsize=7)
        axes[0][j].legend(fontsize=6)
    fig.suptitle(f"Learning curves on the validation scenarios (lower is better); made by: {COMMAND}", fontsize=8)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110))
    plt.close(fig)


# ---------------------------------------------------------------------------------------------------
# Evaluation


def evaluate_groups(groups: dict, episodes: int, workers: int, progress: bool):
    """Run the evaluation harness on every task that has runs; returns {task: Results}."""
    from ehss_gym.evaluation import harness as ev

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
        out[task] = ev.evaluate(specs, cfg, workers=workers, progress=progress, command=COMMAND)
    return out


def has_noise(noise_std) -> bool:
    """True if any of the four measurement channels has sensor noise."""
    return any(v > 0 for v in noise_std)


def base_law_diagnostics(results) -> dict:
    """What the reference law's error is made of on the held-out suite (where a residual could gain)."""
    from ehss_gym.evaluation import harness as ev

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
    """The residual agent's env settings for ``task`` (n = 2): the loop its diagnostics must be measured in."""
    from ehss_gym.agents.specs import env_kwargs_for, get_spec

    return env_kwargs_for(get_spec("residual-ppo"), task, 2)


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
    from ehss_gym.core.scenarios import heldout_scenarios
    from ehss_gym.core.sim import simulate_batch
    from ehss_gym.envs import EHSSTrackingEnv

    tmpl = EHSSTrackingEnv(**{k: v for k, v in agent_env_kwargs(task).items() if k != "mode"}).scenario_template
    scs = [sc.replace(log_interval=sc.control_period, noise_std=(0.0, 0.0, 0.0, 0.0))
           for sc in heldout_scenarios(episodes, tmpl)]
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
    from ehss_gym.core.scenarios import heldout_scenarios
    from ehss_gym.core.sim import simulate_batch
    from ehss_gym.envs import EHSSTrackingEnv

    tmpl = EHSSTrackingEnv(**{k: v for k, v in agent_env_kwargs(task).items() if k != "mode"}).scenario_template
    scs = [sc.replace(log_interval=sc.control_period) for sc in heldout_scenarios(episodes, tmpl)]
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
    from ehss_gym.agents.safeweights import load_policy

    from ehss_gym.core.scenarios import heldout_scenarios

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
    return float(np.mean([r["summary"]["best_validation"]["score"] for r in rs]))


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


def ship(groups: dict, models_dir: str) -> list[str]:
    """Copy the kept policies of every seed of the chosen residual groups (:func:`choose_variants`) to
    ``models_dir`` as ``<agent>-<task>-n<n>-seed<k>``."""
    from ehss_gym.agents.safeweights import load_policy, model_paths
    from ehss_gym.agents.specs import resolved_env_kwargs

    written = []
    os.makedirs(models_dir, exist_ok=True)
    for base, k in sorted(choose_variants(groups).items()):
        rs = groups[k]
        for r in rs:
            stem = os.path.join(r["dir"], "best", "policy")
            load_policy(stem)  # refuse to ship anything that does not load
            st, js = model_paths(stem)
            name = f"{label(base + ('',))}-seed{r['config']['seed']}"
            with open(st, "rb") as f:
                blob = f.read()
            with open(js, encoding="utf-8") as f:
                cfg = json.load(f)
            cfg["name"] = name
            cfg["env_kwargs"] = resolved_env_kwargs(cfg["env_kwargs"])  # pin the env defaults it was trained with
            cfg["metadata"] = {"run_name": r["summary"]["run_name"], "seed": r["config"]["seed"],
                               "hp_overrides": r["config"].get("hp") or {},
                               "step": r["summary"]["best_step"], "validation": r["summary"]["best_validation"],
                               "agent_spec": r["config"]["agent_spec"], "timesteps": r["config"]["timesteps"],
                               "made_by": f"ehss train (run {r['summary']['run_name']}); shipped by {COMMAND}"}
            dst = os.path.join(models_dir, name)
            atomic_write(dst + ".safetensors", lambda f, b=blob: f.write(b))
            atomic_write_text(dst + ".json", json.dumps(cfg, indent=1, sort_keys=True) + "\n")
            load_policy(dst)
            written.append(dst)
    return written


# ---------------------------------------------------------------------------------------------------
# Markdown


def _f(x, d=3):
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    if isinstance(x, float):
        return f"{x:.{d}g}" if abs(x) < 1e-2 or abs(x) >= 1e4 else f"{x:.{d}f}"
    return str(x)


def _table(header, rows) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(_f(v) for v in row) + " |" for row in rows]
    return "\n".join(out)


def markdown(groups, results, noise, args, shipped, figure, wall_eval) -> str:
    from ehss_gym.agents.specs import AGENTS

    lines = ["# Training: residual PPO and pure PPO on EHSSTracking-v0",
             "",
             f"Generated by `{COMMAND} --runs {' '.join(args.runs)} --out {args.out} --episodes {args.episodes}"
             + (f" --ship {args.ship}" if args.ship else "") + "` from the run folders that `ehss train` wrote "
             "(commands below). Do not edit by hand.", ""]
    lines += ["## Runs", ""]
    for k, rs in groups.items():
        c = rs[0]["config"]
        seeds = ",".join(str(r["config"]["seed"]) for r in rs)
        hp = "".join(f" --hp '{key}={json.dumps(v)}'" for key, v in sorted((c.get("hp") or {}).items()))
        lines.append(f"- `{label(k)}`: `ehss train --agent {c['agent']} --task {c['task']} --n {c['n']} --seeds "
                     f"{seeds} --timesteps {c['timesteps']} --eval-freq {c['eval_freq']} --eval-episodes "
                     f"{c['eval_episodes']}{hp}`")
    lines += ["", "## Hyperparameters", "",
              "From `agents/specs.py` (`AGENTS`, reasons in the comments there); every run's exact "
              "settings are in its `config.json`.", ""]
    fields_ = [f for f in AGENTS["residual-ppo"].as_dict() if f not in ("name",)]
    lines.append(_table(["hyperparameter"] + list(AGENTS), [[f] + [json.dumps(AGENTS[a].as_dict()[f])
                                                                 for a in AGENTS] for f in fields_]))
    lines += ["", "Observations and rewards are normalised by VecNormalize (clip 10); the residual agent's "
              "action net is zero-initialised, so its deterministic policy at step 0 is exactly the base law "
              "(the step-0 validation score equals the base law's in every run).", ""]
    if noise:
        lines += ["## Initial exploration noise", "",
                  f"Measured by `{noise['command']}` (seeds {noise['seeds']}, {noise['episodes']} validation "
                  f"episodes, {noise['timesteps']} steps per candidate, evaluation every {noise['eval_freq']} "
                  "steps, constant learning rate as in the early phase of an annealed run). *Exploration "
                  "score*: the untrained residual sampled as in PPO's rollouts; *early scores*: deterministic "
                  "evaluations during the short run (1 = the base law, lower is better).", ""]
        lines.append(_table(["log_std_init", "std [mA]", "exploration score", "early evaluation scores (per seed)",
                             "mean early", "worst early", "below base law?"],
                            [[r["log_std_init"], r["std_mA"], r["explore_score"],
                              "; ".join(", ".join(f"{x:.3f}" for x in v) for v in r["early_scores"].values()),
                              r["mean_early_score"], r["worst_early_score"], "yes" if r["below_base"] else "no"]
                             for r in noise["rows"]]))
        safe = noise["largest_safe_log_std_init"]
        lines += ["", "Largest log_std_init whose early evaluations never fell below the base law: "
                  f"{'none of the candidates' if safe is None else _f(safe)}"
                  f"; the residual agent uses {_f(AGENTS['residual-ppo'].log_std_init)} (the reasons are in "
                  "`agents/specs.py`"
                  + ("; the validation comparison of log_std_init variants is in the training-cost table and under "
                     "Shipped models)." if any("log_std_init" in k[3] for k in groups) else
                     "; this report has no log_std_init variant runs).") , ""]
    lines += ["## Training cost", "",
              "Wall time of each seed on this machine (2 cores shared with other jobs; one process per seed, one "
              "torch thread), including the periodic validation episodes. *To kept policy*: up to the "
              "evaluation that selected the shipped/evaluated policy.", ""]
    rows = []
    for k, rs in groups.items():
        for r in rs:
            s = r["summary"]
            rows.append([label(k), r["config"]["seed"], s["timesteps"], s["wall_s"] / 60, wall_to_best(r) / 60,
                         s["best_step"], s["best_validation"]["score"]])
    lines.append(_table(["policy", "seed", "steps", "wall [min]", "to kept policy [min]", "kept step",
                         "validation score"], rows))
    lines += ["", f"![learning curves]({os.path.basename(figure)})", "",
              f"`{os.path.basename(figure)}`: validation score, RMSE and control-TV ratios to the base law against "
              f"training steps, per seed (made by `{COMMAND}`).", ""]
    for task, res in results.items():
        lines += [f"## Held-out results, {task} task", "",
                  f"The evaluation harness (`ehss_gym.evaluation.harness.evaluate`) on its held-out suite "
                  f"({args.episodes} episodes of 2 s, scenario seeds disjoint from training and from the validation "
                  "block) and on the paper's 20 s scenario. Primary score: 0.5 RMSE/RMSE_ref + 0.5 TV/TV_ref per "
                  "episode (reference: the CLF law n = 2 at the env defaults; lower is better). CI: 95 % "
                  "percentile bootstrap, over training seeds and episodes for learned policies.", ""]
        rows = []
        for d in res.summary:
            lo = d.get("score_mean_lo_both", d["score_mean_lo"])
            hi = d.get("score_mean_hi_both", d["score_mean_hi"])
            rows.append([d["suite"], d["policy"], d["n_runs"], d["n_episodes"], d["score_mean"],
                         f"[{_f(lo)}, {_f(hi)}]", d["score_iqm"], d["rmse"], d["max_abs_e_friction"], d["tv_u_rate"],
                         d["divergence_rate"], d["rank"]])
        lines.append(_table(["suite", "policy", "seeds", "episodes", "score (mean)", "95 % CI", "IQM", "RMSE",
                             "max |e| friction", "TV [mA/s]", "diverged", "rank"], rows))
        lines += ["", "Learned policies against the best CLF law at their own settings (improvement = 1 - "
                  "score/score_best with both scores normalised by the CLF n = 2 at those settings, the score "
                  "reference; CI over seeds and episodes, paired episodes) and against their own base law (ratios "
                  "of means over the episodes; friction ratio over episodes with friction):", ""]
        rows = []
        for c in res.comparisons:
            rows.append([c["suite"], c["policy"], c["n_runs"], c["score_reference"], c["score_mean"], c["best_clf"],
                         c["best_clf_score_mean"], c["improvement"],
                         f"[{_f(c['improvement_lo'])}, {_f(c['improvement_hi'])}]", c["base_law"],
                         c.get("rmse_ratio"), c.get("tv_ratio"), c.get("friction_peak_ratio")])
        lines.append(_table(["suite", "policy", "seeds", "score reference", "score", "best CLF", "its score",
                             "improvement", "95 % CI", "base law", "RMSE ratio", "TV ratio", "friction peak ratio"],
                            rows))
        lines += ["", "Targets of the residual policies on the held-out suite (from the table above):", ""]
        means = {(d["suite"], d["policy"]): d for d in res.summary}
        for c in res.comparisons:
            if c["suite"] != "heldout" or not c["policy"].startswith("residual-ppo"):
                continue
            imp_ok = c["improvement"] >= 0.2 and c["improvement_lo"] > 0 and c["n_runs"] >= 5
            tv = c.get("tv_ratio", math.nan)
            fr = c.get("friction_peak_ratio", math.nan)
            pol, best = means[("heldout", c["policy"])], means[("heldout", c["best_clf"])]
            lines.append(f"- `{c['policy']}` ({c['n_runs']} seeds): improvement over {c['best_clf']} "
                         f"{c['improvement']:+.1%} (95 % CI [{c['improvement_lo']:+.1%}, {c['improvement_hi']:+.1%}]) "
                         f"-> target (>= 20 %, CI excluding 0, >= 5 seeds) {'met' if imp_ok else 'NOT met'}; "
                         f"control TV {tv:.3f} x its base law -> {'met' if tv <= 1 else 'NOT met'}; friction-window "
                         f"peak {fr:.3f} x its base law -> halving {'met' if fr <= 0.5 else 'NOT met'}. Against the "
                         f"best CLF itself (means over the episodes): RMSE {pol['rmse'] / best['rmse']:.3f} x, control "
                         f"TV {pol['tv_u_rate'] / best['tv_u_rate']:.3f} x.")
        per_seed = []
        for d in res.specs:
            if not d.learned:
                continue
            for i in range(len(d.runs)):
                sel = [r for r in res.rows if r["policy"] == d.name and r["run"] == i and r["suite"] == "heldout"]
                if sel:
                    per_seed.append([d.name, os.path.basename(os.path.dirname(os.path.dirname(str(d.runs[i])))),
                                     float(np.mean([r["score"] for r in sel]))])
        if per_seed:
            lines += ["", "Held-out score of each training seed:", ""]
            lines.append(_table(["policy", "run", "score (mean over episodes)"], per_seed))
        diag = base_law_diagnostics(res)
        lines += ["", f"Reference law on this suite: mean saturation {diag['saturation_mean']:.3f}; its control TV "
                  f"ranges from {_f(diag['tv_rate_min'])} to {_f(diag['tv_rate_max'])} mA/s, median "
                  f"{_f(diag['tv_rate_median_noisy'])} mA/s on the {diag['noisy_episodes']} episodes with sensor "
                  f"noise and {_f(diag['tv_rate_median_clean'])} mA/s on the "
                  f"{diag['episodes'] - diag['noisy_episodes']} without: on the latter, any jitter of a residual "
                  "weighs heavily in the per-episode TV ratio of the score.", ""]
        eb = error_budget(task, args.episodes)
        lines += ["Where the reference law's squared error lies on this suite (simulated at the control rate): "
                  f"{eb['start_share']:.0%} in the first 50 ms (start-up transient; the applied current is at the "
                  f"limit on {eb['start_saturation']:.0%} of those control steps), {eb['friction_share']:.0%} during "
                  f"friction events (+50 ms), {eb['other_share']:.0%} elsewhere. Median delay from a friction "
                  f"switch-on to the event's largest |e|: {eb['peak_delay_median'] * 1e3:.2f} ms over "
                  f"{eb['events']} events.", ""]
        fa = friction_authority(task, args.episodes)
        lines += ["How much of the friction peak a residual can reach (the same episodes without sensor noise): "
                  f"on the {fa['events']} of {fa['all_events']} friction events whose window peak comes within "
                  f"{ONSET_PEAK * 1e3:g} ms of the switch-on (median {fa['rise_median'] * 1e3:.2f} ms), the reference "
                  "law already applies the full current limit in the direction that opposes the error on a median "
                  f"{fa['at_limit_share']:.0%} of the control steps before the peak. There a "
                  "residual cannot add current; only acting *before* the switch-on could (the env's oracle "
                  "feed-forward, which knows the event in advance, halves the peak; the same doublet started at "
                  "the switch-on does not, see docs/ENV.md).", ""]
        rows = []
        for k, rs in groups.items():
            if k[1] == task and rs[0]["config"]["env_kwargs"]["mode"] == "residual":
                ts = tv_sources([os.path.join(r["dir"], "best", "policy") for r in rs], args.episodes)
                rows.append([label(k), ts["policies"], ts["episodes"], ts["tv_ratio"], ts["own_share_of_added"],
                             ts["own_share_of_total"], ts["crossings_ratio"], ts["rmse_ratio"]])
        if rows:
            lines += ["Where the residuals' added control TV comes from: each seed's kept policy and its base law "
                      "on the held-out episodes with sensor noise (where the suite's TV is), logged at every "
                      "control period (`period_log`); sums over seeds and episodes. *Own steps*: sum |r_k - r_(k-1)| "
                      "of the residual current. A share of the added TV well below 1 means the added TV is the base "
                      "law's own switching in the state the residual drives the loop into, which no penalty on the "
                      "action's changes reaches (docs/ENV.md, \"Residual PPO settings\"); sign changes of s are "
                      "where the law's sign(s) term switches.", ""]
            lines.append(_table(["policy", "seeds", "episodes", "TV ratio", "own steps / added TV",
                                 "own steps / total TV", "sign changes of s ratio", "RMSE ratio"], rows))
            lines.append("")
        lines += [f"Evaluation wall time: {wall_eval[task]:.0f} s.", ""]
    if shipped:
        total = sum(os.path.getsize(p + ext) for p in shipped for ext in (".safetensors", ".json"))
        chosen = choose_variants(groups)
        lines += ["## Shipped models", "",
                  "Per (task, n), the residual runs whose kept policies have the best mean *validation* score "
                  "(the selection never looks at the held-out suite above):", ""]
        lines += [f"- `{label(b + ('',))}`: `{label(k)}` (mean validation score {mean_validation(groups[k]):.3f}"
                  + "".join(f"; `{label(o)}` {mean_validation(groups[o]):.3f}" for o in groups
                            if o[:3] == b and o != k) + ")" for b, k in sorted(chosen.items())]
        lines += ["",
                  f"{len(shipped)} policies in `{args.ship}` ({total / 1e3:.0f} kB in total), safe weights "
                  "(`.safetensors` + `.json`, loaded by `ehss_gym.agents.safeweights.load_policy` without unpickling): "
                  + ", ".join(f"`{os.path.basename(p)}`" for p in shipped) + ". `ehss evaluate` picks them up "
                  "as one policy per name with the seeds as training runs.", ""]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog=COMMAND, description=__doc__.split("\n")[0])
    p.add_argument("--runs", nargs="+", default=[os.path.join("runs", "final")], help="folders of run folders")
    p.add_argument("--out", default=os.path.join("reports", "training"))
    p.add_argument("--episodes", type=int, default=48, help="held-out episodes of the evaluation")
    p.add_argument("--noise", default=os.path.join("reports", "training", "noise_study.json"))
    p.add_argument("--ship", default=None, help="copy the residual policies' safe weights here (e.g. ehss_gym/models)")
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    try:
        groups = group_runs([r for folder in args.runs for r in load_runs(folder)])
    except ValueError as exc:
        print(f"{COMMAND}: error: {exc}", file=sys.stderr)
        return 2
    if not groups:
        print(f"{COMMAND}: error: no finished runs under {args.runs}", file=sys.stderr)
        return 2
    os.makedirs(args.out, exist_ok=True)
    figure = os.path.join(args.out, "learning_curves.png")
    plot_curves(groups, figure)
    workers = args.workers or 2
    results, wall_eval = {}, {}
    for task in sorted({k[1] for k in groups}):
        t0 = time.perf_counter()
        results.update(evaluate_groups({k: v for k, v in groups.items() if k[1] == task}, args.episodes, workers,
                                       not args.no_progress))
        wall_eval[task] = time.perf_counter() - t0
    shipped = ship(groups, args.ship) if args.ship else []
    noise = json.load(open(args.noise, encoding="utf-8")) if args.noise and os.path.isfile(args.noise) else None
    atomic_write_text(os.path.join(args.out, "TRAINING.md"),
                      markdown(groups, results, noise, args, shipped, figure, wall_eval))
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["task", "suite", "policy", "run", "episode", "score", "rmse", "max_abs_e_friction", "tv_u_rate",
                "diverged"])
    for task, res in results.items():
        for r in res.rows:
            w.writerow([task, r["suite"], r["policy"], r["run"], r["episode"], r["score"], r["rmse"],
                        r["max_abs_e_friction"], r["tv_u_rate"], r["diverged"]])
    atomic_write_text(os.path.join(args.out, "episodes.csv"), buf.getvalue())
    summary = {task: {"summary": res.summary, "comparisons": res.comparisons} for task, res in results.items()}
    atomic_write_text(os.path.join(args.out, "results.json"), json.dumps(summary, indent=1, default=str) + "\n")
    print(f"wrote {os.path.join(args.out, 'TRAINING.md')}, {figure}, episodes.csv, results.json"
          + (f"; shipped {len(shipped)} models to {args.ship}" if shipped else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
