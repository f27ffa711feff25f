"""Where the vector env's compiled step spends its time, stage by stage, on the lanes of one block.

cProfile sees one opaque call (``advance``); here small compiled drivers call the package's own stage kernels over
the lanes of a native vector env caught mid-episode (seeded random residuals first, so noise, friction and the
metric windows are live as in training), one thread, each timed alone as the best of many short runs:

- the control period's stages as :func:`ehss_gym.core.loop.lanes_period` runs them (the sensors and model over the
  lanes, the rest of the controller over the lanes, the current, the friction torque, the plant, the divergence
  check, the metrics, the state copy);
- the env's per-agent-step work (the look-ahead :func:`ehss_gym.envs.kernels.peek_lanes`, the observation), spread
  over the agent step's control periods, and the whole compiled step;
- the whole ``lanes_period`` on two layouts of the same lanes: the env's (each block a (B, width) array, lane rows
  contiguous: :mod:`ehss_gym.envs.buffers`) and column blocks of one (B, N) buffer, whose rows have a stride numba only
  knows at run time (the env's layout before this release); and the divergence check on both (loops over a lane's
  rows with no exit per entry: over every row, the compiler vectorised them on contiguous rows only; over the fixed
  core rows of a lane without add-ons, on both).

Every figure is ns per lane and control period. The drivers are compiled as the package's hot kernels are (without
numba's reference counting, :data:`ehss_gym.core.jit.jit_noalloc`), so a lane's view costs what it costs there.
Benchmark code only: nothing here is used by the package.
"""

from __future__ import annotations

import math
import time

import numba as nb
import numpy as np

from ehss_gym.core.controller import CW_TODO, controller_apply, law_lanes, sense_lanes
from ehss_gym.core.jit import jit_noalloc
from ehss_gym.core.layout import I_UBASE, N_LOOP, N_PLANT, X_OMEGA
from ehss_gym.core.loop import check_state, copy_live, lanes_period
from ehss_gym.core.metrics import accumulate
from ehss_gym.core.params import P_DF
from ehss_gym.core.physics import friction_torque, integrate_lanes
from ehss_gym.core.references import reference_value
from ehss_gym.envs.buffers import BB_RUN, F_URES, HOT_BLOCKS, IB_GID, IB_K
from ehss_gym.envs.kernels import advance, observe_lanes, peek_lanes
from ehss_gym.envs.lanes import hot_block
from ehss_gym.envs.vector import EHSSTrackingVectorEnv

# the hot blocks lanes_period takes, in its order, by their order in HOT_BLOCKS (z, plant, model, ctrl, ref, info,
# info_ok, peek, acc, zprev)
PERIOD_BLOCKS = (0, 1, 2, 3, 4, 5, 8, 9, 7)


@jit_noalloc
def _periods(n, k0, h, substeps, z, plant, model, ctrl, ref, info, acc, zprev, peek, u_res, run, events, filt, c, X,
             U, work, lwork, pre, active, kv):
    """``n`` control periods of lanes_period from sample k0, every lane sensed afresh (``pre``, ``active``, ``kv``:
    scratch)."""
    for b in range(z.shape[0]):
        pre[b] = False
        active[b] = run[b]
    for j in range(n):
        for b in range(kv.shape[0]):
            kv[b] = k0 + j
        lanes_period(z, kv, h, substeps, plant, model, ctrl, ref, events, filt, u_res, active, info, acc, c, X,
                     U, zprev, work, lwork, pre, peek)


@jit_noalloc
def _sense(n, k0, z, ctrl, c, cw, kv):
    for j in range(n):
        for b in range(kv.shape[0]):
            kv[b] = k0 + j
        sense_lanes(z, kv, ctrl, c, cw)


@jit_noalloc
def _law(n, k0, h, z, ctrl, ref, filt, info, work, cw, kv):
    for j in range(n):
        for b in range(kv.shape[0]):
            kv[b] = k0 + j
        law_lanes(z, kv, h, ctrl, ref, filt, info, work, cw)


@jit_noalloc
def _reference(n, k0, h, ref):
    total = 0.0
    for j in range(n):
        for b in range(ref.shape[0]):
            total += reference_value((k0 + j) * h, ref[b])
    return total


@jit_noalloc
def _apply(n, z, info, ctrl, u_res, U):
    for _ in range(n):
        for b in range(z.shape[0]):
            U[b] = controller_apply(z[b], info[b], ctrl[b], info[b, I_UBASE], u_res[b])


@jit_noalloc
def _friction(n, k0, h, z, events, plant, out):
    for j in range(n):
        for b in range(z.shape[0]):
            out[b] = friction_torque((k0 + j) * h, z[b, X_OMEGA], events[b], plant[b, P_DF])


@jit_noalloc
def _plant(n, k0, h, substeps, X, U, c, events, lwork, ctrl, ref, filt, ynoise, t0):
    for j in range(n):
        for b in range(t0.shape[0]):
            t0[b] = (k0 + j) * h
        integrate_lanes(X, U, t0, h, substeps, c, events, lwork, False, ctrl, ref, filt, ynoise)


@jit_noalloc
def _check(n, z, ctrl, plant):
    total = 0
    for _ in range(n):
        for b in range(z.shape[0]):
            total += check_state(z[b], ctrl[b], plant[b])
    return total


@jit_noalloc
def _metrics(n, k0, h, acc, info, events):
    for j in range(n):
        for b in range(acc.shape[0]):
            accumulate(acc[b], info[b], h, k0 + j, events[b])


@jit_noalloc
def _copy(n, z, zprev, ctrl):
    for _ in range(n):
        for b in range(z.shape[0]):
            copy_live(zprev[b], z[b], ctrl[b], 0)


@jit_noalloc
def _peek(n, kv, h, z, ctrl, ref, peek, u_res, gid, BB, filt, c, work, cw):
    for _ in range(n):
        peek_lanes(z, ctrl, ref, peek, u_res, BB, gid, kv, h, filt, c, work, cw)


@jit_noalloc
def _observe(n, F, peek, info_ok, obs, lay, gid, scratch):
    for _ in range(n):
        observe_lanes(obs, peek, info_ok, F, lay, gid, scratch)


def live_lanes(lanes: int, steps: int = 64, seed: int = 0):
    """A native vector env of ``lanes`` sub-envs (one thread, one block) after ``steps`` steps with seeded random
    residuals, and its :class:`ehss_gym.envs.lanes.Lanes`."""
    v = EHSSTrackingVectorEnv(lanes)
    v.reset(seed=seed)
    for a in np.random.default_rng(seed).uniform(-1.0, 1.0, (steps, lanes) + v.single_action_space.shape):
        v.step(a)
    return v, v._lanes


class StageTimer:
    """The lanes of a live vector env, a copy of their state to start every timed run from, and the timings.

    Args:
        L: the env's :class:`ehss_gym.envs.lanes.Lanes` (one block).
        periods: control periods per timed run.
        repeats: timed runs per figure (the least is kept: the call's own cost on a shared machine).
    """

    def __init__(self, L, periods: int, repeats: int):
        self.L, self.periods, self.repeats = L, periods, repeats
        self.B = L.B
        self.H0, self.F0, self.IB0, self.BB0 = L.H.copy(), L.F.copy(), L.IB.copy(), L.BB.copy()
        self.hot = [hot_block(L.H, self.B, off, w) for off, w in HOT_BLOCKS]  # the env's own blocks
        # the same lanes as column blocks of one (B, N) buffer, the layout before the blocks had arrays of their own
        self.G = np.hstack(self.hot)
        edges = np.cumsum([0] + [w for _, w in HOT_BLOCKS])
        self.columns = [self.G[:, a:b] for a, b in zip(edges[:-1], edges[1:])]
        cfg = L.cfg
        self.h, self.substeps, self.ap = cfg.control_period, cfg.substeps, cfg.agent_period
        self.k0 = int(self.IB0[IB_K, 0])
        self.u_res = np.ascontiguousarray(self.F0[:, F_URES])
        self.run = self.BB0[:, BB_RUN].copy()
        self.pre = np.zeros(self.B, dtype=np.bool_)
        self.active = np.zeros(self.B, dtype=np.bool_)
        self.kv = np.zeros(self.B, dtype=np.int64)
        L.lwork[0][6][CW_TODO, :] = 1.0
        self.X = L.X[0]
        self.X[:N_PLANT] = self.hot[0][:, :N_PLANT].T

    def restore(self) -> None:
        """Every buffer back to the state the timings start from."""
        L = self.L
        L.H[:] = self.H0
        L.F[:] = self.F0
        L.IB[:] = self.IB0
        L.BB[:] = self.BB0
        self.G[:] = np.hstack(self.hot)

    def cost(self, fn, before=None) -> float:
        """ns per lane and control period of ``fn`` (which runs ``self.periods`` control periods of every lane)."""
        before = before or self.restore
        before()
        fn()  # compile, or load from the cache
        best = math.inf
        for _ in range(self.repeats):
            before()
            t0 = time.perf_counter()
            fn()
            best = min(best, time.perf_counter() - t0)
        return best / (self.B * self.periods) * 1e9

    def stages(self) -> dict:
        """The control period's stages, in the order lanes_period runs them [ns per lane and period]."""
        L, n, k0, h = self.L, self.periods, self.k0, self.h
        z, plant, _, ctrl, ref, info, _, _, acc, zprev = self.hot
        c, U, work, lwork = L.c[0], L.U[0], L.work[0], L.lwork[0]
        cw = lwork[6]
        tf = np.zeros(self.B)
        none = np.zeros(self.B)
        return {
            "sensors and model over the lanes (sense_lanes)": self.cost(lambda: _sense(n, k0, z, ctrl, c, cw,
                                                                                       self.kv)),
            "rest of the controller over the lanes (law_lanes)": self.cost(
                lambda: _law(n, k0, h, z, ctrl, ref, L.filt, info, work, cw, self.kv)),
            "  of it: the reference (reference_value)": self.cost(lambda: _reference(n, k0, h, ref)),
            "residual, valve inverse, current limit (controller_apply)": self.cost(
                lambda: _apply(n, z, info, ctrl, self.u_res, U)),
            "friction torque at the sample": self.cost(lambda: _friction(n, k0, h, z, L.events, plant, tf)),
            "plant, RK4 over the lanes (integrate_lanes)": self.cost(
                lambda: _plant(n, k0, h, self.substeps, self.X, U, c, L.events, lwork, ctrl, ref, L.filt, none,
                               np.zeros(self.B))),
            "divergence check (the live rows of the loop state)": self.cost(lambda: _check(n, z, ctrl, plant)),
            "metrics (accumulate)": self.cost(lambda: _metrics(n, k0, h, acc, info, L.events)),
            "state copy at t_k (the live rows)": self.cost(lambda: _copy(n, z, zprev, ctrl)),
        }

    def step(self) -> dict:
        """The whole compiled step and its once-per-agent-step parts [ns per lane and period]."""
        L, per_step = self.L, self.periods / self.ap
        z, _, _, ctrl, ref, _, info_ok, peek, _, _ = self.hot
        lw = L.lwork[0]

        def one_group():
            self.restore()
            L.IB[IB_GID] = 0

        return {
            "the whole compiled step (advance), per period": self.cost(lambda: advance(*L._args)) * per_step,
            f"look-ahead (peek_lanes), once per agent step of {self.ap} periods": self.cost(
                lambda: _peek(1, np.full(self.B, self.k0), self.h, z, ctrl, ref, peek, L.F[:, F_URES], L.IB[IB_GID],
                              L.BB, L.filt, L.c[0], L.work[0], lw[6]), one_group) * per_step,
            "observation, once per agent step (observe_lanes)": self.cost(
                lambda: _observe(1, L.F, peek, info_ok, L.obs, L.lay, L.IB[IB_GID], lw[0]), one_group) * per_step,
        }

    def layout(self) -> dict:
        """lanes_period and the divergence check on the env's blocks and on column blocks [ns per lane and period]."""
        L, n = self.L, self.periods

        def periods(blocks, u_res):
            return self.cost(lambda: _periods(n, self.k0, self.h, self.substeps, *(blocks[i] for i in PERIOD_BLOCKS),
                                              u_res, self.run, L.events, L.filt, L.c[0], self.X, L.U[0], L.work[0],
                                              L.lwork[0], self.pre, self.active, self.kv))

        ctrl, plant = self.hot[3], self.hot[1]
        return {
            "lanes_period, the env's blocks (lane rows contiguous)": periods(self.hot, self.u_res),
            "lanes_period, column blocks of one buffer (lane rows strided)": periods(self.columns, self.u_res),
            "divergence check, lane rows contiguous": self.cost(lambda: _check(n, self.hot[0], ctrl, plant)),
            "divergence check, lane rows strided": self.cost(lambda: _check(n, self.columns[0], ctrl, plant)),
        }


def stage_costs(lanes: int = 256, periods: int = 5, repeats: int = 40) -> dict:
    """ns per lane and control period of each stage of the vector env's compiled step at ``lanes`` sub-envs, one
    thread (module docstring). Returns ``stages`` (name -> ns, the control period's stages in order), ``step``
    (name -> ns: the whole compiled step and its per-agent-step parts), ``layout`` (name -> ns: lanes_period and the
    divergence check on the env's blocks and on column blocks), and the env's ``agent_period``, ``n_loop`` (doubles
    of loop state per lane) and ``lanes``."""
    threads = nb.get_num_threads()
    nb.set_num_threads(1)
    v, L = live_lanes(lanes)
    try:
        t = StageTimer(L, periods, repeats)
        out = {"stages": t.stages(), "step": t.step(), "layout": t.layout()}
        t.restore()
    finally:
        nb.set_num_threads(threads)
        v.close()
    return out | {"agent_period": L.cfg.agent_period, "n_loop": N_LOOP, "lanes": lanes}


def phase_costs(lanes: int = 64, phases: tuple[int, ...] = (1, 4, 16, 64), repeats: int = 30) -> dict[int, float]:
    """ns per lane and control period of the vector env's compiled step (one thread) with its ``lanes`` sub-envs in
    each number of ``phases`` (lane b restarted b mod phases agent steps after the others, as autoreset leaves lanes
    whose episodes ended early): the cost of lanes that are out of phase."""
    threads = nb.get_num_threads()
    nb.set_num_threads(1)
    out = {}
    try:
        for g in phases:
            v = EHSSTrackingVectorEnv(lanes, episode_seconds=5.0)
            v.reset(seed=0)
            late = np.arange(lanes) % g
            for i in range(1, g):
                v.step(np.zeros((lanes,) + v.single_action_space.shape, dtype=np.float32))
                v.reset(seed=i, options={"reset_mask": late >= i})
            L = v._lanes
            t = StageTimer(L, L.cfg.agent_period, repeats)
            out[len(set(L.k[:lanes].tolist()))] = t.cost(L.step)
            t.restore()
            v.close()
    finally:
        nb.set_num_threads(threads)
    return out


__all__ = ["stage_costs", "phase_costs", "live_lanes", "StageTimer", "PERIOD_BLOCKS"]
