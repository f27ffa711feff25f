"""A learned residual's unmodelled-suite figure beside the scripted policies', split by time window and with each
cause removed in turn: what its advantage over clf-n2 comes from.

Usage::

    python tools/residual_split.py --runs FOLDER [FOLDER ...] [--episodes 16]

Every learned group of the run folders (``ehss train``'s, or a training report's archive such as
``reports/training/compensators/runs``; grouped as ``ehss training-report`` groups them, each group's kept policies,
one per training seed) is split on its task.

Why: before a figure ranks a policy, the standard is to split it by time window and to remove one cause at a time;
``ehss factors --learned`` does this for the shipped groups only. This runs the same functions
(:mod:`ehss_gym.study.factors_learned`: its episode variants, block figures and verdict rule) on the Table I rig's
unmodelled suite for any learned groups beside ``clf-n2``, ``dob-n2``, ``dcomp-n2`` and ``vinv-n2``,
and prints per policy its figure as it is, by window (start-up, tracking, friction, the current class) and with each
cause removed (friction, model mismatch, noise, valve, delay, quantisation), then the rule's verdict: which removals
take its advantage away.
"""

from __future__ import annotations

import argparse

from ehss_gym.core.rig import as_rig
from ehss_gym.evaluation import EvalConfig
from ehss_gym.evaluation.harness import evaluate
from ehss_gym.evaluation.scoring import physical_floors
from ehss_gym.evaluation.specs import scripted_specs
from ehss_gym.evaluation.suites import build_episodes
from ehss_gym.study.factors_learned import SCRIPTED, _suite_task, variant_episodes, verdict
from ehss_gym.study.training import group_runs, group_spec, load_runs


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", nargs="+", required=True, help="folders of run folders")
    ap.add_argument("--episodes", type=int, default=16, help="unmodelled-suite episodes per task (default 16)")
    args = ap.parse_args(argv)
    groups = group_runs([r for folder in args.runs for r in load_runs(folder)])
    cfg = EvalConfig(suites=("unmodelled",), tasks=("velocity", "position"), heldout_episodes=args.episodes,
                     n_boot=100)
    specs = scripted_specs(SCRIPTED, cfg.tasks, cfg.law_settings)
    specs += [group_spec(key, rs) for key, rs in groups.items()]
    res = evaluate(specs, cfg, progress=False, episodes=variant_episodes(build_episodes(cfg)))
    floors = physical_floors(as_rig("table1"))
    for task in cfg.tasks:
        names = [s.name for s in res.specs if task in s.tasks]
        b = _suite_task(res.rows, names, "unmodelled", task, floors, [])
        print(f"\nunmodelled/{task} ({args.episodes} episodes; clf-n2 = 1)")
        for n in names:
            if n == "clf-n2":
                continue
            asis = b["variants"]["as is"][n]
            w = asis["windows"]
            removed = {v: round(b["variants"][v][n]["G"], 3) for v in b["variants"] if v != "as is"}
            vd = verdict(asis["G"], {v[3:]: b["variants"][v][n]["G"] for v in b["variants"] if v != "as is"})
            print(f"  {n}: G {asis['G']:.3f}; by window: start-up {w['startup']:.3f}, tracking {w['tracking']:.3f}, "
                  f"friction {w['disturbance']:.3f}, current {w['current']:.3f}; with a cause removed: {removed}; "
                  f"{vd['gap']}, explained by {vd['explained']}, mostly {vd['mostly']}")


if __name__ == "__main__":
    main()
