"""Scoring: per-episode ratios to the reference law by metric class, the summary figures, gates and ranking.

**The ruler** (lower is better; the reference law scores exactly 1). Per episode, against the reference law R
(:data:`~ehss_gym.evaluation.specs.REFERENCE_POLICY`: the CLF law with n = 2 at the env's defaults) on the same
episode, both not diverged, each metric floored at its physical floor (x -> max(x, floor), :data:`PHYSICAL_FLOORS`)::

    q_trk = sqrt((trk_rmse / trk_rmse_R) * (trk_iae / trk_iae_R))        tracking window
    q_dst = sqrt((dst_peak / dst_peak_R) * (dst_iae / dst_iae_R))        episodes with a disturbance window
    q_eff = sqrt((tv_u_rate / tv_u_rate_R) * (rms_u / rms_u_R))          effort: noise-free episodes;
                                                                         chatter: episodes with sensor noise

(the windows and metrics: :mod:`ehss_gym.core.metrics`). A class figure is G_c = exp(mean over the class's
episodes and runs of log q_c); the overall figure is G = exp(mean over the classes present on the suite of
log G_c). Halving a metric pair gives 1/2, doubling it 2: the figure is symmetric in log ratio and has no cap.
The per-episode overall log ratio (for the IQM and the probability of improvement) is the mean of that episode's
class log ratios. An episode counts in a policy's figures only if the reference and every run of the policy
finished it without diverging.

**The floors and which figure ranks** (the rule, written before the runs it judges). A difference no real rig
resolves, or no real valve responds to, must not rank policies, so each metric is floored at a physical level
(:class:`Floors`, :data:`PHYSICAL_FLOORS`; each value's source in :data:`FLOOR_SOURCES`):

- an error (RMSE, peak |e|) at the smallest error the task's sensor resolves: one count of the finest position
  encoder the suites model (2^20 counts per revolution: 5.99e-6 rad), the finest velocity signal's step
  (1e-4 rad/s); an IAE at that error held over the IAE's window (floor x the window's duration);
- the RMS current at the servo valve's threshold (0.5 % of its 10 mA rated current: 0.05 mA), the smallest
  current step that moves the spool;
- the control TV rate at that threshold switched back and forth at the valve's bandwidth 1/(2 pi tau):
  2 x 0.05 mA x 15.9 Hz = 1.59 mA/s, the largest TV rate that can lie wholly below the threshold within the
  valve's band.

Ranking is by the overall figure G of these floored ratios, as before (failure gate first). The absolute levels
(medians of the raw metrics, :func:`absolute_levels`) are shown beside the ratios and rank nothing. The earlier
numeric floors (1e-12 output unit for every error and IAE, 1e-9 mA/s, 1e-9 mA: :data:`NUMERIC_FLOORS`) remain
available to measure what the physical floors change (``ehss factors``).

**Failure gates**: a policy fails on a (suite, task) if any episode of any run diverged or lost track, or its mean
saturation share exceeds :data:`SATURATION_GATE`. **Ranking**: policies without a failure first, by G; then the
failed ones, by the number of failed episodes, then G. Learned policies whose controller settings differ from
today's env defaults (recorded in an earlier loop) are summarised but not ranked against today's laws.

:func:`summarize` gives, per (suite, task, policy) of the figure suites, the class and overall figures with
bootstrap CIs (:mod:`ehss_gym.evaluation.stats`, on the log ratios, reported exponentiated), the IQM and the
probability of improvement over the best CLF, the gates, the mean metrics and the absolute levels; and, per learned
policy in today's loop, its comparison with the best CLF and its base law. The step suite is summarised apart (its
own table).
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ehss_gym.controllers import COMPENSATOR_ROWS, compensator_loops
from ehss_gym.core.layout import QUIET_STARTUP
from ehss_gym.core.resolution import (
    CURRENT_FLOOR,
    ERROR_RESOLUTION,
    FLOOR_SOURCES,
    POSITION_RESOLUTION,
    TV_FLOOR,
    VALVE_BANDWIDTH,
    VALVE_THRESHOLD,
    VELOCITY_RESOLUTION,
    floor_sources,
    valve_floors,
)
from ehss_gym.envs.config import ADDON_KEYS, DEFAULTS, law_table_of

from . import stats
from .specs import CLF_RE, REFERENCE_POLICY, PolicySpec, controller_settings
from .suites import SUITES, TASKS, UNITS, EvalConfig

SATURATION_GATE = 0.10  # [-] a mean saturation share above this fails the gate
CLASSES = ("tracking", "disturbance", "effort", "chatter")
# class -> its two metrics (keys of metrics.summarize_acc); their floors: Floors.of
CLASS_METRICS = {
    "tracking": ("trk_rmse", "trk_iae"),
    "disturbance": ("dst_peak", "dst_iae"),
    "effort": ("tv_u_rate", "rms_u"),
    "chatter": ("tv_u_rate", "rms_u"),
}
# the start-up window's pair (t < QUIET_STARTUP: outside every class; a diagnostic of where an error comes from)
STARTUP_METRICS = ("su_rmse", "su_iae")
# an IAE metric -> the key of its window's duration [s] (metrics.summarize_acc)
IAE_WINDOW = {"trk_iae": "t_tracking", "dst_iae": "t_disturbance"}


@dataclass(frozen=True)
class Floors:
    """The floor of each class metric before a ratio (x -> max(x, floor)).

    Attributes:
        name: "physical" or "numeric".
        error: task -> the floor of an error metric (RMSE, peak |e|) [output unit].
        tv: the floor of the control TV rate [mA/s].
        current: the floor of the RMS current [mA].
        iae_per_window: an IAE's floor is ``error`` times its window's duration [output unit * s] (the IAE of an
            error at the floor all through the window); False: ``error`` itself (the numeric floors').
        sources: where each floor comes from (task, "tv", "current" -> text); empty for the numeric floors.
    """

    name: str
    error: dict
    tv: float
    current: float
    iae_per_window: bool = True
    sources: tuple = ()

    def of(self, key: str, task: str, m: dict) -> float:
        """The floor of metric ``key`` of ``task`` in an episode's metrics ``m`` (its window's duration, for an IAE).

        Raises:
            KeyError: an unknown metric or task, or an IAE without its window's duration in ``m``.
        """
        if key in ("tv_u_rate",):
            return self.tv
        if key == "rms_u":
            return self.current
        e = self.error[task]
        if key in IAE_WINDOW:
            return e * float(m[IAE_WINDOW[key]]) if self.iae_per_window else e
        if key == "su_iae":  # the start-up window lasts QUIET_STARTUP in every episode
            return e * QUIET_STARTUP if self.iae_per_window else e
        if key in ("trk_rmse", "dst_peak", "su_rmse"):
            return e
        raise KeyError(f"no floor for metric {key!r}")

    def rows(self) -> list[tuple[str, str, str, str]]:
        """(what, value, unit, source) per floor, for the reports."""
        srcs = dict(self.sources)
        out = [(f"{t} error (RMSE, peak)", f"{v:.3g}", UNITS[t], srcs.get(t, "numeric")) for t, v in self.error.items()]
        iae = "the error floor x the window's duration" if self.iae_per_window else f"{self.error[TASKS[0]]:g}"
        out.append(("IAE", iae, "output unit * s", "the error floor held over the IAE's window" if srcs
                    else "numeric"))
        out.append(("control TV rate", f"{self.tv:.3g}", "mA/s", srcs.get("tv", "numeric")))
        out.append(("RMS current", f"{self.current:.3g}", "mA", srcs.get("current", "numeric")))
        return out


# the ruler's: the physical resolutions and valve levels of ehss_gym.core.resolution, with their sources
PHYSICAL_FLOORS = Floors("physical", dict(ERROR_RESOLUTION), TV_FLOOR, CURRENT_FLOOR,
                         sources=tuple(FLOOR_SOURCES.items()))


def physical_floors(rig=None) -> Floors:
    """The ruler's physical floors for a rig (:class:`ehss_gym.core.rig.Rig`; None: Table I's): the sensors'
    resolutions, and the valve's floors of its rated current and time constant
    (:func:`ehss_gym.core.resolution.valve_floors`)."""
    if rig is None:
        return PHYSICAL_FLOORS
    tv, current = valve_floors(rig.rated_current, rig.plant.tau)
    if (tv, current) == (PHYSICAL_FLOORS.tv, PHYSICAL_FLOORS.current):
        return PHYSICAL_FLOORS
    return Floors("physical", dict(ERROR_RESOLUTION), tv, current,
                  sources=tuple(floor_sources(rig.rated_current, rig.plant.tau).items()))


# the floors before the physical ones: numeric only, the same for every task and for an IAE as for an error
NUMERIC_FLOORS = Floors("numeric", {"velocity": 1e-12, "position": 1e-12}, 1e-9, 1e-9, iae_per_window=False)
FLOORS = PHYSICAL_FLOORS  # the ruler's
# the suites with the summary figure (step: its own table)
FIGURE_SUITES = ("paper", "heldout", "robustness", "unmodelled")
STEP_KEYS = ("step_rise_time", "step_overshoot", "step_settling_time")  # step-suite extras, with iae_r

# (key, label, unit ("U" = output unit), definition) of every reported metric; keys of metrics.summarize_acc
METRICS = (
    ("trk_rmse", "tracking RMSE", "U",
     "sqrt(mean e_t^2) over the tracking window (t >= 0.2 s, outside every friction window and its 0.2 s guard); "
     "e_t = y - y_d, the true error (no sensor noise)"),
    ("trk_iae", "tracking IAE", "U*s", "sum |e_t| h over the tracking window (h the control period)"),
    ("dst_peak", "disturbance peak", "U",
     "max |e_t| over the disturbance windows (t >= 0.2 s, from a friction event's start to 0.2 s after its end)"),
    ("dst_iae", "disturbance IAE", "U*s", "sum |e_t| h over the disturbance windows"),
    ("su_rmse", "start-up RMSE", "U", "sqrt(mean e_t^2) over the start-up, t < 0.2 s (diagnostic, not a class)"),
    ("su_peak", "start-up peak", "U", "max |e_t| over the start-up"),
    ("rmse", "RMSE", "U", "sqrt(mean e^2) over all control steps, e = y - y_d as measured"),
    ("rmse_nominal", "RMSE outside friction", "U", "the same over the steps with no friction event active"),
    ("iae", "IAE", "U*s", "sum |e| h over the control steps"),
    ("itae", "ITAE", "U*s^2", "sum t |e| h"),
    ("iae_r", "IAE to r", "U*s", "sum |y - r| h: the true output against the raw reference (no reference model)"),
    ("max_abs_e", "max |e|", "U", "largest |e| of the episode"),
    ("max_abs_e_friction", "max |e| in friction", "U", "largest |e| while a friction event is active"),
    ("recovery_on", "recovery on", "s",
     "time from the first friction switch-on until |e| enters and stays in 2x the largest |e| of the second "
     "before it (error sampled once per agent step); inf = never"),
    ("recovery_off", "recovery off", "s", "the same after that event switches off"),
    ("tv_u_rate", "control TV", "mA/s",
     "chattering index: sum |u_k - u_{k-1}| of the applied current over the control steps, per second"),
    ("rms_u", "RMS current", "mA", "sqrt(mean u^2) of the applied current"),
    ("peak_u_applied", "peak current", "mA", "largest |u| applied (after the current limit)"),
    ("saturation", "saturation", "-", "share of control steps on which the current limit clipped the command"),
    ("v_decrease", "V decrease", "-", "share of control steps on which the CLF value V = (s/sigma)^n/n fell"),
    ("diverged", "divergence rate", "-",
     "share of episodes stopped by a non-finite value, |x2| > omega_max or |x3| > 1.5 P_s"),
    ("lost_track", "lost-track rate", "-",
     "share of episodes that lost track without diverging: past the start-up (0.2 s), the RMS of e over a "
     "0.1 s sliding window exceeded the reference's amplitude (a saturated oscillation, for instance)"),
)
METRIC_KEYS = tuple(m[0] for m in METRICS)
RATE_KEYS = {"diverged": "divergence_rate", "lost_track": "lost_track_rate"}  # per-episode flag -> summary rate
RATIO_KEYS = tuple(f"q_{c}" for c in CLASSES) + ("q_overall",)  # per-episode ratio columns of a row


def episode_classes(noisy: bool) -> tuple[str, ...]:
    """The classes an episode can belong to: tracking, disturbance (if it has a window) and effort (noise-free)
    or chatter (with sensor noise)."""
    return ("tracking", "disturbance", "chatter" if noisy else "effort")


def class_log_ratio(m: dict, ref: dict, cls: str, task: str, floors: Floors = PHYSICAL_FLOORS) -> float:
    """log q_c of one episode of ``task`` (module docstring): half the sum of the log ratios of the class's two
    metrics, each floored (``floors``, the ruler's by default); NaN if a metric is undefined (no sample in the class's
    window)."""
    return pair_log_ratio(m, ref, CLASS_METRICS[cls], task, floors)


def pair_log_ratio(m: dict, ref: dict, keys: Sequence[str], task: str, floors: Floors = PHYSICAL_FLOORS) -> float:
    """Half the sum of the log ratios of two metrics ``keys`` of one episode (``m``) to the reference's on it
    (``ref``), each floored as the ruler floors it; NaN if a metric is undefined. A class's pair
    (:data:`CLASS_METRICS`) or the start-up window's (:data:`STARTUP_METRICS`, which ranks nothing)."""
    out = 0.0
    for key in keys:
        a, b = m[key], ref[key]
        if not (math.isfinite(a) and math.isfinite(b)):
            return math.nan
        floor = floors.of(key, task, ref)  # the same episode, so the same window for both
        out += 0.5 * (math.log(max(a, floor)) - math.log(max(b, floor)))
    return out


def episode_log_ratios(m: dict, ref: dict, noisy: bool, task: str, floors: Floors = PHYSICAL_FLOORS) -> dict:
    """The episode's class log ratios against the reference law's metrics ``ref`` on it (only its classes with a
    defined ratio); empty if either diverged. ``task`` and ``floors``: as :func:`class_log_ratio`."""
    if m["diverged"] or ref["diverged"]:
        return {}
    out = {}
    for cls in episode_classes(noisy):
        v = class_log_ratio(m, ref, cls, task, floors)
        if math.isfinite(v):
            out[cls] = v
    return out


def failure(rows: Sequence[dict]) -> tuple[bool, int]:
    """(failed, number of failed episodes) of a policy's rows on one (suite, task): an episode fails if it diverged
    or lost track; the policy fails on any failed episode or a mean saturation share above SATURATION_GATE."""
    n = sum(1 for r in rows if r["diverged"] or r["lost_track"])
    sat = float(np.mean([r["saturation"] for r in rows])) if rows else 0.0
    return n > 0 or sat > SATURATION_GATE, n


def figure_of(logs: dict) -> tuple[float, dict]:
    """(G, {class: G_c}) from per-class lists of episode log ratios (classes with no entry are left out)."""
    g = {c: math.exp(float(np.mean(v))) for c, v in logs.items() if len(v)}
    return (math.exp(float(np.mean([math.log(x) for x in g.values()]))) if g else math.nan), g


def rank_key(failed: bool, n_failed: int, g: float, name: str = "") -> tuple:
    """The ranking order: no failure first (by G), then by failed episodes, then G (an undefined G last)."""
    return (bool(failed), int(n_failed) if failed else 0, math.isnan(g), g if not math.isnan(g) else 0.0, name)


def gated_figure(metrics: Sequence[dict], anchor: Sequence[dict], noisy: Sequence[bool], task: str,
                 floors: Floors = PHYSICAL_FLOORS) -> dict:
    """The ruler's overall figure of per-episode ``metrics`` against the anchor's on the same episodes (of ``task``,
    under the rig's ``floors``), with the gate: the objective of every tuning procedure (``ehss baselines``).

    Returns:
        {"figure" (G), "classes" ({class: G_c}), "failed", "n_failed", "saturation" (mean share), "key" (the order:
        :func:`rank_key`)}.
    """
    logs: dict[str, list[float]] = {}
    for m, a, nz in zip(metrics, anchor, noisy):
        for c, v in episode_log_ratios(m, a, nz, task, floors).items():
            logs.setdefault(c, []).append(v)
    g, gc = figure_of(logs)
    failed, n_failed = failure(list(metrics))
    sat = float(np.mean([m["saturation"] for m in metrics]))
    return {"figure": g, "classes": gc, "failed": failed, "n_failed": n_failed, "saturation": sat,
            "key": rank_key(failed, n_failed, g)}


def ratio_rows(rows: list, floors: Floors = PHYSICAL_FLOORS) -> None:
    """Add the per-episode ratios ``q_<class>`` and ``q_overall`` (NaN outside the episode's classes or where it or
    the reference law diverged) to every row, against the reference law on the same episode (metrics floored at
    ``floors``, the ruler's by default).

    Raises:
        RuntimeError: an episode the reference law was not run on.
    """
    ref = {(r["suite"], r["task"], r["episode"]): r for r in rows if r["policy"] == REFERENCE_POLICY}
    for r in rows:
        k = (r["suite"], r["task"], r["episode"])
        rr = ref.get(k)
        if rr is None:
            raise RuntimeError(f"no {REFERENCE_POLICY} result for {k}; the reference law must be evaluated")
        logs = episode_log_ratios(r, rr, r["noisy"], r["task"], floors)
        for c in CLASSES:
            r[f"q_{c}"] = math.exp(logs[c]) if c in logs else math.nan
        r["q_overall"] = math.exp(float(np.mean(list(logs.values())))) if logs else math.nan


def matrix(rows: list, policy: str, suite: str, task: str, key: str = "q_overall", episodes: list | None = None):
    """The (runs, episodes) matrix of ``key`` for one policy, suite and task.

    Args:
        rows: per-episode rows.
        policy: the policy's name.
        suite: the suite.
        task: the task.
        key: the row field.
        episodes: episode ids in column order (default: their order in ``rows``).

    Returns:
        (matrix or None if the policy has no such rows, the episode ids of its columns).
    """
    sel = [r for r in rows if r["policy"] == policy and r["suite"] == suite and r["task"] == task]
    if not sel:
        return None, []
    eps = episodes or list(dict.fromkeys(r["episode"] for r in sel))
    runs = sorted({r["run"] for r in sel})
    idx = {(r["run"], r["episode"]): r for r in sel}
    m = np.array([[float(idx[(ru, e)][key]) for e in eps] for ru in runs])
    return m, eps


def _finite_mean(v) -> float:
    """Mean of the finite values of ``v`` (NaN if none)."""
    v = np.asarray(v, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else math.nan


def _mean_metrics(sel: list) -> dict:
    """Means of every metric over the non-diverged rows ``sel`` (recovery: plus the count that never recovered),
    and the divergence and lost-track rates over all of them."""
    d = {}
    ok = [r for r in sel if not r["diverged"]]
    for key in METRIC_KEYS:
        if key in ("diverged", "lost_track"):
            d[RATE_KEYS[key]] = float(np.mean([bool(r[key]) for r in sel]))
        elif key.startswith("recovery"):
            vals = [r[key] for r in ok if not math.isnan(r[key])]
            d[key] = _finite_mean(vals)
            d[key + "_never"] = int(sum(1 for v in vals if math.isinf(v)))
        else:
            d[key] = _finite_mean([r[key] for r in ok])
    return d


# the absolute levels shown beside the ratios (medians over a policy's non-diverged episodes; they rank nothing):
# (key of the summary row, metric, which episodes: "all", "noise-free" (the effort class's) or "noisy" (chatter's))
ABSOLUTE_LEVELS = (("abs_trk_rmse", "trk_rmse", "all"), ("abs_dst_peak", "dst_peak", "all"),
                   ("abs_tv_effort", "tv_u_rate", "noise-free"), ("abs_tv_chatter", "tv_u_rate", "noisy"),
                   ("abs_rms_u", "rms_u", "all"))


def absolute_levels(sel: Sequence[dict]) -> dict:
    """The absolute levels of a policy's rows ``sel`` on one (suite, task) (:data:`ABSOLUTE_LEVELS`): the median of
    each metric over the non-diverged episodes it is defined on (NaN if none)."""
    out = {}
    for key, metric, which in ABSOLUTE_LEVELS:
        v = [r[metric] for r in sel if not r["diverged"] and math.isfinite(r[metric])
             and (which == "all" or r["noisy"] == (which == "noisy"))]
        out[key] = float(np.median(v)) if v else math.nan
    return out


class Block:
    """The log-ratio matrices of one (suite, task): per policy and class a (runs, episodes) array over the
    episodes every run of the policy and the reference finished (``kept``; NaN outside the class), and the
    per-episode overall log ratios on them."""

    def __init__(self, rows: list, names: Sequence[str], suite: str, task: str):
        _, self.episodes = matrix(rows, REFERENCE_POLICY, suite, task)
        q = {n: {k: matrix(rows, n, suite, task, k, self.episodes)[0] for k in RATIO_KEYS} for n in names}
        self.classes = [c for c in CLASSES if any(np.isfinite(q[n][f"q_{c}"]).any() for n in names)]
        self.kept, self.overall, self.logs = {}, {}, {}
        for n in names:
            keep = np.isfinite(q[n]["q_overall"]).all(axis=0)
            self.kept[n] = [e for e, k in zip(self.episodes, keep) if k]
            self.overall[n] = np.log(q[n]["q_overall"][:, keep])
            self.logs[n] = {c: np.log(q[n][f"q_{c}"][:, keep]) for c in self.classes}

    def figure(self, name: str) -> tuple[float, dict]:
        """(G, {class: G_c}) of a policy (module docstring)."""
        return figure_of({c: m[np.isfinite(m)] for c, m in self.logs[name].items()})


def _log_ci(stat_logs, cfg: EvalConfig, seed: int, over: str) -> tuple[float, float]:
    """Exponentiated bootstrap CI of the grouped mean of log ratios (NaN, NaN if there are none)."""
    if not any(np.isfinite(g).any() for g in stat_logs):
        return math.nan, math.nan
    lo, hi = stats.grouped_mean_ci(stat_logs, over, cfg.n_boot, seed=seed)
    return math.exp(lo), math.exp(hi)


def policy_stream(name: str) -> int:
    """The bootstrap stream of policy ``name``: a stable hash of its name (CRC-32), so a policy's CIs do not depend on
    which other policies are evaluated beside it, nor on their order."""
    return zlib.crc32(name.encode("utf-8"))


def figure_statistics(blk: Block, name: str, cfg: EvalConfig) -> dict:
    """A policy's class and overall figures with bootstrap CIs (over episodes; with several runs also over seeds and
    both), and the IQM of its per-episode overall ratios; the bootstrap seeds are the policy's own
    (:func:`policy_stream`)."""
    k = policy_stream(name)
    g, gc = blk.figure(name)
    ov = blk.overall[name]
    d = {"n_runs": ov.shape[0], "n_episodes": len(blk.episodes), "n_used": ov.shape[1], "figure": g}
    overs = ("episodes",) + (("seeds", "both") if ov.shape[0] > 1 else ())
    for j, over in enumerate(overs):
        tag = "" if over == "episodes" else f"_{over}"
        groups = [blk.logs[name][c] for c in blk.classes if c in gc]
        d[f"figure_lo{tag}"], d[f"figure_hi{tag}"] = (_log_ci(groups, cfg, cfg.seed + 101 * k + j, over) if groups
                                                      else (math.nan, math.nan))
        for i, c in enumerate(blk.classes):
            m = blk.logs[name][c]
            d[c] = gc.get(c, math.nan)
            d[f"{c}_lo{tag}"], d[f"{c}_hi{tag}"] = _log_ci([m], cfg, cfg.seed + 101 * k + 11 * (i + 1) + j, over)
            d[f"{c}_n"] = int(np.isfinite(m[0]).sum()) if m.size else 0
    if ov.size:
        d["figure_iqm"] = math.exp(stats.iqm(ov))
        lo, hi = stats.bootstrap_ci(ov, "iqm", "episodes", cfg.n_boot, seed=cfg.seed + 101 * k + 7)
        d["figure_iqm_lo"], d["figure_iqm_hi"] = math.exp(lo), math.exp(hi)
    else:
        d["figure_iqm"] = d["figure_iqm_lo"] = d["figure_iqm_hi"] = math.nan
    return d


def _poi(blk: Block, a: str, b: str, cfg: EvalConfig, seed: int) -> tuple[float, float, float]:
    """Probability that policy ``a``'s per-episode overall ratio is lower than ``b``'s, on the episodes both
    finished, with its CI (NaN if none)."""
    ea = dict(zip(blk.kept[a], blk.overall[a].T))
    eb = dict(zip(blk.kept[b], blk.overall[b].T))
    common = [e for e in ea if e in eb]
    if not common:
        return math.nan, math.nan, math.nan
    x = np.stack([ea[e] for e in common], axis=1)
    y = np.stack([eb[e] for e in common], axis=1)
    return stats.probability_of_improvement_ci(x, y, n_boot=cfg.n_boot, seed=seed)


def is_earlier_loop(spec: PolicySpec, task: str) -> bool:
    """True for a learned policy whose controller settings differ from today's env defaults on ``task`` for its n
    (the law's settings are tuned per n), the law's add-ons aside (:data:`~ehss_gym.envs.config.ADDON_KEYS`: a
    residual on top of the observer or a compensator acts in today's loop, as dob-n2 and dcomp-n2 do), and unless
    they are those of a scripted baseline of today's on that task (``eso-n2``'s estimator: a residual on top of it acts
    in today's loop too): it was recorded in an earlier loop and is not ranked against today's laws."""
    if not spec.learned:
        return False
    n = policy_n(spec, task)
    ours = controller_settings(spec.env_kwargs, task)
    laws = law_table_of(spec.env_kwargs.get("law_settings"))
    bases = [{}] + [loop for kind in COMPENSATOR_ROWS for loop in compensator_loops(kind, (task,), laws).values()]
    for base in bases:
        today = controller_settings({"n": n, **base}, task)
        if all(ours[k] == today[k] for k in ours if k not in ADDON_KEYS):
            return False
    return True


def policy_n(spec: PolicySpec, task: str) -> int:
    """The power factor n of the law a policy acts with on ``task`` (the env's default unless its settings say)."""
    return int(spec.env_kwargs_for(task).get("n", DEFAULTS.n))


def _block_summary(rows: list, blk: Block, specs: Sequence[PolicySpec], suite: str, task: str,
                   cfg: EvalConfig) -> list:
    """The summary rows of one (suite, task) block: today's laws ranked, earlier-loop policies after them
    unranked."""
    block = []
    for spec in specs:
        n = spec.name
        sel = [r for r in rows if r["policy"] == n and r["suite"] == suite and r["task"] == task]
        failed, n_failed = failure(sel)
        d = {"suite": suite, "task": task, "policy": n, "rank": 0, "failed": failed, "n_failed": n_failed,
             "earlier_loop": is_earlier_loop(spec, task)}
        d.update(figure_statistics(blk, n, cfg))
        d.update(_mean_metrics(sel))
        d.update(absolute_levels(sel))
        block.append(d)
    ranked = sorted((d for d in block if not d["earlier_loop"]),
                    key=lambda d: rank_key(d["failed"], d["n_failed"], d["figure"], d["policy"]))
    for rank, d in enumerate(ranked, 1):
        d["rank"] = rank
    best = next((d["policy"] for d in ranked if CLF_RE.match(d["policy"])), None)
    for d in block:
        d["best_clf"] = best or ""
        if best is not None and d["policy"] != best:
            d["poi_vs_best_clf"], d["poi_lo"], d["poi_hi"] = _poi(blk, d["policy"], best, cfg,
                                                                  cfg.seed + 7 + 101 * policy_stream(d["policy"]))
        else:
            d["poi_vs_best_clf"] = d["poi_lo"] = d["poi_hi"] = math.nan
    earlier = [d for d in block if d["earlier_loop"]]
    return ranked + earlier


def _paired_logs(blk: Block, a: str, b: str) -> tuple[list, list]:
    """Per class the log-ratio differences a - b on the episodes both finished (runs of ``b`` averaged, so a
    scripted law's single run pairs with every training seed), and the class names."""
    ka, kb = blk.kept[a], blk.kept[b]
    common = [e for e in ka if e in kb]
    ia = [ka.index(e) for e in common]
    ib = [kb.index(e) for e in common]
    out, names = [], []
    for c in blk.classes:
        xa = blk.logs[a][c][:, ia]
        xb = blk.logs[b][c][:, ib].mean(axis=0, keepdims=True)
        diff = xa - xb
        if np.isfinite(diff).any():
            out.append(diff)
            names.append(c)
    return out, names


def _comparison(blk: Block, spec: PolicySpec, specs: Sequence[PolicySpec], summary: list, suite: str, task: str,
                cfg: EvalConfig) -> dict | None:
    """A learned policy in today's loop against the best CLF of the block and against its base law
    (:func:`base_law_of`; a direct policy's is the best CLF): the ratio of its figure to each with a paired bootstrap
    CI, the PoI over the best CLF, and its class figures over the base law's. None if no CLF ran."""
    by = {d["policy"]: d for d in summary}
    best = by[spec.name]["best_clf"]
    if not best:
        return None
    diffs, _ = _paired_logs(blk, spec.name, best)
    if not diffs:
        return None
    ratio = math.exp(stats.grouped_mean(diffs))
    over = "both" if diffs[0].shape[0] > 1 else "episodes"
    lo, hi = stats.grouped_mean_ci(diffs, over, cfg.n_boot, seed=cfg.seed + 3)
    p, plo, phi = _poi(blk, spec.name, best, cfg, cfg.seed + 5)
    c = {"suite": suite, "task": task, "policy": spec.name, "n_runs": blk.overall[spec.name].shape[0],
         "best_clf": best, "figure": by[spec.name]["figure"], "best_clf_figure": by[best]["figure"],
         "ratio_to_best": ratio, "improvement": 1.0 - ratio, "improvement_lo": 1.0 - math.exp(hi),
         "improvement_hi": 1.0 - math.exp(lo), "poi": p, "poi_lo": plo, "poi_hi": phi}
    base = base_law_of(spec, [s for s in specs if s.name in by], task) or best
    c["base_law"] = base
    diffs, names = _paired_logs(blk, spec.name, base)
    for cls in CLASSES:
        c[f"{cls}_ratio"] = (math.exp(float(np.nanmean(diffs[names.index(cls)]))) if cls in names else math.nan)
    # the overall figure over the base law's, paired the same way: what the residual adds to the law it acts on
    if base != best:
        ratio, lo, hi = math.nan, math.nan, math.nan
        if diffs:
            ratio = math.exp(stats.grouped_mean(diffs))
            lo, hi = stats.grouped_mean_ci(diffs, over, cfg.n_boot, seed=cfg.seed + 9)
    c["ratio_to_base"], c["ratio_to_base_lo"], c["ratio_to_base_hi"] = ratio, math.exp(lo), math.exp(hi)
    return c


def base_law_of(spec: PolicySpec, specs: Sequence[PolicySpec], task: str) -> str | None:
    """The scripted policy among ``specs`` whose closed loop a learned residual acts in on ``task`` (the same
    controller settings, defaults resolved: ``eso-n2`` for a residual on the observer's law), the CLF with the
    policy's n first; else that CLF where it ran; None for a direct policy or where neither ran."""
    if spec.env_kwargs.get("mode", "residual") != "residual":
        return None
    n = policy_n(spec, task)
    own = f"clf-n{n}"
    ours = controller_settings(spec.env_kwargs, task)
    scripted = sorted((s for s in specs if not s.learned), key=lambda s: s.name != own)
    for s in scripted:
        if controller_settings(s.env_kwargs_for(task), task) == ours:
            return s.name
    return own if any(s.name == own for s in scripted) else None


def summarize(rows: list, specs: Sequence[PolicySpec], cfg: EvalConfig) -> tuple[list, list]:
    """Per (suite, task, policy) of the figure suites: figures with CIs, gates, rank, PoI against the best CLF and
    mean metrics; comparisons of the learned policies in today's loop.

    Args:
        rows: per-episode rows with their ratios (:func:`ratio_rows`).
        specs: the evaluated policies (order = order within a block before ranking).
        cfg: bootstrap sizes and seed.

    Returns:
        (summary rows in suite, task, rank order, the earlier-loop policies last; comparison rows).
    """
    summary, comparisons = [], []
    for suite in SUITES:
        if suite not in FIGURE_SUITES:
            continue
        for task in TASKS:
            present = [s for s in specs if any(r["policy"] == s.name and r["suite"] == suite and r["task"] == task
                                               for r in rows)]
            if not present:
                continue
            blk = Block(rows, [s.name for s in present], suite, task)
            block = _block_summary(rows, blk, present, suite, task, cfg)
            summary += block
            for spec in present:
                if spec.learned and not is_earlier_loop(spec, task):
                    c = _comparison(blk, spec, present, block, suite, task, cfg)
                    if c is not None:
                        comparisons.append(c)
    return summary, comparisons


__all__ = ["CLASSES", "CLASS_METRICS", "IAE_WINDOW", "Floors", "FLOORS", "PHYSICAL_FLOORS", "physical_floors",
           "NUMERIC_FLOORS",
           "FLOOR_SOURCES", "POSITION_RESOLUTION", "VELOCITY_RESOLUTION", "VALVE_THRESHOLD", "VALVE_BANDWIDTH",
           "TV_FLOOR", "CURRENT_FLOOR", "SATURATION_GATE", "ABSOLUTE_LEVELS", "absolute_levels", "METRICS",
           "METRIC_KEYS", "FIGURE_SUITES", "episode_classes", "class_log_ratio", "episode_log_ratios", "failure",
           "figure_of", "rank_key", "gated_figure", "ratio_rows", "pair_log_ratio", "STARTUP_METRICS",
           "matrix", "Block", "figure_statistics", "policy_stream", "is_earlier_loop", "policy_n", "base_law_of",
           "summarize"]
