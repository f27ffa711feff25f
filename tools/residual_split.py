"""Learned residuals' held-out and unmodelled figures beside the scripted policies', split by time window and with
each cause removed in turn: what their advantage over clf-n2 comes from.

Usage::

    python tools/residual_split.py --runs FOLDER [FOLDER ...] [--episodes 16]

Every learned group of the run folders (``ehss train``'s, or a training report's archive such as
``reports/training/compensators/runs``; grouped as ``ehss training-report`` groups them, each group's kept policies,
one per training seed) is split on its task.

Why: before a figure ranks a policy, the standard is to split it by time window and to remove one cause at a time;
``ehss factors --learned`` does this for the shipped groups only. This runs its study
(:func:`ehss_gym.study.factors_learned.run`: the episode variants, block figures and verdict rule) on the Table I
rig's held-out and unmodelled suites for any learned groups beside ``clf-n2``, ``dob-n2``, ``dcomp-n2`` and ``vinv-n2``,
and prints per suite, task and policy its figure as it is, by window (start-up, tracking, friction, the current class)
and with each cause removed (friction, model mismatch, noise; on the unmodelled suite also the valve, the delay and
the quantisation), then the rule's verdict: which removals take its advantage (or its loss) away.
"""

from __future__ import annotations

import argparse

from ehss_gym.evaluation.specs import scripted_specs
from ehss_gym.evaluation.suites import TASKS
from ehss_gym.study.factors_learned import SCRIPTED, run, verdict
from ehss_gym.study.training import group_runs, group_spec, load_runs


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", nargs="+", required=True, help="folders of run folders")
    ap.add_argument("--episodes", type=int, default=16, help="episodes per suite and task (default 16)")
    args = ap.parse_args(argv)
    groups = group_runs([r for folder in args.runs for r in load_runs(folder)])
    specs = scripted_specs(SCRIPTED, TASKS) + [group_spec(key, rs) for key, rs in groups.items()]
    out = run(TASKS, args.episodes, specs=specs)  # ehss factors --learned's study, on these policies
    for b in out["blocks"]:
        print(f"\n{b['suite']}/{b['task']} ({args.episodes} episodes; clf-n2 = 1)")
        variants = b["variants"]
        for n, asis in variants["as is"].items():
            if n == "clf-n2":
                continue
            w = asis["windows"]
            removed = {v: round(variants[v][n]["G"], 3) for v in variants if v != "as is"}
            vd = verdict(asis["G"], {v[3:]: variants[v][n]["G"] for v in variants if v != "as is"})
            print(f"  {n}: G {asis['G']:.3f}; by window: start-up {w['startup']:.3f}, tracking {w['tracking']:.3f}, "
                  f"friction {w['disturbance']:.3f}, current {w['current']:.3f}; with a cause removed: {removed}; "
                  f"{vd['gap']}, explained by {vd['explained']}, mostly {vd['mostly']}")


if __name__ == "__main__":
    main()
