"""The arrays of B closed loops, shared by the single and the vector env: their one step (:meth:`Lanes.step`) and the
info it reports (:func:`step_info`)."""

from __future__ import annotations

import math

import numpy as np

from ehss_gym.core.controller import model_constants
from ehss_gym.core.filters import filter_block
from ehss_gym.core.layout import (
    EV_END,
    EV_START,
    I_E,
    I_S,
    I_SAT,
    I_T,
    I_TF,
    I_UAPP,
    I_UBASE,
    I_URES,
    I_V,
    M_DST_MAX,
    M_DST_STEPS,
    M_DST_SUM_ABS,
    M_STEPS,
    M_SUM_U2,
    M_TRK_STEPS,
    M_TRK_SUM_ABS,
    M_TRK_SUM_E2,
    M_TV_U,
    MAX_DELAY,
    N_INFO,
    N_LOOP,
    N_METRICS,
    N_PARAM,
    N_REF,
)
from ehss_gym.core.loop import N_LWORK, init_filters
from ehss_gym.core.metrics import init_accumulator, summarize_acc
from ehss_gym.core.physics import N_LANE_CONST, lane_constants
from ehss_gym.core.references import reference_value
from ehss_gym.core.registry import REFERENCE_FAMILIES
from ehss_gym.core.resolution import CURRENT_FLOOR, ERROR_RESOLUTION, TV_FLOOR, valve_floors
from ehss_gym.core.scenarios import (
    PHYSICAL_FIELDS,
    TRAIN_SEED_LIMIT,
    describe,
    paper_scenario,
    sample_scenario,
)
from ehss_gym.core.settings import (
    C_BASE,
    C_DOB_GAIN,
    C_INV_HYSTERESIS,
    C_INV_THRESHOLD,
    C_LAYER_GAIN,
    C_NOISE_THETA,
    C_OMEGA_MAX,
    C_P_BOUND,
    C_REF_DELAY,
    C_SEED,
    C_SHIFT,
    C_SHIFT_ON,
    C_SIGMA,
    C_SMOOTH,
    N_CTRL,
    Scenario,
    ctrl_row,
    unmodelled_slots,
)
from ehss_gym.core.sim import simulate_batch

from .actions import (
    ACTIONS,
    action_code,
    action_dims,
    action_mode,
    compensation_factors,
    period_constants,
    schedule_factors,
)
from .buffers import (
    BB_ACT,
    BB_PRE,
    BB_RUN,
    F_ACT,
    F_RCLS,
    F_REW,
    F_RPHYS,
    F_STATS,
    F_URES,
    FLAG_LAST,
    FLAG_MEM,
    FLAG_SQUASH,
    H_ACC,
    H_CTRL,
    H_INFO_OK,
    H_MODEL,
    H_PEEK,
    H_PLANT,
    H_REF,
    H_Z,
    HOT_BLOCKS,
    IB_K,
    IB_NSTEP,
    LAY_FLAGS,
    LAY_SCALE,
    LAY_SRC,
    N_BB,
    N_F,
    N_H,
    N_IB,
    N_PEEK,
    N_RCLS,
    N_RPHYS,
    N_STATS,
    P_DMA,
    P_K,
    P_MA,
    P_MS,
    P_N,
    P_NCLS,
    P_NDST,
    P_NTRK,
    P_PK,
    P_TV,
    P_U2,
    R_B,
    R_DST_ABS,
    R_DST_MAX,
    R_K,
    R_TRK_ABS,
    R_TRK_E2,
    R_TV,
    R_U2,
    R_W,
    S_SATF,
    W_ACT_C1,
    W_ACT_C2,
    W_ACT_MODE,
    W_ACT_PERIOD,
    block,
)
from .config import SCENARIOS, EnvConfig
from .kernels import advance, advance_chunks, advance_held, held_record, observe, reward_weights
from .observation import observation_layout

MAX_EVENTS = 4  # friction-event slots per lane (grown on demand)
hot_block = block.py_func  # a hot block's (B, width) view, from Python (numpy's reshape of a slice is a view)
# The class reward's parts: (slot R_*, accumulator sum M_*, its weight in the class's log figure, the class).
# log q_trk = 1/4 log(sum e^2 ratio) + 1/2 log(IAE ratio) (the RMSE is a square root), log q_dst = 1/2 log(peak
# ratio) + 1/2 log(IAE ratio), log q_eff = 1/2 log(TV ratio) + 1/4 log(sum u^2 ratio).
CLASS_PARTS = ((R_TRK_E2, M_TRK_SUM_E2, 0.25, "tracking"), (R_TRK_ABS, M_TRK_SUM_ABS, 0.5, "tracking"),
               (R_DST_ABS, M_DST_SUM_ABS, 0.5, "disturbance"), (R_DST_MAX, M_DST_MAX, 0.5, "disturbance"),
               (R_TV, M_TV_U, 0.5, "effort"), (R_U2, M_SUM_U2, 0.25, "effort"))


def base_law_run(sc: Scenario, agent_period: int) -> np.ndarray:
    """The metrics accumulator (M_*) of the base law's run of an episode's K whole agent steps: zero residual, the
    disturbance observer and the compensators off (the law alone, which a residual or the observer is measured
    against); what the class and the physical rewards take their constants from."""
    return base_law_runs([sc], agent_period)[0]


def base_law_runs(scs: list[Scenario], agent_period: int) -> list[np.ndarray]:
    """:func:`base_law_run` of several episodes in one batch (:func:`ehss_gym.core.sim.simulate_batch`: lanes in
    lock-step, each lane's arithmetic its own, so every accumulator is the one its episode's own run gives)."""
    laws = []
    for sc in scs:
        K = sc.n_steps // agent_period
        laws.append(sc.replace(t_end=K * agent_period * sc.control_period, log_interval=sc.t_end, dob_hz=0.0,
                               reference_delay=0.0, inverse_threshold=0.0, inverse_hysteresis=0.0))
    return [t.acc for t in simulate_batch(laws)]


def class_coefficients(sc: Scenario, agent_period: int, base: np.ndarray | None = None) -> np.ndarray:
    """The class reward's constants (R_*) of an episode, from the base law's run of it (``base``, its accumulator;
    default: :func:`base_law_run`).

    A part of a class the episode has (tracking and disturbance if it has samples in their windows, effort always)
    gets its weight in the class's log figure over the number of such classes (the ruler's mean over classes), the
    others 0; the base law's totals and the episode's agent steps K complete them (see
    :func:`ehss_gym.envs.kernels.class_reward`). A part whose base total is 0 (no sample moved it) is left out.
    """
    base = base_law_run(sc, agent_period) if base is None else base
    present = {"tracking": base[M_TRK_STEPS] > 0, "disturbance": base[M_DST_STEPS] > 0, "effort": True}
    n_cls = sum(present.values())
    out = np.zeros(N_RCLS)
    for slot, m, w, cls in CLASS_PARTS:
        if present[cls] and base[m] > 0.0:
            out[R_W + slot] = w / n_cls
            out[R_B + slot] = base[m]
    out[R_K] = sc.n_steps // agent_period
    return out


def physical_coefficients(sc: Scenario, agent_period: int, base: np.ndarray | None = None,
                          valve: tuple[float, float] = (TV_FLOOR, CURRENT_FLOOR)) -> np.ndarray:
    """The physical reward's constants (P_*) of an episode, from the base law's run of it (``base``, its accumulator;
    default: :func:`base_law_run`): its samples in the tracking and disturbance windows and in all, its agent steps K,
    its number of classes (tracking and disturbance where their windows have samples, effort always), and each
    metric's scale, its physical floor (:mod:`ehss_gym.core.resolution`) plus the base law's level over the episode
    (:func:`ehss_gym.envs.kernels.physical_reward`). ``valve``: the rig's valve floors (TV [mA/s], current [mA];
    :func:`ehss_gym.core.resolution.valve_floors`), Table I's by default."""
    base = base_law_run(sc, agent_period) if base is None else base
    e, h = ERROR_RESOLUTION[sc.task], sc.control_period
    out = np.zeros(N_RPHYS)
    n_trk, n_dst, n = base[M_TRK_STEPS], base[M_DST_STEPS], base[M_STEPS]
    out[P_NTRK], out[P_NDST], out[P_N] = n_trk, n_dst, n
    out[P_K] = sc.n_steps // agent_period
    out[P_NCLS] = 1 + (n_trk > 0) + (n_dst > 0)
    out[P_MS] = e * e + (base[M_TRK_SUM_E2] / n_trk if n_trk else 0.0)
    out[P_MA] = e + (base[M_TRK_SUM_ABS] / (n_trk * h) if n_trk else 0.0)
    out[P_PK] = e + base[M_DST_MAX]
    out[P_DMA] = e + (base[M_DST_SUM_ABS] / (n_dst * h) if n_dst else 0.0)
    tv_floor, current_floor = valve
    out[P_TV] = tv_floor + base[M_TV_U] / (n * h)
    out[P_U2] = current_floor * current_floor + base[M_SUM_U2] / n
    return out


STEP_INFO_KEYS = ("t", "e", "s", "V", "u_base", "u_residual", "u_applied", "saturated", "sat_fraction",
                  "friction_torque", "clipped", "n_clipped", "diverged", "lost_track")  # step_info's, in its order


def step_info(i, st, clipped, n_clipped, diverged, lost_track) -> dict:
    """The ``info`` of an env step (the env's docstring lists it): the same keys for the single and the vector env.

    Args:
        i: the last finite control sample's info row (layout I_*): one lane's as a list (the single env), or the
            lanes' block transposed, ``i[k]`` the column of index k (the vector env).
        st: the step's statistics (S_*), the same way.
        clipped, n_clipped, diverged, lost_track: the action was clipped, clipped actions in the episode, the loop
            diverged in the step, the episode has lost track (values, or arrays over the lanes).
    """
    return {"t": i[I_T], "e": i[I_E], "s": i[I_S], "V": i[I_V], "u_base": i[I_UBASE], "u_residual": i[I_URES],
            "u_applied": i[I_UAPP], "saturated": i[I_SAT] > 0.0, "sat_fraction": st[S_SATF],
            "friction_torque": i[I_TF], "clipped": clipped, "n_clipped": n_clipped, "diverged": diverged,
            "lost_track": lost_track}


class Lanes:
    """State and scratch arrays of B closed loops (padded to whole chunks) and the calls into the kernels."""

    def __init__(self, cfg: EnvConfig, n_lanes: int, chunk: int | None = None):
        self.cfg = cfg
        self.chunk = n_lanes if chunk is None else chunk
        self.n_chunks = -(-n_lanes // self.chunk)
        B = self.B = self.n_chunks * self.chunk
        self.n_lanes = n_lanes
        tmpl = cfg.template()
        base = ctrl_row(tmpl)
        base[C_BASE] = 1.0 if cfg.mode == "residual" else 0.0
        self.action = action_mode(cfg.action)
        self.action_dims = action_dims(self.action, cfg.dob_hz)
        base[C_SHIFT_ON] = 1.0 if self.action.shift else 0.0
        self.ctrl_base = base
        nominal = cfg.plant.plant.as_array()  # the rows before a lane's first episode: the rig's
        self.F = np.zeros((B, N_F))
        self.IB = np.zeros((N_IB, B), dtype=np.int64)  # a row per quantity (buffers.IB_*)
        self.BB = np.zeros((B, N_BB), dtype=np.bool_)
        self.H = np.zeros(B * N_H)  # the hot blocks, block after block (buffers.py says why)
        # named views into the buffers (writes go to H, F, IB, BB)
        self.z = hot_block(self.H, B, H_Z, N_LOOP)
        self.plant = hot_block(self.H, B, H_PLANT, N_PARAM)
        self.model = hot_block(self.H, B, H_MODEL, N_PARAM)
        self.ctrl = hot_block(self.H, B, H_CTRL, N_CTRL)
        self.ref = hot_block(self.H, B, H_REF, N_REF)
        self.info_ok = hot_block(self.H, B, H_INFO_OK, N_INFO)
        self.acc = hot_block(self.H, B, H_ACC, N_METRICS)
        self.peek = hot_block(self.H, B, H_PEEK, N_PEEK)  # the controller's view at the next sample, then its state
        self.stats = self.F[:, F_STATS:F_STATS + N_STATS]
        self.u_res = self.F[:, F_URES]
        self.rew = self.F[:, F_REW]
        # lane 0's rows, pre-made for the single env's step: stats (N_STATS), residual and reward in one view
        self.info_ok0 = self.info_ok[0]
        self.acc0 = self.acc[0]
        self.tail0 = self.F[0, F_STATS:F_REW + 1]
        self.k = self.IB[IB_K]
        self.nstep = self.IB[IB_NSTEP]
        self.run = self.BB[:, BB_RUN]
        self.plant[:] = nominal
        self.model[:] = cfg.plant.controller_model.as_array()
        self.ctrl[:] = base
        self.events = self._empty_events(B, MAX_EVENTS)
        self.filt = np.tile(filter_block(cfg.order, tmpl.ref_model_hz, cfg.estimator_hz, cfg.control_period,
                                         cfg.estimator, cfg.observer_hz), (B, 1, 1, 1))
        self.c = np.zeros((self.n_chunks, N_LANE_CONST, self.chunk))
        for i in range(self.n_chunks):
            lanes = slice(i * self.chunk, (i + 1) * self.chunk)
            lane_constants(np.ascontiguousarray(self.plant[lanes]), self.c[i])
            model_constants(self.model[lanes], self.ctrl[lanes], self.c[i])
        self.X = np.zeros((self.n_chunks, N_LOOP, self.chunk))
        self.U = np.zeros((self.n_chunks, self.chunk))
        self.work = np.zeros((self.n_chunks, 8, 4))
        self.lwork = np.zeros((self.n_chunks, N_LWORK, N_LOOP, self.chunk))
        self.layout = observation_layout(cfg)
        self.lay = np.zeros((3, len(self.layout)))
        for i, (_, src, scale, squash, _) in enumerate(self.layout):
            self.lay[LAY_SRC, i] = src
            self.lay[LAY_SCALE, i] = scale
            last = src in (I_UAPP, I_URES)  # the applied/residual current of the last period, not a peek
            mem = src < 0  # a memory feature (observation_layout: -1 - its index in F_MEM)
            self.lay[LAY_SRC, i] = -1 - src if mem else src
            self.lay[LAY_FLAGS, i] = (FLAG_SQUASH if squash else 0) + (FLAG_LAST if last else 0) + (
                FLAG_MEM if mem else 0)
        self.obs = np.zeros((B, len(self.layout)), dtype=np.float32)
        self.obs0 = self.obs[0]
        rw = cfg.reward_weights
        self.wts = reward_weights(rw, cfg.error_scale, cfg.residual_scale, cfg.memory_tau, cfg.agent_dt)
        self.wts[W_ACT_MODE] = action_code(cfg.action)
        self.wts[W_ACT_PERIOD] = 0.0 if self.action.period is None else 1.0
        self.wts[W_ACT_C1], self.wts[W_ACT_C2] = period_constants(self.action, cfg.action_bound, cfg.control_period)
        self._write = ACTION_WRITERS[self.action.write]
        self.elog = np.zeros((B, 1), dtype=np.float32)
        self.T = np.zeros(B, dtype=np.int64)  # agent steps in each lane's episode
        self.scenarios: list[Scenario | None] = [None] * B
        self.tmp_c = np.zeros((N_LANE_CONST, 1))
        self._bind()

    @staticmethod
    def _empty_events(B: int, E: int) -> np.ndarray:
        ev = np.zeros((B, E, 3))
        ev[:, :, EV_START] = ev[:, :, EV_END] = math.inf  # padding never fires
        return ev

    @staticmethod
    def check(sc: Scenario) -> None:
        """ValueError for a scenario the lanes cannot hold (a reference that is not parametric)."""
        if len(sc.reference.spec) != N_REF:
            parametric = ", ".join(f.name for f in REFERENCE_FAMILIES if f.parametric)
            raise ValueError(f"the env runs the parametric references ({parametric}), not a "
                             f"{sc.reference.family!r} reference: its lanes hold fixed-size rows; simulate it with "
                             "ehss_gym.simulate")

    def needs_base_run(self) -> bool:
        """The env's reward takes constants from the base law's run of each episode (:func:`base_law_run`)."""
        rw = self.cfg.reward_weights
        return rw.get("class", 0.0) > 0.0 or rw.get("physical", 0.0) > 0.0

    def load_many(self, lanes, scs: list[Scenario]) -> None:
        """:meth:`load` of several lanes, the base law's runs of their episodes (where the reward needs them) in one
        batch (:func:`base_law_runs`): what a vector env's lanes that restart together cost."""
        for sc in scs:  # a scenario the lanes cannot hold is refused before the batch runs
            self.check(sc)
        bases = base_law_runs(scs, self.cfg.agent_period) if self.needs_base_run() and len(scs) > 1 else None
        for i, (b, sc) in enumerate(zip(lanes, scs)):
            self.load(b, sc, None if bases is None else bases[i])

    def load(self, b: int, sc: Scenario, base: np.ndarray | None = None) -> None:
        """Put lane b at the start of scenario ``sc`` (rows as :meth:`ehss_gym.core.sim.LoopArrays.build` has them);
        ``base``: the base law's run of it (:func:`base_law_run`), where the caller has it already."""
        cfg = self.cfg
        self.check(sc)
        if len(sc.friction) > self.events.shape[1]:
            ev = self._empty_events(self.B, len(sc.friction))
            ev[:, :self.events.shape[1]] = self.events
            self.events = ev
            self._bind()
        self.F[b] = 0.0
        for off, width in HOT_BLOCKS:
            hot_block(self.H, self.B, off, width)[b] = 0.0
        self.plant[b] = sc.plant.as_array()
        self.model[b] = (sc.model or sc.plant).as_array()
        row = self.ctrl[b]
        row[:] = self.ctrl_base
        row[C_SEED] = sc.seed
        row[C_NOISE_THETA:C_NOISE_THETA + 4] = sc.noise_std
        row[C_OMEGA_MAX] = sc.omega_max
        row[C_P_BOUND] = sc.pressure_bound
        unmodelled_slots(sc.unmodelled, row)
        self.ref[b] = sc.reference.spec
        self.events[b, :, :] = 0.0
        self.events[b, :, EV_START] = self.events[b, :, EV_END] = math.inf
        if sc.friction:
            self.events[b, :len(sc.friction)] = sc.friction
        init_filters(self.z[b], self.filt[b], reference_value(0.0, self.ref[b]))
        lane_constants(self.plant[b:b + 1].copy(), self.tmp_c)
        model_constants(self.model[b:b + 1], self.ctrl[b:b + 1], self.tmp_c)
        self.c[b // self.chunk][:, b % self.chunk] = self.tmp_c[:, 0]
        init_accumulator(self.acc[b], sc.lost_track_bound)
        rw = cfg.reward_weights
        if self.needs_base_run():
            base = base_law_run(sc, cfg.agent_period) if base is None else base  # once for both rewards
            if rw.get("class", 0.0) > 0.0:
                self.F[b, F_RCLS:F_RCLS + N_RCLS] = class_coefficients(sc, cfg.agent_period, base)
            if rw.get("physical", 0.0) > 0.0:
                self.F[b, F_RPHYS:F_RPHYS + N_RPHYS] = physical_coefficients(
                    sc, cfg.agent_period, base, valve_floors(cfg.plant.rated_current, cfg.plant.plant.tau))
        self.IB[:, b] = 0
        self.BB[b, BB_PRE] = False  # the look-ahead of the previous episode is stale
        self.run[b] = True
        T = sc.n_steps // cfg.agent_period
        self.T[b] = T
        if T > self.elog.shape[1]:
            el = np.zeros((self.B, T), dtype=np.float32)
            el[:, :self.elog.shape[1]] = self.elog
            self.elog = el
            self._bind()
        self.scenarios[b] = sc

    def set_actions(self, idx, a: np.ndarray) -> None:
        """Write the agent step's actions ``a`` (len(idx), k), already clipped to [-1, 1], into lanes ``idx``, as the
        env's action mode does (:mod:`ehss_gym.envs.actions`)."""
        self._write(self, idx, a)

    def resense(self, idx) -> None:
        """Drop the look-ahead of lanes ``idx``: their next period computes its sample afresh (the same arithmetic,
        with the law's inputs the action has just changed)."""
        self.BB[idx, BB_PRE] = False

    def observe(self, lanes) -> None:
        """Fill the observations of the given lanes from their current state (no time passes)."""
        self.BB[:, BB_ACT] = False
        self.BB[lanes, BB_ACT] = True
        observe(self.cfg.control_period, self.F, self.H, self.IB, self.BB, self.filt, self.c, self.work, self.lwork,
                self.obs, self.lay)

    def _bind(self) -> None:
        # Pre-bound kernel arguments: a step then costs one call, not a dozen attribute look-ups.
        cfg = self.cfg
        self._args = (cfg.agent_period, cfg.control_period, cfg.substeps, self.F, self.H, self.IB, self.BB,
                      self.events, self.filt, self.c[0], self.X[0], self.U[0], self.work[0], self.lwork[0], self.obs,
                      self.elog, self.lay, self.wts)
        self._pargs = (self.chunk, cfg.agent_period, cfg.control_period, cfg.substeps, self.F, self.H, self.IB,
                       self.BB, self.events, self.filt, self.c, self.X, self.U, self.work, self.lwork, self.obs,
                       self.elog, self.lay, self.wts)

    def step(self) -> None:
        """One agent step of every running lane (``run``), each with its residual ``u_res`` [mA]: one compiled call
        (:func:`ehss_gym.envs.kernels.advance`; with several chunks, :func:`~ehss_gym.envs.kernels.advance_chunks`
        in parallel threads). Afterwards ``obs``, ``rew``, ``info_ok``, ``stats`` and ``acc`` hold each lane's
        observation, reward, last finite control sample, step statistics and metrics accumulator."""
        if self.n_chunks == 1:
            advance(*self._args)
        else:
            advance_chunks(*self._pargs)

    def step_held(self, n_max: int, stop_lost: bool, rec: np.ndarray, rsum: np.ndarray) -> int:
        """Up to ``n_max`` agent steps of :meth:`step` with the lanes' actions held, stopping after the first in which
        a lane ends (diverges, or loses track where ``stop_lost``); one compiled call for one chunk
        (:func:`ehss_gym.envs.kernels.advance_held`). Each step adds the rewards of the lanes that stepped to ``rsum``
        (B,) and, where ``rec`` (K, n, N_INFO) has its row, copies their last finite samples into it. Returns the
        steps taken."""
        if self.n_chunks == 1:
            return advance_held(n_max, stop_lost, rec, rsum, *self._args)
        for k in range(n_max):
            advance_chunks(*self._pargs)
            if held_record(k, stop_lost, rec, rsum, self.F, self.H, self.IB, self.BB):
                return k + 1
        return n_max

    def metrics(self, b: int) -> dict:
        """The core metrics summary of lane b's episode so far (with recovery times from the agent-rate log)."""
        sc = self.scenarios[b]
        n = int(min(self.IB[IB_NSTEP, b], self.elog.shape[1]))
        per = self.cfg.agent_period
        t = ((np.arange(n) + 1) * per - 1) * self.cfg.control_period
        return summarize_acc(self.acc[b], sc, t, self.elog[b, :n].astype(np.float64))

    def draw(self, b: int, cfg: EnvConfig, rng: np.random.Generator, options) -> tuple[Scenario, dict]:
        """Choose lane b's next scenario from the env setting and reset options; returns it and its info."""
        choice = cfg.scenario
        if options:
            bad = sorted(set(options) - {"scenario"})
            if bad:
                raise ValueError(f"unknown reset option(s) {bad}; valid: ['scenario']")
            choice = options.get("scenario", choice)
        tmpl = self.template
        info: dict = {}
        if isinstance(choice, Scenario):
            cfg.check_pinned(choice)
            sc = choice
            info["scenario_name"] = "pinned"
        elif isinstance(choice, dict):
            bad = sorted(set(choice) - set(PHYSICAL_FIELDS))
            if bad:
                raise ValueError(f"scenario dict has unknown field(s) {bad}; valid: {list(PHYSICAL_FIELDS)}")
            sc = paper_scenario(tmpl, cfg.episode_seconds).replace(**choice)
            info["scenario_name"] = "custom"
        elif choice == "paper":
            sc = paper_scenario(tmpl, cfg.episode_seconds)
            info["scenario_name"] = "paper"
        elif choice == "random":
            seed = int(rng.integers(0, TRAIN_SEED_LIMIT))
            sc = sample_scenario(seed, tmpl, cfg.episode_seconds, cfg.distribution())  # the valve sized on the rig
            info["scenario_name"] = "random"
            info["scenario_seed"] = seed
        else:
            raise ValueError(f"options['scenario'] must be one of {list(SCENARIOS)}, a dict of "
                             f"{list(PHYSICAL_FIELDS)} or a Scenario, got {choice!r}")
        if sc.n_steps < cfg.agent_period:
            raise ValueError(f"scenario t_end ({sc.t_end:g} s) is shorter than one agent step ({cfg.agent_dt:g} s)")
        info["scenario"] = describe(sc, tmpl.plant)
        return sc, info

    @property
    def template(self) -> Scenario:
        t = getattr(self, "_template", None)
        if t is None:
            t = self._template = self.cfg.template()
        return t


# --- the action modes' writers (ehss_gym.envs.actions: each row names its writer here) ---------------------------


def write_current(lanes: Lanes, idx, a: np.ndarray) -> None:
    """The current action: the residual ``residual_scale * a`` [mA], held over the agent step."""
    lanes.u_res[idx] = a[:, 0] * lanes.cfg.residual_scale


def write_held(lanes: Lanes, idx, a: np.ndarray) -> None:
    """The rate and filtered actions: the action, which the kernel turns into the residual every period."""
    lanes.F[idx, F_ACT:F_ACT + a.shape[1]] = a


def _shift(lanes: Lanes, idx, a0: np.ndarray) -> None:
    """The law's reference shift delta = ``action_bound * a0`` [output unit]."""
    lanes.ctrl[idx, C_SHIFT] = a0 * lanes.cfg.action_bound


def _schedule(lanes: Lanes, idx, a: np.ndarray) -> None:
    """The law's boundary-layer width (smoothing and adaptive gain), sigma and (a third column: the observer on) the
    observer's gain 1 - exp(-2 pi f_d h) at the scaled bandwidth, each the template's times its factor of ``a``."""
    f = schedule_factors(a)
    base = lanes.ctrl_base
    lanes.ctrl[idx, C_SMOOTH] = base[C_SMOOTH] * f[:, 0]
    lanes.ctrl[idx, C_LAYER_GAIN] = base[C_LAYER_GAIN] * f[:, 0]
    lanes.ctrl[idx, C_SIGMA] = base[C_SIGMA] * f[:, 1]
    if a.shape[1] > 2:  # at factor 1 the template's own gain, bit for bit
        scaled = -np.expm1(-2.0 * math.pi * lanes.cfg.dob_hz * f[:, 2] * lanes.cfg.control_period)
        lanes.ctrl[idx, C_DOB_GAIN] = np.where(f[:, 2] == 1.0, base[C_DOB_GAIN], scaled)


def write_reference(lanes: Lanes, idx, a: np.ndarray) -> None:
    """The reference action: the law's reference shift delta = ``action_bound * a`` [output unit]."""
    write_held(lanes, idx, a)
    _shift(lanes, idx, a[:, 0])
    lanes.resense(idx)


def write_schedule(lanes: Lanes, idx, a: np.ndarray) -> None:
    """The schedule action: the law's boundary-layer width, sigma and (observer on) bandwidth scaled by its factors."""
    write_held(lanes, idx, a)
    _schedule(lanes, idx, a)
    lanes.resense(idx)


def write_reference_schedule(lanes: Lanes, idx, a: np.ndarray) -> None:
    """The reference-schedule action: a_0 the reference shift, a_1 and a_2 the width and sigma factors."""
    write_held(lanes, idx, a)
    _shift(lanes, idx, a[:, 0])
    _schedule(lanes, idx, a[:, 1:3])
    lanes.resense(idx)


def write_compensation(lanes: Lanes, idx, a: np.ndarray) -> None:
    """The compensation action: a_0 scales the valve inverse's threshold and hysteresis, a_1 the reference delay (at
    most MAX_DELAY samples), each the template's times 1 + a; a_2 and a_3 the width and sigma factors."""
    write_held(lanes, idx, a)
    f = compensation_factors(a[:, :2])
    base = lanes.ctrl_base
    lanes.ctrl[idx, C_INV_THRESHOLD] = base[C_INV_THRESHOLD] * f[:, 0]
    lanes.ctrl[idx, C_INV_HYSTERESIS] = base[C_INV_HYSTERESIS] * f[:, 0]
    lanes.ctrl[idx, C_REF_DELAY] = np.minimum(base[C_REF_DELAY] * f[:, 1], MAX_DELAY)
    _schedule(lanes, idx, a[:, 2:4])
    lanes.resense(idx)


ACTION_WRITERS = {row.write: globals()[row.write] for row in ACTIONS}
