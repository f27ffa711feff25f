"""Closed-loop simulation: ours against the same loop stepped by ``scipy.integrate.solve_ivp``.

Peer (B). The plant of Eq. (1), as documented in ``ehss_gym/core/physics.py``, is written
again here in plain Python floats and integrated by ``solve_ivp`` once per control
period with the current held (zero-order hold), the way a user without this package
would build the loop. The control law itself is the core's compiled
``controller_update`` (same estimator, reference model and Sontag law), called once per
period from Python, so both sides run the same law and differ only in how the plant
is integrated and how the loop is driven.

Ours (A). ``ehss_gym.simulate`` end to end (Python set-up plus the compiled loop), and the
compiled loop alone (``loop.run_lanes`` on prebuilt arrays).

Setting. Velocity task, n = 2, f_r = 100 Hz, sigma = 1e5, smoothing = 1e4, |u| <= 10 mA,
h = 1e-4 s (10 kHz), 10 RK4 substeps: a stable loop that stays smooth through the friction
events, so both integrations follow the same trajectory (their max relative state
difference is reported). The run checks this: it compares ours at 10 and 40 substeps
for this setting and for smoothing = 1e3, which chatters against the current limit once
friction acts, so that no integrator's trajectory is reproducible there.
"""

from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import dataclass

import numba
import numpy as np
from scipy.integrate import solve_ivp

from ehss_gym import Scenario, simulate, simulate_batch
from ehss_gym.core.controller import controller_update
from ehss_gym.core.layout import N_INFO
from ehss_gym.core.loop import run_lanes
from ehss_gym.core.sim import LoopArrays

from . import kernel_profile
from .common import (
    Section,
    Table,
    Target,
    child_main,
    interleave,
    log,
    median,
    profile,
    run_child,
    spread,
    top_own_time,
)

SETTING = dict(task="velocity", n=2, fr=100.0, sigma=1e5, smoothing=1e4, current_limit=10.0,
               control_period=1e-4, substeps=10)
ALT_SMOOTHING = 1e3  # the narrower smoothing checked (and rejected) as a benchmark setting
SOLVER = dict(method="RK45", rtol=1e-8, atol_rel=1e-10)
TARGET_RATIO = 1000.0
TARGET_SUBSTEPS = 20e6


def make_rhs(p):
    """x' of Eq. (1) as a plain-Python function f(t, x, u, amp) for solve_ivp.

    Args:
        p: PlantParams (SI units; u in mA).

    The friction amplitude ``amp`` [N*m] is held over the call, like the current:
    the core switches friction events on its integration grid (amplitude at each
    substep's midpoint), and the paper's events start and end on the control grid,
    so holding the amplitude at the period's midpoint is the same rule.
    """
    dmJ, BJ, iJ = p.d_m / p.J, p.B / p.J, 1.0 / p.J
    C = 4.0 * p.beta / p.V_m
    cd, Ps, rho, dpt2 = p.c_d, p.P_s, p.rho, p.dp_transition ** 2
    Kt, it, dv, df, csm, dm = p.K / p.tau, 1.0 / p.tau, p.delta_valve, p.delta_friction, p.c_sm, p.d_m
    sqrt = math.sqrt

    def rhs(t, x, u, amp):
        _, x2, x3, x4 = x.tolist()
        dp = Ps - x4 / sqrt(x4 * x4 + dv) * x3  # smooth sign of the valve opening, Eq. (2)
        q = cd * x4 * dp / sqrt(rho * sqrt(dp * dp + dpt2))  # orifice flow, laminar near dp = 0
        tf = amp * x2 / sqrt(x2 * x2 + df)  # Coulomb friction, Eq. (25)
        return [x2, dmJ * x3 - BJ * x2 - iJ * tf, C * (q - dm * x2 - csm * x3), Kt * u - it * x4]

    return rhs


def friction_amplitude(t: float, friction) -> float:
    """Sum of the amplitudes [N*m] of the events (A, start, end) active at t [s]."""
    return sum(a for a, t0, t1 in friction if t0 <= t < t1)


class ScipyLoop:
    """The digital loop with the plant integrated by ``solve_ivp`` over each control period.

    Args:
        sc: the scenario.
        method, rtol: solve_ivp's method and relative tolerance.
        atol_rel: absolute tolerance as a fraction of each state's scale
            (1 rad, 1 rad/s, P_s [Pa], K * 1 mA [m^2]).
    """

    def __init__(self, sc: Scenario, method: str = SOLVER["method"], rtol: float = SOLVER["rtol"],
                 atol_rel: float = SOLVER["atol_rel"]):
        self.sc = sc
        self.a = LoopArrays.build([sc])
        self.rhs = make_rhs(sc.plant)
        self.method = method
        self.rtol = rtol
        self.atol = atol_rel * np.array([1.0, 1.0, sc.plant.P_s, sc.plant.K])
        self.nfev = 0
        self.relief_hits = 0
        self.states = None

    def timed_run(self) -> None:
        """Run the whole scenario, keeping the states in ``self.states`` (for :func:`interleave`)."""
        self.run()

    def run(self, n_steps: int | None = None) -> np.ndarray:
        """Run the loop; returns the plant states at the logged instants (every ``log_every`` periods)."""
        sc, a = self.sc, self.a
        n = sc.n_steps if n_steps is None else n_steps
        h, every = sc.control_period, sc.log_every
        ps = sc.plant.P_s
        z = a.z0[0].copy()
        info = np.zeros(N_INFO)
        work = np.zeros((8, 4))
        out = np.empty(((n + every - 1) // every, 4))
        nfev = relief = 0
        for k in range(n):
            if k % every == 0:
                out[k // every] = z[:4]
            u = controller_update(z, k, h, a.model[0], a.ctrl[0], a.ref[0], a.filt[0], 0.0, info, work)
            amp = friction_amplitude((k + 0.5) * h, sc.friction)
            sol = solve_ivp(self.rhs, (k * h, (k + 1) * h), z[:4], method=self.method, rtol=self.rtol,
                            atol=self.atol, args=(u, amp))
            if not sol.success:
                raise RuntimeError(f"solve_ivp failed at step {k}: {sol.message}")
            z[:4] = sol.y[:, -1]
            if abs(z[2]) > ps:  # the core's ideal relief valves, |x3| <= P_s
                z[2] = math.copysign(ps, z[2])
                relief += 1
            nfev += sol.nfev
        if not np.all(np.isfinite(z)):
            raise RuntimeError("reference loop produced a non-finite state")
        self.nfev = nfev
        self.relief_hits = relief
        self.states = out
        return out


def max_rel_diff(ours: np.ndarray, ref: np.ndarray) -> tuple[float, np.ndarray]:
    """max_k |x_ours - x_ref| / max_k |x_ref|, per state and the max over states."""
    n = min(len(ours), len(ref))
    scale = np.maximum(np.abs(ref[:n]).max(axis=0), 1e-300)
    per_state = np.abs(ours[:n] - ref[:n]).max(axis=0) / scale
    return float(per_state.max()), per_state


@dataclass(frozen=True)
class Sizes:
    """Problem sizes of one run of the section (``--quick`` shrinks them)."""

    t_short: float  # [s] simulated in the '1 s' case
    t_long: float  # [s] simulated in the '20 s' case (and the setting check)
    reps_short: int  # interleaved repeats of the '1 s' case
    reps_long: int  # ... and of the '20 s' case
    n_batch: int  # scenarios in the substeps/s batch
    t_batch: float  # [s] each of them
    t_scale: float  # [s] each scenario of the batch-scaling runs
    setup_calls: int  # simulate() calls per set-up child process
    setup_procs: int  # set-up child processes per BLAS setting
    peer_periods: int  # control periods of the profiled peer loop

    @classmethod
    def of(cls, quick: bool) -> Sizes:
        if quick:
            return cls(0.05, 0.2, 2, 1, 32, 0.05, 0.05, 5, 1, 200)
        return cls(1.0, 20.0, 5, 3, 256, 1.0, 1.0, 15, 2, 2000)


def run(quick: bool) -> Section:
    """Section 1: ours against solve_ivp, substeps/s, batch scaling, set-up cost, and the profile bounding them."""
    sec = Section("sim", "1. Closed-loop simulation vs scipy solve_ivp", template="sim.md.j2")
    size = Sizes.of(quick)
    base = Scenario(**SETTING)
    simulate(base.replace(t_end=0.01))  # compile or load the kernels outside any timing
    check = setting_check(base, size.t_long)
    cmp, cases = versus_solve_ivp(base, size)
    sub, rates = substeps_per_second(base, size, cases["20 s"])
    scaling = batch_scaling(base, size.t_scale)
    blas, setup_ms = setup_by_blas_threads(size)
    peer_us = cases["1 s"]["peer_s"] / base.replace(t_end=size.t_short).n_steps * 1e6
    prof, bd, mix, pp = where_time_goes(base.replace(t_end=size.t_short), size.peer_periods, peer_us)
    sec.tables += [check, cmp, sub, scaling, blas, prof]
    sec.targets += [Target(f"simulate() vs solve_ivp, {label} velocity scenario", cases[label]["ratio"],
                           TARGET_RATIO) for label in ("1 s", "20 s")]
    sec.targets += [Target("plant substeps/s/core, single scenario", rates["single"], TARGET_SUBSTEPS, unit="/s"),
                    Target(f"plant substeps/s/core, batch of {size.n_batch} (numba 1 thread)", rates["batch"],
                           TARGET_SUBSTEPS, unit="/s")]
    sec.context = report_context(quick, size, base, cases, rates, (bd, mix, pp), peer_us, setup_ms)
    return sec


def report_context(quick: bool, size: Sizes, base: Scenario, cases: dict[str, dict], rates: dict,
                   profile_results: tuple[dict, dict, dict], peer_us: float, setup_ms: dict[str, float]) -> dict:
    """What ``sim.md.j2`` is rendered with: the setting, and the measurements and the explanations of misses.

    Args:
        quick: whether this is the --quick run.
        size: its problem sizes.
        base: the benchmark scenario.
        cases: :func:`versus_solve_ivp`'s measurements.
        rates: :func:`substeps_per_second`'s rates.
        profile_results: :func:`where_time_goes`'s breakdown, instruction mix and peer profile.
        peer_us: the peer's median cost per control period [us].
        setup_ms: :func:`setup_by_blas_threads`'s set-up times [ms].
    """
    bd, mix, pp = profile_results
    return {
        "quick": quick, "size": size, "setting": SETTING, "rate_khz": 1 / SETTING["control_period"] / 1e3,
        "solver": SOLVER, "threads": numba.get_num_threads(),
        "cases": list(cases.values()), "batch": batch_cost(base, size, rates, cases["1 s"]["peer_s"]),
        "bd": bd, "mix": mix, "pp": pp, "ratio_miss": ratio_miss(cases, bd, pp, peer_us, setup_ms),
        "substeps_miss": substeps_miss(rates, bd),
    }


def setting_check(base: Scenario, t_long: float) -> Table:
    """Ours at 10 vs 40 substeps for the benchmark's smoothing and the narrower one: is the loop smooth enough?"""
    log("sim: setting check (ours at 10 vs 40 substeps)")
    chk = Table("setting_check", columns=["smoothing", "used_here", "max_rel_state_diff_10_vs_40_substeps",
                                          "saturation", "tv_u_rate_mA_per_s", "max_abs_e_friction"])
    for w in (SETTING["smoothing"], ALT_SMOOTHING):
        s10, s40 = simulate_batch([base.replace(smoothing=w, t_end=t_long),
                                   base.replace(smoothing=w, t_end=t_long, substeps=40)])
        m = s10.metrics()
        chk.add(w, w == SETTING["smoothing"], max_rel_diff(s10.x, s40.x)[0], m["saturation"], m["tv_u_rate"],
                m["max_abs_e_friction"])
    return chk


def versus_solve_ivp(base: Scenario, size: Sizes) -> tuple[Table, dict[str, dict]]:
    """The '1 s' and '20 s' cases, ours and the peer interleaved.

    Returns:
        the table, and per case label its measurements: ``ratio`` (simulate() vs the peer), ``peer_s`` (the
        peer's median [s]), ``simulate_s`` and ``loop_s`` (ours' medians [s]), ``substeps`` (of one run),
        ``diff`` and ``per_state`` (max relative state difference) and ``relief_hits`` (of the peer).
    """
    cmp = Table("sim_vs_solve_ivp", columns=["scenario", "case", "repeats", "median_s", "min..max_s",
                                             "speed-up_vs_solve_ivp", "max_rel_state_diff",
                                             "solve_ivp_nfev_per_period"])
    cases = {}
    for label, t_end, reps in (("1 s", size.t_short, size.reps_short), ("20 s", size.t_long, size.reps_long)):
        sc = base.replace(t_end=t_end)
        peer = ScipyLoop(sc)
        last = {}

        def ours(sc=sc, last=last):
            last["traj"] = simulate(sc)

        log(f"sim: {label} scenario ({t_end:g} s simulated), {reps} interleaved repeats; solve_ivp is slow")
        times = interleave({"ours: simulate()": ours, "ours: compiled loop only": _run_lanes_callable(sc),
                            "solve_ivp loop": peer.timed_run}, reps)
        t_peer = median(times["solve_ivp loop"])
        diff, per_state = max_rel_diff(last["traj"].x, peer.states)
        for case, ts in times.items():
            cmp.add(label, case, reps, median(ts), spread(ts), t_peer / median(ts),
                    diff if case != "solve_ivp loop" else 0.0,
                    peer.nfev / sc.n_steps if case == "solve_ivp loop" else "")
        cases[label] = {"label": label, "ratio": t_peer / median(times["ours: simulate()"]), "peer_s": t_peer,
                        "simulate_s": median(times["ours: simulate()"]),
                        "loop_s": median(times["ours: compiled loop only"]), "substeps": sc.n_steps * sc.substeps,
                        "diff": diff, "per_state": per_state.tolist(), "relief_hits": peer.relief_hits}
    return cmp, cases


def _run_lanes_callable(sc):
    def call():
        _, args = kernel_profile.run_lanes_args([sc])
        t0 = time.perf_counter()
        run_lanes(*args)
        return time.perf_counter() - t0  # array set-up left out: the compiled loop alone

    return call


def _batch(base: Scenario, n: int, t_end: float) -> list[Scenario]:
    """n scenarios of t_end [s], n = 2, 4, 6 in turn."""
    return [base.replace(n=(2, 4, 6)[i % 3], t_end=t_end) for i in range(n)]


def substeps_per_second(base: Scenario, size: Sizes, long: dict) -> tuple[Table, dict]:
    """Plant substeps/s of the lone '20 s' case and of a batch on 1 thread and on all.

    Returns:
        the table, and the rates [substeps/s]: ``single`` (simulate(), 20 s case), ``batch`` (the batch on one
        thread), with ``batch_1thread_s``, the batch's median time on one thread [s].
    """
    batch = _batch(base, size.n_batch, size.t_batch)
    substeps = size.n_batch * batch[0].n_steps * batch[0].substeps
    threads = numba.get_num_threads()
    simulate_batch(batch[:2])  # compile or load the parallel kernel

    def batch_with(nthreads):
        def call():
            numba.set_num_threads(nthreads)
            try:
                simulate_batch(batch)
            finally:
                numba.set_num_threads(threads)
        return call

    log(f"sim: batch of {size.n_batch} x {size.t_batch:g} s, 1 thread vs {threads} threads")
    bt = interleave({"1 thread": batch_with(1), f"{threads} threads": batch_with(threads)}, 3)
    sub = Table("substeps_per_second", columns=["case", "threads", "scenarios", "median_s", "substeps_per_s",
                                                "substeps_per_s_per_core"])
    single, single_loop = long["substeps"] / long["simulate_s"], long["substeps"] / long["loop_s"]
    sub.add("single scenario, simulate() (20 s case)", 1, 1, long["simulate_s"], single, single)
    sub.add("single scenario, compiled loop only (20 s case)", 1, 1, long["loop_s"], single_loop, single_loop)
    per_core_batch = substeps / median(bt["1 thread"])
    all_threads = substeps / median(bt[f"{threads} threads"])
    sub.add(f"batch simulate_batch(), {size.t_batch:g} s each", 1, size.n_batch, median(bt["1 thread"]),
            per_core_batch, per_core_batch)
    sub.add(f"batch simulate_batch(), {size.t_batch:g} s each", threads, size.n_batch,
            median(bt[f"{threads} threads"]), all_threads, all_threads / threads)
    return sub, {"single": single, "batch": per_core_batch, "batch_1thread_s": median(bt["1 thread"])}


def batch_cost(base: Scenario, size: Sizes, rates: dict, peer_s: float) -> dict:
    """One '1 s' scenario's share of the one-thread batch [ms], and how much less that is than the peer's run."""
    per_scenario = (rates["batch_1thread_s"] / size.n_batch
                    * (base.replace(t_end=size.t_short).n_steps / base.replace(t_end=size.t_batch).n_steps))
    return {"per_scenario_ms": per_scenario * 1e3, "vs_peer": peer_s / per_scenario}


def batch_scaling(base: Scenario, t_scale: float) -> Table:
    """Throughput of batches of 1, 16 and 256 scenarios on all numba threads."""
    sizes = (1, 16, 256)
    threads = numba.get_num_threads()
    groups = {B: _batch(base, B, t_scale) for B in sizes}
    log(f"sim: batch scaling {sizes} x {t_scale:g} s, {threads} threads")
    st = interleave({B: (lambda g=g: simulate_batch(g)) for B, g in groups.items()}, 3)
    scale = Table("batch_scaling", columns=["scenarios", "median_s", "substeps_per_s", "throughput_vs_1",
                                            "s_per_scenario"])
    tput1 = None
    for B in sizes:
        n_sub = B * groups[B][0].n_steps * groups[B][0].substeps
        tp = n_sub / median(st[B])
        tput1 = tput1 or tp
        scale.add(B, median(st[B]), tp, tp / tput1, median(st[B]) / B)
    return scale


def setup_by_blas_threads(size: Sizes) -> tuple[Table, dict[str, float]]:
    """simulate()'s fixed set-up in fresh processes, with the default BLAS pool and with one BLAS thread.

    LoopArrays.build discretises the filters with scipy.linalg.expm, which goes through OpenBLAS; its thread
    pool stalls when the other core is busy, so the set-up is timed in fresh processes with the default pool
    and with one BLAS thread, interleaved.

    Returns:
        the table, and the median LoopArrays.build time [ms] per BLAS setting ("default", "1").
    """
    log("sim: simulate() set-up with the default BLAS pool vs OPENBLAS_NUM_THREADS=1 (subprocesses)")
    setup = {"default": [], "1": []}
    interleave({key: (lambda key=key: setup[key].append(_spawn_setup(key, size.t_short, size.setup_calls)))
                for key in setup}, size.setup_procs)
    blas = Table("setup_blas_threads", columns=["OpenBLAS threads", "LoopArrays.build_ms", "simulate_ms"])
    setup_ms = {}
    for key, label in (("default", "default (all cores)"), ("1", "1 (OPENBLAS_NUM_THREADS=1)")):
        setup_ms[key] = median([r["build_ms"] for r in setup[key]])
        blas.add(label, setup_ms[key], median([r["simulate_ms"] for r in setup[key]]))
    return blas, setup_ms


def _spawn_setup(blas_threads: str, t_end: float, calls: int) -> dict:
    """:func:`setup_child` in a fresh process; ``blas_threads`` "default" leaves OpenBLAS's pool as it is."""
    env = dict(os.environ)
    if blas_threads != "default":
        env["OPENBLAS_NUM_THREADS"] = blas_threads
    return run_child("bench_sim", [t_end, calls], env=env, timeout=600)


def setup_child(t_end: float, calls: int) -> dict:
    """In a fresh process: median LoopArrays.build and simulate() times [ms] for the benchmark scenario."""
    sc = Scenario(**SETTING, t_end=t_end)
    simulate(sc)
    build, sim = [], []
    for _ in range(calls):
        t0 = time.perf_counter()
        LoopArrays.build([sc])
        build.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        simulate(sc)
        sim.append(time.perf_counter() - t0)
    return {"build_ms": median(build) * 1e3, "simulate_ms": median(sim) * 1e3}


def where_time_goes(sc: Scenario, peer_periods: int, peer_us: float) -> tuple[Table, dict, dict, dict]:
    """The profile: numba timing breakdown of our kernels, the plant RHS's instruction mix, cProfile of the peer.

    Args:
        sc: the '1 s' case.
        peer_periods: control periods of the profiled peer loop.
        peer_us: the peer's median cost per control period [us] (from the interleaved runs).

    Returns:
        the table, :func:`kernel_profile.breakdown`, :func:`kernel_profile.rhs_instruction_mix` and
        :func:`_peer_profile` results.
    """
    log("sim: kernel timing breakdown and peer profile")
    bd = kernel_profile.breakdown(sc, repeats=3)
    mix = kernel_profile.rhs_instruction_mix()
    pp = _peer_profile(sc, peer_periods)
    prof = Table("sim_profile", columns=["piece", "us_per_period", "note"])
    prof.add("simulate(), single scenario", bd["simulate_us"], "end to end")
    prof.add("  Python set-up (LoopArrays.build)", bd["setup_us"], f"{bd['setup_ms']:.3g} ms per call, fixed")
    prof.add("  compiled loop (run_lanes, 1 lane)", bd["loop_us"], "")
    prof.add("    controller (controller_update)", bd["controller_us"], "estimator, ref model, Lie derivs, law")
    prof.add(f"    plant, {bd['substeps']} RK4 substeps, 1 lane", bd["plant_1lane_us"],
             f"{bd['ns_per_substep_1lane_plant']:.3g} ns per substep")
    prof.add("    rest (checks, metrics, logging, lane copies)", bd["other_1lane_us"], "")
    prof.add(f"plant, {bd['substeps']} RK4 substeps, one state (kernel_profile.scalar_plant_rk4)",
             bd["ns_per_substep_scalar_plant"] * bd["substeps"] / 1e3,
             f"{bd['ns_per_substep_scalar_plant']:.3g} ns per substep, no lane machinery")
    prof.add("plant per lane, 8-lane block", bd["ns_per_substep_8lane_plant"] * bd["substeps"] / 1e3,
             f"{bd['ns_per_substep_8lane_plant']:.3g} ns per substep per lane")
    prof.add(f"plant per lane, {bd['lanes']}-lane block", bd["plant_block_us_per_lane"],
             f"{bd['ns_per_substep_block_plant']:.3g} ns per substep per lane")
    prof.add(f"compiled loop per lane, {bd['lanes']}-lane block", bd["loop_block_us_per_lane"],
             "one thread, controller and bookkeeping included")
    prof.add("solve_ivp loop (peer), 1 s case median", peer_us,
             f"under cProfile: RHS {pp['rhs_share']:.0%}, controller {pp['ctrl_share']:.0%}, solve_ivp machinery "
             f"the rest; {pp['nfev_per_period']:.2f} RHS calls per period")
    return prof, bd, mix, pp


def _peer_profile(sc, n_periods: int) -> dict:
    """cProfile of the peer loop: share of its time in the plant RHS, the controller and solve_ivp itself."""
    loop = ScipyLoop(sc)
    st = profile(loop.run, n_periods)
    total, top = top_own_time(st)
    rhs = sum(v[2] for k, v in st.stats.items() if k[2] == "rhs")
    ctrl = sum(v[2] for k, v in st.stats.items() if "controller_update" in str(k))
    return {"total_s": total, "rhs_share": rhs / total, "ctrl_share": ctrl / total, "top": top,
            "periods": n_periods, "nfev_per_period": loop.nfev / n_periods}


def ratio_miss(cases: dict, bd: dict, pp: dict, peer_us: float, setup_ms: dict) -> dict | None:
    """The numbers that explain a missed speed-up target; None when both cases meet it."""
    if not min(cases["1 s"]["ratio"], cases["20 s"]["ratio"]) < TARGET_RATIO:
        return None
    budget_ns = peer_us / TARGET_RATIO * 1e3
    plant_block_ns = bd["plant_block_us_per_lane"] * 1e3
    return {"target": TARGET_RATIO, "peer_us": peer_us, "rhs_share": pp["rhs_share"], "budget_ns": budget_ns,
            "plant_block_ns": plant_block_ns, "plant_vs_budget": plant_block_ns / budget_ns,
            "controller_ns": bd["controller_us"] * 1e3, "setup_ms": setup_ms,
            "blas_pool_stalls": setup_ms["default"] > 2 * setup_ms["1"],
            "ceiling_batch": peer_us / bd["loop_block_us_per_lane"], "ceiling_single": peer_us / bd["loop_us"]}


def substeps_miss(rates: dict, bd: dict) -> dict | None:
    """The numbers that explain a missed substeps/s/core target; None when both rates meet it."""
    if not (rates["single"] < TARGET_SUBSTEPS or rates["batch"] < TARGET_SUBSTEPS):
        return None
    return {"single_M": rates["single"] / 1e6, "scalar_M": 1e3 / bd["ns_per_substep_scalar_plant"],
            "batch_M": rates["batch"] / 1e6,
            "rest_block_us": bd["loop_block_us_per_lane"] - bd["plant_block_us_per_lane"]}


def main(argv=None) -> int:
    return child_main(setup_child, {"T_END": float, "CALLS": int}, "set-up timing child of the sim benchmark", argv)


if __name__ == "__main__":
    sys.exit(main())
