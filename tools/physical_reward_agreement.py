"""How well the physical reward's episode return orders fixed policies as the ruler's overall figure does.

Usage: ``python tools/physical_reward_agreement.py [--episodes 8]``

On the first ``--episodes`` episodes per task of ``ehss evaluate``'s unmodelled suite, eight fixed policies at agent
period 20 (the base law; constant residuals of 0.5 and 0.05 mA; residuals alternating +-0.2 mA every step and +-0.1 mA
every 10 steps; the disturbance observer at 20 Hz; the delay compensation and the valve inverse knowing the episode's
effects) are run in the env with the physical reward (``reward_weights={"physical": 1}``, docs/RL.md). Printed: the
share of the pairs of policies whose overall figures (the ruler's, physical floors) differ by more than 0, 1, 2 and 5 %
that the episode return orders alike, and on how many episodes the five policies of the reward's test (the base law,
the 0.5 mA bias, the +-0.2 mA chatter, the observer, the delay compensation) come out in the ruler's order; for the
reward as built (its scales: each floor plus the base law's level) and for the same formula with the floors alone as
its scales (recomputed from each step's sums, which the script records from the env's buffers).
"""

from __future__ import annotations

import argparse
import itertools
import math

import numpy as np

from ehss_gym.core.layout import M_DST_STEPS, M_DST_SUM_ABS, M_SUM_U2, M_TRK_STEPS, M_TRK_SUM_ABS, M_TRK_SUM_E2, M_TV_U
from ehss_gym.core.resolution import CURRENT_FLOOR, ERROR_RESOLUTION, TV_FLOOR
from ehss_gym.envs import EHSSTrackingEnv
from ehss_gym.envs.buffers import (
    F_RPHYS,
    N_RPHYS,
    P_K,
    P_N,
    P_NCLS,
    P_NDST,
    P_NTRK,
    S_DST_ABS,
    S_DST_N,
    S_EMAX,
    S_N,
    S_TRK_ABS,
    S_TRK_E2,
    S_TRK_N,
    S_TV0,
    S_U2,
)
from ehss_gym.evaluation.scoring import episode_log_ratios
from ehss_gym.evaluation.suites import EvalConfig, build_episodes

PHYSICAL_ONLY = {"track": 0.0, "effort": 0.0, "rate": 0.0, "physical": 1.0}
AP = 20
FIVE = ("base", "bias", "chatter", "dob", "delay")
MARGINS = (0.0, 0.01, 0.02, 0.05)


def policies(um) -> dict:
    """Name -> (action of agent step k, env settings)."""
    return {"base": (lambda k: 0.0, {}), "bias": (lambda k: 0.05, {}), "chatter": (lambda k: 0.02 * (-1) ** k, {}),
            "dob": (lambda k: 0.0, {"dob_hz": 20.0}), "delay": (lambda k: 0.0, {"reference_delay": float(um.delay)}),
            "valve": (lambda k: 0.0, {"inverse_threshold": um.threshold, "inverse_hysteresis": um.hysteresis}),
            "small bias": (lambda k: 0.005, {}), "slow chatter": (lambda k: 0.01 * (-1) ** (k // 10), {})}


def run(task: str, physical: dict, act, **kw) -> tuple[float, dict, float]:
    """(return, end-of-episode metrics, the floor-only form's return) of one policy on one pinned episode."""
    env = EHSSTrackingEnv(task=task, agent_period=AP, reward_weights=PHYSICAL_ONLY, **kw)
    env.reset(options={"scenario": env.unwrapped.scenario_template.replace(**physical)})
    lanes, e, h = env.unwrapped._lanes, ERROR_RESOLUTION[task], env.config.control_period
    rp = lanes.F[0, F_RPHYS:F_RPHYS + N_RPHYS].copy()
    ret, floor_only, k = 0.0, 0.0, 0
    while True:
        _, r, term, trunc, info = env.step(np.array([act(k)], np.float32))
        ret, k = ret + r, k + 1
        st, acc = lanes.stats[0], lanes.acc[0]
        n, ntrk, ndst = st[S_N], acc[M_TRK_STEPS] - st[S_TRK_N], acc[M_DST_STEPS] - st[S_DST_N]
        x = 0.0
        if ntrk > 0:
            x += ntrk / rp[P_NTRK] * (0.25 * math.log1p((acc[M_TRK_SUM_E2] - st[S_TRK_E2]) / ntrk / e**2)
                                      + 0.5 * math.log1p((acc[M_TRK_SUM_ABS] - st[S_TRK_ABS]) / (ntrk * h) / e))
        if ndst > 0:
            x += ndst / rp[P_NDST] * 0.5 * (math.log1p(st[S_EMAX] / e)
                                            + math.log1p((acc[M_DST_SUM_ABS] - st[S_DST_ABS]) / (ndst * h) / e))
        x += n / rp[P_N] * (0.5 * math.log1p((acc[M_TV_U] - st[S_TV0]) / (n * h) / TV_FLOOR)
                            + 0.25 * math.log1p((acc[M_SUM_U2] - st[S_U2]) / n / CURRENT_FLOOR**2))
        floor_only -= rp[P_K] / rp[P_NCLS] * x
        if term or trunc:
            return ret, info["metrics"], floor_only


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--episodes", type=int, default=8, help="unmodelled-suite episodes per task (default 8)")
    a = p.parse_args()
    tally = {form: {"pairs": {m: [0, 0] for m in MARGINS}, "five": 0} for form in ("scaled", "floor only")}
    n_eps = 0
    for task in ("velocity", "position"):
        for ep in build_episodes(EvalConfig(suites=("unmodelled",), tasks=(task,), heldout_episodes=a.episodes)):
            ph = ep.physical
            runs = {name: run(task, ph, act, **kw) for name, (act, kw) in policies(ph["unmodelled"]).items()}
            noisy = any(v > 0.0 for v in ph["noise_std"])
            g = {n: float(np.mean(list(episode_log_ratios(m, runs["base"][1], noisy, task).values())))
                 for n, (_, m, _) in runs.items()}
            n_eps += 1
            for form, col in (("scaled", 0), ("floor only", 2)):
                ret = {n: r[col] for n, r in runs.items()}
                for x, y in itertools.combinations(runs, 2):
                    for m in MARGINS:
                        if abs(g[x] - g[y]) > math.log1p(m):
                            tally[form]["pairs"][m][1] += 1
                            tally[form]["pairs"][m][0] += (g[x] < g[y]) == (ret[x] > ret[y])
                tally[form]["five"] += sorted(FIVE, key=g.get) == sorted(FIVE, key=lambda n: -ret[n])
            print(f"{task} {ep.episode_id}: " + ", ".join(f"{n} {math.exp(g[n]):.3f}" for n in sorted(g, key=g.get)),
                  flush=True)
    for form, t in tally.items():
        pairs = "; ".join(f"> {100 * m:g} %: {ok}/{tot}" for m, (ok, tot) in t["pairs"].items())
        print(f"{form}: pairs ordered alike {pairs}; the five in the ruler's order on {t['five']}/{n_eps} episodes")


if __name__ == "__main__":
    main()
