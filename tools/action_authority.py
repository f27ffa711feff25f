"""The ideal corrections a residual would make on the unmodelled suite, from which the action modes' bounds are chosen.

Usage::

    python tools/action_authority.py [--episodes 32]

Per task, on the first ``--episodes`` episodes of ``ehss evaluate``'s unmodelled suite, at the env's defaults (n = 2):

- **the reference shift that compensates the sensor delay** d (1-2 samples in the suite): delta = -d h y_d', h the
  control period, y_d' the reference model's rate from the base law's run (logged every 1 ms); its RMS over the
  tracking windows (past the 0.2 s start-up) of all episodes, and the 99th percentile of its magnitude [output unit];
- **the current that does the same**: a constant residual of 1 mA moves the tracking error by k [output unit / mA]
  (the law rejects most of it: measured as the mean change of the measured error over the noise- and friction-free
  episodes' last second); the shift's current equivalent is |delta| / |k| [mA];
- **the dead band's and hysteresis's ideal inverse**: the current that jumps the valve's threshold and half its
  play, th + h/2 [mA], per episode;
- the ideal current correction per sample, |delta| / |k| + th + h/2: its RMS and 99th percentile [mA];
- **what the shift does**: the base law against the delay-compensating shift (the reference action with the oracle
  delta = -d h y_d' from the controller's view, agent period 20), the tracking-window RMSE of the true error.

The bounds of :mod:`ehss_gym.envs.actions` are twice the RMS (a sine's peak is sqrt(2) times its RMS), rounded up to
one significant digit; the share of samples whose ideal correction exceeds the bound is printed beside it.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from gymnasium.vector import AutoresetMode

from ehss_gym.core.layout import I_YD, L_T, L_YD, QUIET_STARTUP
from ehss_gym.core.sim import simulate_batch
from ehss_gym.envs import EHSSTrackingVectorEnv, EnvConfig
from ehss_gym.evaluation.suites import EvalConfig, build_episodes

AGENT_PERIOD = 20


def round_up(x: float) -> float:
    """x rounded up to one significant digit."""
    e = math.floor(math.log10(x))
    return math.ceil(x / 10**e) * 10**e


def run(task: str, eps: list, action: str, policy, friction_free: bool = False,
        bound: float | None = None) -> tuple[list, list]:
    """Roll the episodes out in the vector env (``action`` mode, ``action_bound`` ``bound``); per episode its metrics
    and the measured error at each agent step."""
    kw = {"task": task, "agent_period": AGENT_PERIOD, "action": action, "action_bound": bound}
    venv = EHSSTrackingVectorEnv(len(eps), autoreset_mode=AutoresetMode.DISABLED, **kw)
    tmpl = venv.scenario_template
    scs = []
    for ep in eps:
        phys = dict(ep.physical)
        if friction_free:
            phys.update(friction=(), noise_std=(0.0, 0.0, 0.0, 0.0))
        scs.append(tmpl.replace(**phys))
    venv.reset(seed=0, options={"scenario": scs})
    lanes = venv._lanes
    metrics: list = [None] * len(eps)
    errors = [[] for _ in eps]
    while any(m is None for m in metrics):
        a = policy(lanes, scs)
        _, _, term, trunc, info = venv.step(a.reshape(len(eps), 1).astype(np.float32))
        for i in range(len(eps)):
            if metrics[i] is None:
                errors[i].append(info["e"][i])
                if term[i] or trunc[i]:
                    metrics[i] = lanes.metrics(i)
    return metrics, errors


def measure(task: str, episodes: int) -> dict:
    """The numbers of the module docstring for one task."""
    eps = build_episodes(EvalConfig(suites=("unmodelled",), tasks=(task,), heldout_episodes=episodes))
    cfg = EnvConfig.from_kwargs({"task": task})
    h = cfg.control_period
    tmpl = cfg.template()
    trs = simulate_batch([tmpl.replace(**ep.physical) for ep in eps])
    delays = np.array([ep.physical["unmodelled"].delay for ep in eps], dtype=float)
    inverse = np.array([ep.physical["unmodelled"].threshold_current + ep.physical["unmodelled"].hysteresis_current / 2
                        for ep in eps])
    shift = [d * h * tr.log[tr.log[:, L_T] >= QUIET_STARTUP, L_YD + 1] for d, tr in zip(delays, trs)]
    # a constant 1 mA residual (a = 0.1 at residual_scale 10): the change of the measured error over the last second
    n = len(eps)
    _, e0 = run(task, eps, "current", lambda lanes, scs: np.zeros(n), friction_free=True)
    _, e1 = run(task, eps, "current", lambda lanes, scs: np.full(n, 1.0 / cfg.residual_scale), friction_free=True)
    half = len(e0[0]) // 2
    k = float(np.mean([np.mean(np.subtract(b[half:], a[half:])) for a, b in zip(e0, e1)]))
    current = [np.abs(s) / abs(k) + c for s, c in zip(shift, inverse)]
    # the oracle shift delta = -d h y_d' (the controller's y_d' at the next sample), against the base law
    D = 10.0 * max(float(np.max(np.abs(s))) for s in shift)  # a bound the oracle never reaches

    def oracle(lanes, scs):
        return np.clip(-delays * h * lanes.peek[:n, I_YD + 1] / D, -1.0, 1.0)

    base, _ = run(task, eps, "reference", lambda lanes, scs: np.zeros(n), bound=D)
    comp, _ = run(task, eps, "reference", oracle, bound=D)
    pooled_shift = np.abs(np.concatenate(shift))
    pooled_current = np.concatenate(current)
    shift_rms = float(np.sqrt(np.mean(pooled_shift**2)))
    current_rms = float(np.sqrt(np.mean(pooled_current**2)))
    return {"task": task, "episodes": n, "k": k, "shift_rms": shift_rms, "shift_bound": round_up(2 * shift_rms),
            "shift_over": float(np.mean(pooled_shift > round_up(2 * shift_rms))),
            "shift_p99": float(np.percentile(pooled_shift, 99)),
            "inverse_rms": float(np.sqrt(np.mean(inverse**2))),
            "current_rms": current_rms, "current_bound": round_up(2 * current_rms),
            "current_over": float(np.mean(pooled_current > round_up(2 * current_rms))),
            "current_p99": float(np.percentile(pooled_current, 99)),
            "trk_rmse_base": float(np.mean([m["trk_rmse"] for m in base])),
            "trk_rmse_shift": float(np.mean([m["trk_rmse"] for m in comp]))}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=32, help="unmodelled-suite episodes per task (default 32)")
    args = ap.parse_args(argv)
    for task in ("velocity", "position"):
        r = measure(task, args.episodes)
        unit = "rad/s" if task == "velocity" else "rad"
        print(f"{task} ({r['episodes']} episodes of the unmodelled suite)")
        print(f"  delay-compensating shift d h y_d': RMS {r['shift_rms']:.3g} {unit}, 99th percentile "
              f"{r['shift_p99']:.3g} {unit} -> reference bound D = 2 RMS = {r['shift_bound']:g} {unit} (exceeded "
              f"by {100 * r['shift_over']:.1f} % of the samples)")
        print(f"  error moved by a 1 mA residual: k = {r['k']:.3g} {unit}/mA")
        print(f"  dead band + hysteresis inverse th + h/2: RMS {r['inverse_rms']:.3g} mA")
        print(f"  ideal current correction |d h y_d'|/|k| + th + h/2: RMS {r['current_rms']:.3g} mA, 99th percentile "
              f"{r['current_p99']:.3g} mA -> residual authority R = 2 RMS = {r['current_bound']:g} mA (exceeded by "
              f"{100 * r['current_over']:.1f} % of the samples)")
        print(f"  tracking RMSE (true error, mean over episodes): base law {r['trk_rmse_base']:.3g} {unit}, with the "
              f"oracle shift {r['trk_rmse_shift']:.3g} {unit} (x{r['trk_rmse_shift'] / r['trk_rmse_base']:.3g})")


if __name__ == "__main__":
    main()
