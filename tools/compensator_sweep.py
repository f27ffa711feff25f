"""The compensators' sweep alone, with every candidate's figures: the last stage of ``ehss baselines``.

Usage: ``python tools/compensator_sweep.py [--episodes 48] [--plant FILE --law-settings FILE]``

The rule and its history are in :mod:`ehss_gym.study.compensators`; ``ehss baselines`` runs the same sweep on the
law it has just tuned and writes the chosen sizes into ``law_settings.json``. This tool prints the whole grid per
task (G, the class figures, failed episodes, saturation) and the chosen size, on Table I's built-in laws or on a
plant with its law table.
"""

from __future__ import annotations

import argparse

from ehss_gym.core.rig import as_rig
from ehss_gym.envs.law_table import load_law_table
from ehss_gym.evaluation.scoring import CLASSES
from ehss_gym.evaluation.suites import TASKS
from ehss_gym.study.baselines import EPISODE_SECONDS, EPISODES
from ehss_gym.study.compensators import tune_compensators


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--episodes", type=int, default=EPISODES, help="training scenarios per task (seeds 0..episodes-1)")
    p.add_argument("--plant", default=None, help="a plant file or name (default Table I)")
    p.add_argument("--law-settings", default=None, help="the plant's law table (ehss baselines --plant writes it)")
    a = p.parse_args()
    env = {}
    if a.plant:
        env["plant"] = as_rig(a.plant)
    if a.law_settings:
        env["law_settings"] = load_law_table(a.law_settings)
    res = tune_compensators(TASKS, a.episodes, EPISODE_SECONDS, env)
    for kind in res[TASKS[0]]:
        keys = list(res[TASKS[0]][kind]["chosen"])
        print(f"\n{kind}: | task | " + " | ".join(keys) + " | G | " + " | ".join(CLASSES) + " | failed | saturation |")
        for task in TASKS:
            for e in res[task][kind]["evaluations"]:
                cls = " | ".join(f"{e['classes'][k]:.3f}" if k in e["classes"] else "-" for k in CLASSES)
                vals = " | ".join(f"{e['point'][k]:g}" for k in keys)
                print(f"| {task} | {vals} | {e['objective']:.4f} | {cls} | {e['n_failed']} | {e['saturation']:.4f} |")
        for task in TASKS:
            r = res[task][kind]
            print(f"{kind}, {task}: chosen {r['chosen']} (G {r['figure']:.4f}; lowest {r['best_figure']:.4f} at "
                  f"{r['best']})")


if __name__ == "__main__":
    main()
