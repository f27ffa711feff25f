"""How large the ideal corrections of the unmodelled valve and sensors are: what a residual that learns them must be
able to put out (its authority), measured on the unmodelled suite.

Per episode, three runs of the base law (the env's n = 2 law, zero residual) logged at every control sample: as it is,
with the delay compensation knowing the episode's delay (``reference_delay`` = its delay d) and with the valve inverse
knowing its valve (``inverse_threshold``, ``inverse_hysteresis`` = its own; :mod:`ehss_gym.core.compensators`). Over
the samples past the start-up (t >= 0.2 s, the ruler's classes' samples):

- **the reference shift** the delay compensation makes: y_d^(i)(t) - y_d^(i)(t - d h) for i = 0 .. m [U / s^i] (what
  a residual acting on the law's reference must be able to shift it by);
- **the valve inverse's added current**: the commanded current minus the law's, within its run [mA] (what a current
  residual must add to invert the valve);
- **the closed-loop current change** of each compensation: its run's applied current minus the base law's, each
  averaged over blocks of :data:`BLOCK` control periods (1 ms, the residual recipe's agent period) [mA]: what the
  loop's current moves by when the compensation acts through the law, at the rate a residual acts (sample by sample
  the two runs' noise-driven switching decorrelates and the difference measures that instead);
- for scale, the base law's applied current [mA].

Each as its RMS pooled over the episodes' samples, the median and the largest of the episodes' own RMS, and the largest
|value| [the quantity's unit].
"""

from __future__ import annotations

import math

import numpy as np

from ehss_gym.core.layout import L_T, L_UAPP, L_UBASE, L_UCMD, L_YD, QUIET_STARTUP
from ehss_gym.core.sim import simulate_batch
from ehss_gym.envs import EnvConfig

BLOCK = 20  # [control periods] the closed-loop changes are of the currents' means over blocks of this many samples
QUANTITIES = ("reference shift y_d", "reference shift y_d'", "reference shift y_d''", "reference shift y_d'''",
              "reference shift y_d''''", "valve inverse's added current",
              "closed-loop change of the 1 ms mean current, delay known",
              "closed-loop change of the 1 ms mean current, valve known", "base law's current")


def delay_known(physical: dict) -> dict:
    """The delay compensation knowing an episode's sensor delay (its physical fields): the law's reference delayed by
    it [control samples]."""
    return {"reference_delay": float(physical["unmodelled"].delay)}


def valve_known(physical: dict) -> dict:
    """The valve inverse knowing an episode's valve: its threshold and hysteresis [% of its rated current, which the
    loop's ``rated_current`` is: both are the rig's]."""
    um = physical["unmodelled"]
    return {"inverse_threshold": 100.0 * um.threshold_current / um.rated_current,
            "inverse_hysteresis": 100.0 * um.hysteresis_current / um.rated_current}


def units(task: str) -> dict:
    """Quantity -> its unit on ``task`` (the output's derivatives: rad/s^(i+1) velocity, rad/s^i position)."""
    out = {q: "mA" for q in QUANTITIES[5:]}
    for i, q in enumerate(QUANTITIES[:5]):
        p = i + (task == "velocity")
        out[q] = "rad" if p == 0 else ("rad/s" if p == 1 else f"rad/s^{p}")
    return out


def block_means(x: np.ndarray, sel: np.ndarray) -> np.ndarray:
    """The means of ``x`` over consecutive blocks of :data:`BLOCK` samples, of the blocks wholly in ``sel``."""
    n = len(x) // BLOCK * BLOCK
    xb, sb = x[:n].reshape(-1, BLOCK).mean(axis=1), sel[:n].reshape(-1, BLOCK).all(axis=1)
    return xb[sb]


def episode_corrections(task: str, env_kwargs: dict, physical: dict) -> dict:
    """Quantity -> (sum of squares, samples, largest |value|) of one episode (module docstring); the reference
    shift's orders up to the task's relative degree m only; {} if a run diverged."""
    sc = EnvConfig.from_kwargs(env_kwargs).template().replace(**physical)
    sc = sc.replace(log_interval=sc.control_period)
    dk, vk = delay_known(physical), valve_known(physical)
    base, dl, vl = simulate_batch([sc, sc.replace(**dk), sc.replace(**vk)])
    if base.diverged or dl.diverged or vl.diverged:
        return {}
    sel = base.log[:, L_T] >= QUIET_STARTUP
    d = int(dk["reference_delay"])
    k = np.arange(len(dl.log))
    yd = dl.log[:, L_YD:L_YD + sc.order + 1]
    shift = yd - yd[np.maximum(k - d, 0)]
    series = {QUANTITIES[i]: shift[:, i] for i in range(sc.order + 1)}
    series[QUANTITIES[5]] = vl.log[:, L_UCMD] - vl.log[:, L_UBASE]
    series[QUANTITIES[8]] = base.log[:, L_UAPP]
    out = {q: (float(np.sum(x[sel] ** 2)), int(sel.sum()), float(np.abs(x[sel]).max())) for q, x in series.items()}
    for q, run in ((QUANTITIES[6], dl), (QUANTITIES[7], vl)):
        x = block_means(run.log[:, L_UAPP], sel) - block_means(base.log[:, L_UAPP], sel)
        out[q] = (float(np.sum(x**2)), len(x), float(np.abs(x).max()))
    return out


def corrections_job(config: dict, seed: int, context) -> list[dict]:
    """An executor job: :func:`episode_corrections` of every episode of one task (plain data back)."""
    return [episode_corrections(config["task"], config["env_kwargs"], ep.physical) for ep in config["episodes"]]


def summarize(per_episode: list[dict], task: str) -> list[dict]:
    """One row per quantity: "quantity", "unit", "rms" (pooled), "median_rms", "max_rms" (over the episodes),
    "max_abs", "episodes"."""
    un = units(task)
    out = []
    for q in QUANTITIES:
        eps = [e[q] for e in per_episode if q in e]
        if not eps:
            continue
        rms = [math.sqrt(ss / n) for ss, n, _ in eps]
        out.append({"quantity": q, "unit": un[q], "rms": math.sqrt(sum(e[0] for e in eps) / sum(e[1] for e in eps)),
                    "median_rms": float(np.median(rms)), "max_rms": max(rms), "max_abs": max(e[2] for e in eps),
                    "episodes": len(eps)})
    return out


__all__ = ["BLOCK", "QUANTITIES", "block_means", "delay_known", "valve_known", "units", "episode_corrections",
           "corrections_job", "summarize"]
