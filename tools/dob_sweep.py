"""The disturbance observer's bandwidth for the scripted policy ``dob-n<k>``: a small sweep on training scenarios.

Usage: ``python tools/dob_sweep.py [--hz 5,10,20,40,80,160] [--episodes 48] [--n 2]``

Per task, the env's default loop (n = 2) with ``dob_hz`` = f_d against the same loop without the observer (the
reference law of the evaluation, ``clf-n2``) on the training scenarios ``sample_scenario(seed, template)``, seeds 0 ..
episodes-1 (never the held-out suite, whose seeds start at ``HELDOUT_SEED_BASE``), scored by the evaluation's ruler
(:mod:`ehss_gym.evaluation.scoring`: per class the geometric mean of the per-episode ratios, overall the geometric
mean of the classes).

The rule (written before the sweep was run):

1. admissible: on both tasks, no episode diverged or lost track and the mean saturation share is at most the ruler's
   gate (``SATURATION_GATE``);
2. one bandwidth serves both tasks: the admissible f_d with the lowest geometric mean over the tasks of the overall
   figure G;
3. a tie (within 1 % of that lowest value) goes to the lowest f_d, which lets the least sensor noise through.

The result is :data:`ehss_gym.controllers.clf.DOB_HZ`, until a tuning procedure replaces it.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from ehss_gym import simulate_batch
from ehss_gym.core.scenarios import HELDOUT_SEED_BASE, sample_scenario
from ehss_gym.envs.config import EnvConfig
from ehss_gym.evaluation.scoring import CLASSES, SATURATION_GATE, episode_log_ratios, figure_of

TASKS = ("velocity", "position")


def sweep_task(task: str, hz: list[float], episodes: int, n: int) -> dict:
    """{f_d: (G, {class: G_c}, failed episodes, mean saturation)} of one task (f_d = 0: the reference itself)."""
    assert episodes <= HELDOUT_SEED_BASE, "training seeds only"
    base = EnvConfig.from_kwargs({"task": task, "n": n}).template()
    scenarios = [sample_scenario(seed, base) for seed in range(episodes)]
    runs = {f: simulate_batch([sc.replace(dob_hz=f) for sc in scenarios]) for f in [0.0, *hz]}
    ref = [t.metrics() for t in runs[0.0]]
    out = {}
    for f, trs in runs.items():
        logs = {c: [] for c in CLASSES}
        ms = [t.metrics() for t in trs]
        for sc, m, r in zip(scenarios, ms, ref):
            for c, v in episode_log_ratios(m, r, any(x > 0 for x in sc.noise_std), sc.task).items():
                logs[c].append(v)
        g, gc = figure_of(logs)
        failed = sum(1 for m in ms if m["diverged"] or m["lost_track"])
        out[f] = (g, gc, failed, float(np.mean([m["saturation"] for m in ms])))
    return out


def choose(results: dict, hz: list[float]) -> float:
    """The rule of the module docstring: the admissible f_d with the lowest geometric mean of G over the tasks."""
    ok = [f for f in hz if all(r[f][2] == 0 and r[f][3] <= SATURATION_GATE for r in results.values())]
    score = {f: math.exp(np.mean([math.log(r[f][0]) for r in results.values()])) for f in ok}
    best = min(score.values())
    return min(f for f in ok if score[f] <= 1.01 * best)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--hz", default="5,10,20,40,80,160", help="comma-separated f_d values [Hz]")
    p.add_argument("--episodes", type=int, default=48, help="training scenarios per task (seeds 0..episodes-1)")
    p.add_argument("--n", type=int, default=2, help="CLF power factor")
    a = p.parse_args()
    hz = [float(x) for x in a.hz.split(",")]
    results = {t: sweep_task(t, hz, a.episodes, a.n) for t in TASKS}
    print("| task | f_d [Hz] | G | " + " | ".join(CLASSES) + " | failed | saturation |")
    print("|---|---|---|" + "---|" * len(CLASSES) + "---|---|")
    for t, res in results.items():
        for f, (g, gc, failed, sat) in res.items():
            cls = " | ".join(f"{gc[c]:.3f}" if c in gc else "-" for c in CLASSES)
            print(f"| {t} | {f:g} | {g:.3f} | {cls} | {failed} | {sat:.4f} |")
    pooled = {f: math.exp(np.mean([math.log(r[f][0]) for r in results.values()])) for f in hz}
    print("geometric mean of G over the tasks: " + ", ".join(f"{f:g} Hz {v:.3f}" for f, v in pooled.items()))
    print(f"chosen f_d = {choose(results, hz):g} Hz")


if __name__ == "__main__":
    main()
