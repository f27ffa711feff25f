"""One simulated run of the study (Record), the features beyond the core metrics, and the batch runner."""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numba as nb
import numpy as np
from tqdm import tqdm

from ehss_gym.core.layout import L_E, L_S, L_X, L_YD
from ehss_gym.core.physics import lie_derivatives
from ehss_gym.core.sim import Scenario, Trajectory, lambdas, simulate_batch
from ehss_gym.infra.execution import Executor, Job

from .config import CHATTER_WINDOW


@dataclass
class Record:
    """One simulated run: its settings, metrics and the features the claims and maps use."""

    group: str  # which part of the study: P0..P4, sweep name, probe, ...
    params: dict
    metrics: dict
    features: dict
    traj: object = field(default=None, repr=False)  # kept for paper runs and probes only

    def get(self, key, default=math.nan):
        if key in self.metrics:
            return self.metrics[key]
        return self.features.get(key, default)


def params_of(sc: Scenario) -> dict:
    return {"task": sc.task, "fr": sc.fr, "n": sc.n, "sigma": sc.sigma, "smoothing": sc.smoothing,
            "limit": sc.current_limit, "h": sc.control_period, "substeps": sc.substeps, "t_end": sc.t_end,
            "estimator_hz": sc.estimator_hz, "estimator": sc.estimator, "observer_hz": sc.observer_hz, "law": sc.law,
            "layer_gain": sc.layer_gain, "bumpless": sc.bumpless, "ref_accel": sc.ref_accel,
            "pressure_domain": sc.pressure_domain, "noisy": any(v > 0 for v in sc.noise_std)}


@nb.njit(cache=True)
def _relay_ratios(log, n_rows, m, n, sigma, lam, model_p, ulim):
    """Per logged sample: beta = |s/sigma|^(n-1) |G|/sigma against |psi/G| and the limit.

    Returns (median log10(beta/|psi/G|), median log10(beta/limit), median |psi/G| [mA], median |G|).
    """
    hd = np.zeros(4)
    r1 = np.empty(n_rows)
    r2 = np.empty(n_rows)
    pg = np.empty(n_rows)
    ga = np.empty(n_rows)
    k = 0
    for i in range(n_rows):
        x = log[i, L_X:L_X + 4]
        F, G = lie_derivatives(x, model_p, m, hd)
        if G == 0.0 or not math.isfinite(G):
            continue
        psi = F - log[i, L_YD + m]
        for j in range(m - 1):
            psi += lam[j] * log[i, L_E + j + 1]
        s = log[i, L_S]
        ratio = abs(psi / G)
        if s == 0.0 or ratio == 0.0:
            continue
        lb = (n - 1.0) * math.log10(abs(s) / sigma) + math.log10(abs(G) / sigma)
        r1[k] = lb - math.log10(ratio)
        r2[k] = lb - math.log10(ulim) if math.isfinite(ulim) else math.nan
        pg[k] = ratio
        ga[k] = abs(G)
        k += 1
    if k == 0:
        return math.nan, math.nan, math.nan, math.nan
    return np.median(r1[:k]), np.median(r2[:k]), np.median(pg[:k]), np.median(ga[:k])


def _window_max(t, e, a, b):
    sel = (t >= a) & (t < b)
    return float(np.max(np.abs(e[sel]))) if sel.any() else math.nan


def chatter_index(u: np.ndarray, dt: float, window: float = CHATTER_WINDOW) -> float:
    """RMS(u - its centred moving average over ``window``) / RMS(u): the share of a signal that switches faster
    than ``window`` (a smooth law scores ~0, a relay switching every sample ~1).

    Args:
        u: the signal sampled every ``dt`` [any unit].
        dt: its sampling interval [s].
        window: the moving average's length [s] (rounded to an odd number of samples >= 3).

    Returns:
        The index (dimensionless), NaN if ``u`` is shorter than the window or identically 0.
    """
    u = np.asarray(u, dtype=np.float64)
    w = max(3, 2 * int(round(0.5 * window / dt)) + 1)
    if u.size < w:
        return math.nan
    ma = np.convolve(u, np.ones(w) / w, mode="valid")  # ma[i] is centred on u[i + w // 2]
    core = u[w // 2: w // 2 + ma.size]
    rms_u = math.sqrt(float(np.mean(core ** 2)))
    if rms_u == 0.0:
        return math.nan
    return math.sqrt(float(np.mean((core - ma) ** 2))) / rms_u


def features_of(traj) -> dict:
    """Features beyond the core metrics, from the logged trajectory (log interval, not control rate).

    - amp_pre: max|e| in the second before friction switches on.
    - amp_fric_sus / amp_post_sus: max|e| from 0.5 s after the friction switches on (off) to the
      next edge (the end): a sustained oscillation, not the edge transient.
    - peak_edge_dist: time from the friction-window error peak to the nearest friction edge [s].
    - chatter_index: :func:`chatter_index` of the applied current (NaN unless the run is logged at every control
      period).
    - relay_log_ratio: median log10(beta / |psi/G|); beta_log_limit: median log10(beta / limit);
      psi_over_G: median |psi/G| [mA] (the equivalent control); G_med: median |G|.
    - window_rms_max: largest RMS error over consecutive 0.1 s windows after the first 0.2 s (the
      start-up transient) [output unit]; large when the loop has lost track.
    """
    sc = traj.scenario
    t, e = traj.t, traj.e
    f = {}
    ev = [x for x in sc.friction if x[0] > 0]
    f["t_fric_on"] = ev[0][1] if ev else math.nan
    f["r0"] = float(sc.reference(0.0))
    f["family"] = sc.reference.family
    if ev and len(t) > 1:
        on, off = ev[0][1], ev[0][2]
        f["amp_pre"] = _window_max(t, e, on - 1.0, on)
        f["amp_fric_sus"] = _window_max(t, e, on + 0.5, off)
        f["amp_post_sus"] = _window_max(t, e, off + 0.5, sc.t_end + 1.0)
        sel = (t >= on) & (t < off + 0.5)
        if sel.any():
            i = int(np.argmax(np.abs(e[sel])))
            tp = t[sel][i]
            f["peak_edge_dist"] = float(min(abs(tp - on), abs(tp - off)))
            f["t_peak_fric"] = float(tp)
        else:
            f["peak_edge_dist"] = f["t_peak_fric"] = math.nan
    else:
        for k in ("amp_pre", "amp_fric_sus", "amp_post_sus", "peak_edge_dist", "t_peak_fric"):
            f[k] = math.nan
    ua = traj.u_applied
    dt_log = float(t[1] - t[0]) if len(t) > 1 else sc.control_period
    nw = max(1, int(round(0.1 / dt_log)))
    tail = e[t >= 0.2]
    k = len(tail) // nw
    f["window_rms_max"] = float(np.sqrt(np.mean(tail[:k * nw].reshape(k, nw) ** 2, axis=1)).max()) if k else math.nan
    # C6's chatter index needs every control period (switching at the control rate aliases at a coarser log)
    f["chatter_index"] = chatter_index(ua, sc.control_period) if sc.log_every == 1 else math.nan
    if len(t) > 1:
        lam = np.zeros(3)
        lv = lambdas(sc.order, sc.fr)
        lam[:len(lv)] = lv
        ulim = math.inf if sc.current_limit is None else sc.current_limit
        r1, r2, pg, ga = _relay_ratios(traj.log, len(t), sc.order, float(sc.n), sc.sigma, lam,
                                       (sc.model or sc.plant).as_array(), ulim)
        f.update(relay_log_ratio=float(r1), beta_log_limit=float(r2), psi_over_G=float(pg), G_med=float(ga))
    else:
        f.update(relay_log_ratio=math.nan, beta_log_limit=math.nan, psi_over_G=math.nan, G_med=math.nan)
    return f


def probe_summary(r: Record) -> Record:
    """Dominant frequency and amplitude of the applied current over the probe's second half."""
    tr = r.traj
    sel = tr.t >= 0.5 * tr.scenario.t_end
    u = tr.u_applied[sel]
    f_dom = math.nan
    if u.size > 8 and not tr.diverged:
        u = u - u.mean()
        spec = np.abs(np.fft.rfft(u * np.hanning(u.size)))
        fq = np.fft.rfftfreq(u.size, float(tr.t[1] - tr.t[0]))
        f_dom = float(fq[1 + int(np.argmax(spec[1:]))])
    r.features["f_dom"] = f_dom
    r.features["e_rms_probe"] = float(np.sqrt(np.mean(tr.e[sel] ** 2))) if sel.any() else math.nan
    r.traj = None
    return r


def batch_job(config: dict, seed: int, context) -> list[dict]:
    """An executor job (:mod:`ehss_gym.infra.execution`): one ``simulate_batch`` call of the study, as plain data
    per run (params, metrics, features; with ``keep`` the trajectory's log and accumulators too). The scenarios
    carry their own noise seeds, so ``seed`` is unused."""
    out = []
    for tr in simulate_batch(list(config["scenarios"])):
        d = {"params": params_of(tr.scenario), "metrics": tr.metrics(), "features": features_of(tr)}
        if config["keep"]:
            d["log"], d["acc"] = tr.log, tr.acc
        out.append(d)
    return out


@dataclass
class RecordStore:
    """A study's runs by group (group -> list of :class:`Record`), its choices (``rec``) and its timings [s]; the
    reproduction and the noise study keep their state in a subclass that adds their config."""

    records: dict = field(default_factory=dict)
    rec: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)

    def add(self, records) -> None:
        """File ``records`` under their groups."""
        for r in records:
            self.records.setdefault(r.group, []).append(r)

    def group(self, name: str) -> list[Record]:
        """The records of group ``name`` (empty if none ran)."""
        return self.records.get(name, [])


class Runner:
    """Batches scenarios by time grid into ``simulate_batch`` calls (jobs of an
    :class:`~ehss_gym.infra.execution.Executor`), with one tqdm bar over batches."""

    def __init__(self, max_batch: int = 64, progress: bool = True, desc: str = "ehss reproduce",
                 executor: Executor | None = None):
        """Batches of at most ``max_batch`` runs on ``executor`` (default: in this process, nothing stored)."""
        self.max_batch = max_batch
        self.desc = desc
        self.executor = executor or Executor()
        self.bar = tqdm(total=0, desc=desc, unit="batch", disable=not progress, file=sys.stderr)
        self.n_runs = 0
        self.sim_seconds = 0.0
        self.by_group: dict[str, float] = {}  # wall time [s] per study part (a batch shared out by its runs)

    def batches(self, items: Sequence[tuple[str, Scenario]]) -> list[list[int]]:
        """Indices of ``items`` cut into batches of one time grid each (fixed order: results do not depend on
        where the batches run)."""
        groups: dict[tuple, list[int]] = {}
        for i, (_, sc) in enumerate(items):
            groups.setdefault(sc.grid(), []).append(i)
        batches = []
        for idx in groups.values():
            # interleave so both threads' chunks mix cheap (diverging) and long runs
            rng = np.random.default_rng(len(idx))
            idx = [idx[j] for j in rng.permutation(len(idx))]
            n_b = -(-len(idx) // self.max_batch)
            size = -(-len(idx) // n_b)
            batches += [idx[k:k + size] for k in range(0, len(idx), size)]
        return batches

    def run(self, items: Sequence[tuple[str, Scenario]], keep: bool = False) -> list[Record]:
        """Simulate (group, scenario) pairs; returns Records in the same order."""
        batches = self.batches(items)
        self.bar.total += len(batches)
        self.bar.refresh()
        jobs = [Job(batch_job, {"scenarios": [items[i][1] for i in b], "keep": keep}, 0, label=items[b[0]][0])
                for b in batches]
        t0 = time.perf_counter()
        # locally, in this process: simulate_batch spreads each batch over numba's threads, as before
        results = self.executor.map(jobs, desc=self.desc, in_process=self.executor.backend.name == "local")
        dt = time.perf_counter() - t0
        self.sim_seconds += dt
        out: list[Record | None] = [None] * len(items)
        for b, res in zip(batches, results):
            g = items[b[0]][0]
            self.by_group[g] = self.by_group.get(g, 0.0) + dt * len(b) / max(1, len(items))
            for i, d in zip(b, res):
                traj = Trajectory(items[i][1], d["log"], d["acc"]) if keep else None
                out[i] = Record(items[i][0], d["params"], d["metrics"], d["features"], traj)
            self.n_runs += len(b)
            self.bar.update(1)
        return out

    def close(self):
        self.bar.close()
