"""The held-out check of a tuned law: its saturation, and whether it falls into a limit cycle at the current bound
through the friction events.

A law tuned for one plant must hold on episodes its tuning never saw. :func:`check` runs the CLF law at given env
settings (a plant, its law settings, n) on the held-out suite of ``ehss evaluate`` (its episodes drawn around the
plant, seeds >= 2^62, never a training seed), logged at the control rate, and measures per friction window:

- a **friction window** is the ruler's disturbance window: an event of amplitude > 0 from its start to 0.2 s after
  its end (``ehss_gym.core.layout.QUIET_GUARD``), clipped to [0.2 s, the episode's end];
- its **saturation**: the share of its control periods with the applied current at the current limit;
- its **reversals at the limit**: how often the sign of the current changes between one period at the limit and the
  next period at the limit (a loop switching from one bound to the other, the relay a CLF law turns into when its
  gain is too high for the plant, makes hundreds of them a second).

**The rule, written before the tuned laws were run.** A window **has a limit cycle** when it holds at least
:data:`LIMIT_CYCLE_REVERSALS` = 20 reversals at the limit: a sustained switch between the bounds at 40 Hz or faster over
the shortest window (0.25 s: a 0.05 s event and its guard). The threshold was set from three runs of the held-out
suite's velocity task before the search tuned any law for another plant: Table I's tuned default law, whose friction
edges make it touch the limit with at most 6 reversals in a window (a transient, not a cycle); the same law on the
second shipped rig, which cycles at the limit in every window (up to 1823 reversals); and on that rig a law with a
hand-set sigma ten times the default's (at most 4). A first threshold of 3 counted the edges' transients as cycles:
Table I's own law failed it in 16 windows. The law **passes** when its mean
saturation share over the episodes is below :data:`SATURATION_MAX` (5 %), no friction window has a limit cycle, and
no episode diverges or loses track. The same check of the untuned law (the env's defaults, tuned for Table I) on the
same episodes shows what the tuning changed, and that the check can fail.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ehss_gym.core.layout import QUIET_GUARD, QUIET_STARTUP
from ehss_gym.core.scenarios import heldout_scenarios
from ehss_gym.core.sim import simulate_batch
from ehss_gym.envs import EnvConfig

SATURATION_MAX = 0.05  # [-] the largest mean saturation share that passes
LIMIT_CYCLE_REVERSALS = 20  # reversals at the limit in one friction window that make it a limit cycle
GUARD = QUIET_GUARD  # [s] the window runs on after the event's end (the ruler's disturbance windows)
CHUNK = 4  # episodes simulated at a time (control-rate logs: about 12 MB per episode-second)


@dataclass(frozen=True)
class WindowStats:
    """One friction window of one episode.

    Attributes:
        episode: the held-out episode's index.
        start, end: the window [s].
        amplitude: the event's friction torque [N*m].
        saturation: share of its control periods at the current limit [-].
        reversals: sign changes between consecutive periods at the limit.
    """

    episode: int
    start: float
    end: float
    amplitude: float
    saturation: float
    reversals: int

    @property
    def limit_cycle(self) -> bool:
        """The rule's limit cycle (module docstring)."""
        return self.reversals >= LIMIT_CYCLE_REVERSALS


def window_stats(t: np.ndarray, u: np.ndarray, limit: float, friction, t_end: float, episode: int = 0) -> list:
    """The friction windows of one episode from its control-rate log.

    Args:
        t: the control instants [s].
        u: the applied current at them [mA].
        limit: the current limit [mA] (inf: no window saturates).
        friction: the episode's events (amplitude [N*m], start [s], end [s]).
        t_end: the episode's duration [s].
        episode: its index (for the rows).
    """
    at = np.abs(u) >= limit * (1.0 - 1e-12) if math.isfinite(limit) else np.zeros(len(u), dtype=bool)
    out = []
    for amp, t0, t1 in friction:
        lo, hi = max(t0, QUIET_STARTUP), min(t1 + GUARD, t_end)
        if amp <= 0.0 or hi <= lo:
            continue
        sel = (t >= lo) & (t < hi)
        if not sel.any():
            continue
        signs = np.sign(u[sel][at[sel]])
        reversals = int(np.count_nonzero(signs[1:] != signs[:-1])) if len(signs) > 1 else 0
        out.append(WindowStats(episode, float(lo), float(hi), float(amp), float(at[sel].mean()), reversals))
    return out


def check(env_kwargs: dict, episodes: int = 48, seconds: float = 2.0) -> dict:
    """The module docstring's check of the CLF law at ``env_kwargs`` on the first ``episodes`` held-out episodes.

    Returns:
        {"episodes", "saturation" (mean share), "saturation_max" (the largest episode's), "failed" (diverged or
        lost-track episodes), "windows" (count), "limit_cycles" (windows with one), "window_saturation_max",
        "reversals_max", "passed", "rows" (:class:`WindowStats` as dicts)}.
    """
    cfg = EnvConfig.from_kwargs(env_kwargs)
    tmpl = cfg.template().replace(log_interval=cfg.control_period)
    scs = heldout_scenarios(episodes, tmpl, seconds)
    sats, failed, rows = [], 0, []
    for k in range(0, len(scs), CHUNK):
        for i, tr in enumerate(simulate_batch(scs[k:k + CHUNK]), start=k):
            m = tr.metrics()
            sats.append(m["saturation"])
            failed += int(m["diverged"] or m["lost_track"])
            limit = math.inf if tr.scenario.current_limit is None else tr.scenario.current_limit
            rows += window_stats(tr.t, tr.u_applied, limit, tr.scenario.friction, tr.scenario.t_end, i)
    cycles = sum(w.limit_cycle for w in rows)
    sat = float(np.mean(sats))
    return {"episodes": len(scs), "saturation": sat, "saturation_max": float(np.max(sats)), "failed": failed,
            "windows": len(rows), "limit_cycles": cycles,
            "window_saturation_max": max((w.saturation for w in rows), default=0.0),
            "reversals_max": max((w.reversals for w in rows), default=0),
            "passed": sat < SATURATION_MAX and cycles == 0 and failed == 0,
            "rows": [{**w.__dict__, "limit_cycle": w.limit_cycle} for w in rows]}


__all__ = ["SATURATION_MAX", "LIMIT_CYCLE_REVERSALS", "GUARD", "WindowStats", "window_stats", "check"]
