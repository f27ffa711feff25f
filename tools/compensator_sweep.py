"""The compensators' sizes for the scripted policies ``dcomp-n<k>`` and ``vinv-n<k>``: a sweep on training scenarios.

Usage: ``python tools/compensator_sweep.py [--episodes 48]``

The two compensators of the unmodelled valve and sensors (docs/MODEL.md, "Compensating the unmodelled valve and
sensors") need the effects' sizes, which a causal controller does not know episode by episode: it knows only the
distribution the effects are drawn from. This sweep picks one size per compensator from the training distribution
with the effects on (``sample_scenario(seed, template, 2.0, UNMODELLED_DISTRIBUTION)``, the env's
``unmodelled_effects=True`` draw, seeds 0 .. episodes-1; never the held-out or unmodelled suites, whose seeds start at
``HELDOUT_SEED_BASE``).

The rule. Rules 1-3 and 5 were written before the first sweep; rule 4 was changed before the second (below):

1. the candidates: the reference delay ``reference_delay`` in {0, 0.5, 1, 1.5, 2, 2.5, 3} control samples (the
   distribution's delay is 1 or 2, mean 1.5); the valve inverse (``inverse_threshold``, ``inverse_hysteresis``) on the
   grid {0, 0.125, 0.25, 0.375, 0.5} x {0, 0.75, 1.5, 2.25, 3} % of rated current (the distribution's threshold is
   uniform in 0.25-0.5 %, mean 0.375 %; its hysteresis in 1.5-3 %, mean 2.25 %); each compensator alone on the env's
   default loop (n = 2);
2. the objective, per task: the evaluation ruler's overall figure G (physical floors) against the same loop without
   compensation (``clf-n2``) on the same episodes, with the failure gate (:func:`ehss_gym.study.baselines.objective`,
   the baselines' tuning objective);
3. admissible on a task: no episode of that task diverged or lost track and its mean saturation share is at most the
   ruler's gate;
4. each task its own size (the scripted policies take one row of settings per task, as ``dob-n2`` does): on each task
   the admissible candidate with the lowest G on that task;
5. a tie (within 1 % of that task's lowest G) goes to the smallest compensation (the smallest delay; the smallest
   threshold + hysteresis, then the smallest threshold): the least it adds to what the law does.

Rule 4's history. The first sweep (on the loop before the base laws were retuned, so its figures are not today's)
had a rule 4 asking for one size serving both tasks (the lowest geometric mean over the tasks of G). It chose a
delay of 1 sample (0.811 over the tasks: velocity 0.987, position 0.666) and no valve inverse: at the
distribution's mean the inverse gave 0.883 in velocity but 1.40 in position. An exploratory check on the 16
unmodelled validation episodes of the residual agents (not a training scenario of this sweep) then put the mean
inverse at 0.797 against clf-n2 in velocity, where ``dob-n2`` scored 0.867: the joint rule withheld the best causal
velocity compensation because of its cost in the other task. Rule 4 was made per task, as the observer's rows are,
before the sweep was rerun; the first sweep's rule and figures are kept here so that the change can be judged.

The results are the rows of :data:`ehss_gym.controllers.clf.COMPENSATOR_ROWS` (a compensator whose chosen size on a
task is none acts on the other task only).
"""

from __future__ import annotations

import argparse

from ehss_gym import simulate_batch
from ehss_gym.core.scenarios import UNMODELLED_DISTRIBUTION, sample_scenario
from ehss_gym.envs.config import EnvConfig
from ehss_gym.evaluation.scoring import CLASSES
from ehss_gym.study.baselines import objective

TASKS = ("velocity", "position")
DELAYS = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0)  # [control samples]
THRESHOLDS = (0.0, 0.125, 0.25, 0.375, 0.5)  # [% of rated current]
HYSTERESES = (0.0, 0.75, 1.5, 2.25, 3.0)  # [% of rated current]
SECONDS = 2.0


def candidates() -> dict[str, list[dict]]:
    """Compensator -> its candidate settings (rule 1), the uncompensated law first."""
    return {"dcomp": [{"reference_delay": d} for d in DELAYS],
            "vinv": [{"inverse_threshold": t, "inverse_hysteresis": h} for t in THRESHOLDS for h in HYSTERESES]}


def size(c: dict) -> tuple:
    """The tie order of rule 5: the smaller compensation first."""
    return (c.get("reference_delay", 0.0), c.get("inverse_threshold", 0.0) + c.get("inverse_hysteresis", 0.0),
            c.get("inverse_threshold", 0.0))


def sweep_task(task: str, cands: list[dict], episodes: int) -> list[dict]:
    """Per candidate the objective of rule 2 on one task (:func:`ehss_gym.study.baselines.objective`)."""
    tmpl = EnvConfig.from_kwargs({"task": task}).template()
    scs = [sample_scenario(s, tmpl, SECONDS, UNMODELLED_DISTRIBUTION) for s in range(episodes)]
    noisy = [any(v > 0.0 for v in sc.noise_std) for sc in scs]
    base = [t.metrics() for t in simulate_batch(scs)]
    return [objective([t.metrics() for t in simulate_batch([sc.replace(**c) for sc in scs])], base, noisy, task)
            for c in cands]


def choose(results: list[dict], cands: list[dict]) -> dict:
    """Rules 3-5 on one task's results (:func:`sweep_task`): the chosen candidate."""
    ok = [i for i in range(len(cands)) if not results[i]["failed"]]
    best = min(results[i]["figure"] for i in ok)
    return cands[min((i for i in ok if results[i]["figure"] <= 1.01 * best), key=lambda i: size(cands[i]))]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--episodes", type=int, default=48, help="training scenarios per task (seeds 0..episodes-1)")
    a = p.parse_args()
    for name, cands in candidates().items():
        results = {t: sweep_task(t, cands, a.episodes) for t in TASKS}
        keys = list(cands[0])
        print(f"\n{name}: | task | " + " | ".join(keys) + " | G | " + " | ".join(CLASSES) + " | failed | saturation |")
        for t, res in results.items():
            for c, o in zip(cands, res):
                cls = " | ".join(f"{o['classes'][k]:.3f}" if k in o["classes"] else "-" for k in CLASSES)
                vals = " | ".join(f"{c[k]:g}" for k in keys)
                print(f"| {t} | {vals} | {o['figure']:.4f} | {cls} | {o['n_failed']} | {o['saturation']:.4f} |")
        for t, res in results.items():
            print(f"{name}, {t}: chosen {choose(res, cands)}")


if __name__ == "__main__":
    main()
