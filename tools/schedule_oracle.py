"""How much a gain-scheduling residual could find on top of a scripted law: its sigma and width chosen per episode in
hindsight, against the best fixed pair and the law as it is.

Usage::

    python tools/schedule_oracle.py [--policy eso-n2] [--task velocity] [--episodes 32] [--unmodelled | --nominal]
    python tools/schedule_oracle.py --policy clf-n4 --task position --nominal [--grid action]

Why: the residual agents' schedule action scales the law's boundary-layer width and sigma at the agent rate. Before a
residual is trained on top of a scripted law, this says how much that action could reach there: for each training
scenario (seeds 0 .. episodes-1, 2 s, drawn as ``ehss baselines`` draws them, with the unmodelled effects by default)
the law runs at every pair of a grid of factors on sigma (x0.3 .. x3) and on the width (the smoothing width and the
adaptive layer's gain together, x0.3 .. x10); per episode the pair with the lowest mean class log ratio against
clf-n2 is kept (hindsight: it knows the episode), and the kept episodes' figure is the ruler's G. Printed: the law as
it is, the best fixed pair (one pair for every episode: what a retuning of the law would reach) and the per-episode
choice, each against clf-n2 and against the law as it is. The choice is made on the episodes it is scored on, so it
is an upper bound of what a constant-per-episode schedule reaches, not of what a schedule that moves within an
episode could. The last line takes each class at its best pair of the grid (a class's windows differ: the tracking
window, the friction events, the noise-free and the noisy episodes), the reach of a schedule that changes the pair
between those windows, optimistic too: the effort and chatter classes run over whole episodes.

The law may have any n: a law of n = 4 or 6 runs at that n's tuned settings (sigma, width, reference bandwidth) on
the same scenarios, and its figures are still against clf-n2, which is what the held-out target of a residual on it
asks.
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np

from ehss_gym.controllers import parse_scripted
from ehss_gym.core.scenarios import DEFAULT_DISTRIBUTION, UNMODELLED_DISTRIBUTION, sample_scenario
from ehss_gym.core.settings import LAYER_GAIN_MAX
from ehss_gym.core.sim import simulate_batch
from ehss_gym.envs.config import EnvConfig
from ehss_gym.evaluation.scoring import episode_log_ratios, figure_of
from ehss_gym.study.compensators import training_set

SIGMA_FACTORS = (0.3, 0.5, 1.0, 2.0, 3.0)
WIDTH_FACTORS = (0.3, 1.0, 3.0, 10.0)
# --grid action: the schedule action's whole ranges (envs.actions.SCHEDULE_RANGES), log-spaced
ACTION_SIGMA_FACTORS = (0.1, 0.3, 1.0, 3.0, 10.0)
ACTION_WIDTH_FACTORS = (0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0, 1000.0)


def figure(logs: list[dict]) -> tuple[float, dict]:
    """The ruler's G and class figures of per-episode class log ratios."""
    per: dict = {}
    for d in logs:
        for c, v in d.items():
            per.setdefault(c, []).append(v)
    return figure_of(per)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--policy", default="eso-n2", help="a scripted CLF law's name (its loop settings on the task)")
    p.add_argument("--task", default="velocity", choices=("velocity", "position"))
    p.add_argument("--episodes", type=int, default=32, help="training scenarios (seeds 0..episodes-1)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--unmodelled", dest="unmodelled", action="store_true", default=True,
                   help="draw the unmodelled valve and sensor effects (default)")
    g.add_argument("--nominal", dest="unmodelled", action="store_false", help="the model's plant")
    p.add_argument("--grid", choices=("narrow", "action"), default="narrow",
                   help="the factors searched: narrow (sigma x0.3-3, width x0.3-10) or action (the schedule action's "
                        "whole ranges, sigma x0.1-10, width x0.1-1000)")
    a = p.parse_args(argv)
    kw = parse_scripted(a.policy, a.task)
    if kw is None:
        p.error(f"--policy must be a scripted CLF law's name, got {a.policy!r}")
    loop = {k: v for k, v in kw.items() if k != "mode"}  # the law's settings beyond clf-n2's
    dist = UNMODELLED_DISTRIBUTION if a.unmodelled else DEFAULT_DISTRIBUTION
    scs, noisy, floors, base = training_set(a.task, a.episodes, 2.0, distribution=dist)
    if kw["n"] != 2:  # the same draws on that n's tuned law (only the law's fields differ between templates)
        tmpl = EnvConfig.from_kwargs({"task": a.task, "n": kw["n"]}).template()
        scs = [sample_scenario(s, tmpl, 2.0, dist) for s in range(a.episodes)]
    law = scs[0]  # every scenario carries the template's law settings (sigma, width)
    pairs = list(itertools.product(*((SIGMA_FACTORS, WIDTH_FACTORS) if a.grid == "narrow" else
                                     (ACTION_SIGMA_FACTORS, ACTION_WIDTH_FACTORS))))
    logs = []  # per pair, per episode: the class log ratios against clf-n2 (None: failed)
    for fs, fw in pairs:
        change = {**loop, "sigma": law.sigma * fs, "smoothing": law.smoothing * fw,
                  "layer_gain": min(law.layer_gain * fw, LAYER_GAIN_MAX)}
        ms = [t.metrics() for t in simulate_batch([sc.replace(**change) for sc in scs])]
        logs.append([None if m["diverged"] or m["lost_track"] else episode_log_ratios(m, b, nz, a.task, floors)
                     for m, b, nz in zip(ms, base, noisy)])
    as_is = pairs.index((1.0, 1.0))
    if any(x is None for x in logs[as_is]):
        raise SystemExit(f"{a.policy} itself fails an episode on these scenarios: no figure to compare against")
    g0, c0 = figure(logs[as_is])
    whole = [i for i in range(len(pairs)) if all(x is not None for x in logs[i])]
    best = min(whole, key=lambda i: figure(logs[i])[0])
    gb, _ = figure(logs[best])
    chosen = []
    for e in range(a.episodes):
        ok = [i for i in range(len(pairs)) if logs[i][e]]
        chosen.append(logs[min(ok, key=lambda i: float(np.mean(list(logs[i][e].values()))))][e])
    gc, cc = figure(chosen)
    per_class = {c: min(figure(logs[i])[1][c] for i in whole) for c in c0}
    gk = float(np.exp(np.mean(np.log(list(per_class.values())))))
    print(f"{a.policy}, {a.task}, {a.episodes} training scenarios "
          f"({'with the unmodelled effects' if a.unmodelled else 'the model plant'}); G against clf-n2:")
    print(f"  as it is:                 {g0:.4f}  " + ", ".join(f"{k} {v:.3f}" for k, v in c0.items()))
    fs, fw = pairs[best]
    print(f"  best fixed pair:          {gb:.4f}  (sigma x{fs:g}, width x{fw:g}): {gb / g0:.3f}x the law as it is")
    print(f"  per episode, hindsight:   {gc:.4f}  " + ", ".join(f"{k} {v:.3f}" for k, v in cc.items())
          + f": {gc / g0:.3f}x the law as it is")
    print(f"  each class at its best:   {gk:.4f}  " + ", ".join(f"{k} {v:.3f}" for k, v in per_class.items())
          + f": {gk / g0:.3f}x the law as it is")


if __name__ == "__main__":
    main()
