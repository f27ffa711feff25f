"""Where the closed loop's time goes: a timing breakdown of the compiled kernels and their instruction mix.

cProfile sees one opaque call into numba, so the profile here times the pieces
separately with small compiled drivers that call the core's own kernels:

- the whole loop (``loop.run_lanes``, what ``simulate`` runs after its Python set-up);
- the controller alone (``controller.controller_update``: estimator, reference model,
  Lie derivatives, Sontag law), once per control period;
- the plant alone (``physics.integrate_lanes``: RK4 substeps of Eq. 1), for 1, 8 and a full
  block of lanes, and, as the latency floor of one lane, the same RK4 written for one state with no lane machinery
  (:func:`scalar_plant_rk4`, here only: the package has one integrator);
- the Python set-up of ``simulate`` (``LoopArrays.build``: filter discretisation etc.).

and reads the machine code numba generated for the plant right-hand side
(vector width and the count of square roots and divisions, the expensive
instructions of Eq. 1) and for each stage of the control period (:func:`control_period_mix`: packed and scalar
instructions, and the libm calls that keep a stage scalar).
"""

from __future__ import annotations

import re
import time

import numba as nb
import numpy as np

from ehss_gym import simulate
from ehss_gym.core.controller import controller_update
from ehss_gym.core.layout import N_INFO, N_LOG, N_METRICS, X_OMEGA, X_PL
from ehss_gym.core.loop import MAX_LANES, run_lanes
from ehss_gym.core.params import P_DF, P_PS
from ehss_gym.core.physics import (
    N_LANE_CONST,
    active_amplitude,
    integrate_lanes,
    lane_constants,
    lane_rhs,
    plant_only_arrays,
    plant_rhs,
    relief,
)
from ehss_gym.core.sim import LoopArrays


@nb.njit(cache=True, error_model="numpy")
def _drive_plant(X, U, h, substeps, c, events, work, n_periods, ctrl, ref, filt, ynoise):
    t0 = np.empty(X.shape[1])  # the lanes' start times [s]: all in phase
    for k in range(n_periods):
        t0[:] = k * h
        integrate_lanes(X, U, t0, h, substeps, c, events, work, False, ctrl, ref, filt, ynoise)
    return X[1, 0]


@nb.njit(cache=True, error_model="numpy")
def scalar_plant_rk4(x, u, t0, h, substeps, p, events, work):
    """The loop's RK4 (:func:`ehss_gym.core.physics.integrate_lanes`) for one plant state ``x`` and no lanes: what a
    lone scenario's plant would cost without the lane machinery (``work``: scratch (5, 4))."""
    dt = h / substeps
    k1, k2, k3, k4, xt = work[0], work[1], work[2], work[3], work[4]
    for j in range(substeps):
        amp = active_amplitude(t0 + (j + 0.5) * dt, events)
        plant_rhs(x, u, amp * (x[X_OMEGA] / np.sqrt(x[X_OMEGA] * x[X_OMEGA] + p[P_DF])), p, k1)
        for i in range(4):
            xt[i] = x[i] + 0.5 * dt * k1[i]
        plant_rhs(xt, u, amp * (xt[X_OMEGA] / np.sqrt(xt[X_OMEGA] * xt[X_OMEGA] + p[P_DF])), p, k2)
        for i in range(4):
            xt[i] = x[i] + 0.5 * dt * k2[i]
        plant_rhs(xt, u, amp * (xt[X_OMEGA] / np.sqrt(xt[X_OMEGA] * xt[X_OMEGA] + p[P_DF])), p, k3)
        for i in range(4):
            xt[i] = x[i] + dt * k3[i]
        plant_rhs(xt, u, amp * (xt[X_OMEGA] / np.sqrt(xt[X_OMEGA] * xt[X_OMEGA] + p[P_DF])), p, k4)
        for i in range(4):
            x[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        x[X_PL] = relief(x[X_PL], p[P_PS])


@nb.njit(cache=True, error_model="numpy")
def _drive_scalar_plant(x, u, h, substeps, p, events, work, n_periods):
    for k in range(n_periods):
        scalar_plant_rk4(x, u, k * h, h, substeps, p, events, work)
    return x[1]


@nb.njit(cache=True, error_model="numpy")
def _drive_controller(z, h, model, ctrl, ref, filt, info, work, n_periods):
    total = 0.0
    for k in range(n_periods):
        total += controller_update(z, k, h, model, ctrl, ref, filt, 0.0, info, work)
    return total


def _best_of(fn, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def run_lanes_args(scenarios):
    """The arrays of ``scenarios`` and the argument tuple of ``run_lanes`` on them (output arrays zeroed)."""
    sc = scenarios[0]
    a = LoopArrays.build(scenarios)
    B = len(scenarios)
    n_rows = (sc.n_steps + sc.log_every - 1) // sc.log_every
    return a, (a.z0.copy(), sc.control_period, sc.substeps, sc.n_steps, sc.log_every, a.plant, a.model, a.ctrl,
               a.ref, a.events, a.filt, np.zeros((B, n_rows, N_LOG)), np.zeros((B, N_METRICS)),
               np.zeros(B, dtype=np.int64))


def controller_us(sc, n_periods: int, repeats: int = 3) -> float:
    """Cost of the controller alone (``controller_update``) per control period [us], best of ``repeats``."""
    a = LoopArrays.build([sc])
    h = sc.control_period
    z0 = a.z0[0].copy()
    info = np.zeros(N_INFO)
    work = np.zeros((8, 4))
    args = (h, a.model[0], a.ctrl[0], a.ref[0], a.filt[0], info, work)
    _drive_controller(z0.copy(), *args, 2)
    return _best_of(lambda: _drive_controller(z0.copy(), *args, n_periods), repeats) / n_periods * 1e6


def plant_us_per_lane(sc, lanes: int, n_periods: int, repeats: int = 3) -> float:
    """Cost of the plant alone (``integrate_lanes``, ``sc.substeps`` RK4 steps) per lane per control period [us].

    ``lanes`` copies of the scenario's plant are integrated in lock-step with a small held current.
    """
    a = LoopArrays.build([sc])
    P = np.repeat(a.plant[:1], lanes, axis=0)
    c = np.zeros((N_LANE_CONST, lanes))
    lane_constants(P, c)
    ev = np.repeat(a.events[:1], lanes, axis=0)
    U = np.full(lanes, 0.05)  # a small held current keeps the open-loop plant bounded [mA]
    work = np.zeros((6, 4, lanes))
    h = sc.control_period
    none = plant_only_arrays(lanes)
    _drive_plant(np.zeros((4, lanes)), U, h, sc.substeps, c, ev, work, 2, *none)
    t = _best_of(lambda: _drive_plant(np.zeros((4, lanes)), U, h, sc.substeps, c, ev, work, n_periods, *none),
                 repeats)
    return t / n_periods / lanes * 1e6


def loop_us_per_lane(sc, lanes: int, repeats: int = 3) -> float:
    """The core's whole compiled loop (``run_lanes``: controller, plant, checks, metrics, logging) per lane per
    control period [us], for ``lanes`` copies of the scenario (n = 2, 4, 6 in turn) in one block on one thread."""
    scB = [sc.replace(n=(2, 4, 6)[i % 3]) for i in range(lanes)]
    _, args = run_lanes_args(scB)
    run_lanes(args[0].copy(), *args[1:])
    return _best_of(lambda: run_lanes(args[0].copy(), *args[1:]), repeats) / sc.n_steps / lanes * 1e6


def breakdown(sc, lanes: int = MAX_LANES, repeats: int = 3) -> dict:
    """Per-control-period cost of each piece [microseconds], single lane and per lane in a block.

    Args:
        sc: the scenario (its grid: control period, substeps, n_steps).
        lanes: block size for the batched numbers (a thread integrates this many lanes in lock-step).
        repeats: best-of repeats per piece (the minimum is the least disturbed by other load).
    """
    n = sc.n_steps
    h = sc.control_period
    out = {"periods": n, "substeps": sc.substeps, "lanes": lanes}

    a1, args1 = run_lanes_args([sc])
    run_lanes(args1[0].copy(), *args1[1:])  # compile / load
    t_setup = _best_of(lambda: LoopArrays.build([sc]), repeats)
    t_sim = _best_of(lambda: simulate(sc), repeats)
    t_loop = _best_of(lambda: run_lanes(args1[0].copy(), *args1[1:]), repeats)  # z copied, arrays prebuilt

    t_ctrl = controller_us(sc, n, repeats) * n / 1e6

    def plant_time(B):
        return plant_us_per_lane(sc, B, n, repeats) * B * n / 1e6

    t_plant1 = plant_time(1)
    t_plant8 = plant_time(8)
    t_plantB = plant_time(lanes)
    xw = np.zeros((5, 4))
    _drive_scalar_plant(np.zeros(4), 0.05, h, sc.substeps, a1.plant[0], a1.events[0], xw, 2)
    t_scalar = _best_of(lambda: _drive_scalar_plant(np.zeros(4), 0.05, h, sc.substeps, a1.plant[0], a1.events[0],
                                                    xw, n), repeats)
    t_loopB = loop_us_per_lane(sc, lanes, repeats) * n * lanes / 1e6
    us = 1e6 / n
    out.update({
        "simulate_us": t_sim * us,
        "setup_us": t_setup * us,
        "setup_ms": t_setup * 1e3,
        "loop_us": t_loop * us,
        "controller_us": t_ctrl * us,
        "plant_1lane_us": t_plant1 * us,
        "plant_block_us_per_lane": t_plantB * us / lanes,
        "loop_block_us_per_lane": t_loopB * us / lanes,
    })
    out["other_1lane_us"] = out["loop_us"] - out["controller_us"] - out["plant_1lane_us"]
    out["ns_per_substep_1lane_plant"] = out["plant_1lane_us"] * 1e3 / sc.substeps
    out["ns_per_substep_8lane_plant"] = t_plant8 * us / 8 * 1e3 / sc.substeps
    out["ns_per_substep_scalar_plant"] = t_scalar * us * 1e3 / sc.substeps
    out["ns_per_substep_block_plant"] = out["plant_block_us_per_lane"] * 1e3 / sc.substeps
    return out


def rhs_instruction_mix(lanes: int = MAX_LANES) -> dict:
    """Static instruction counts in the machine code of the lane right-hand side ``lane_rhs``.

    Compiled afresh (no cache) for the (4, lanes) layout the batch kernel uses; the
    vectorised loop body shows up as packed (``...pd``) instructions on zmm
    (512-bit, 8 doubles) or ymm (256-bit, 4 doubles) registers, and its scalar
    remainder loop as ``...sd``.
    """
    f = nb.njit(error_model="numpy")(lane_rhs.py_func)
    X = np.zeros((4, lanes))
    D = np.zeros((4, lanes))
    c = np.ones((N_LANE_CONST, lanes))
    f(X, np.zeros(lanes), np.zeros(lanes), c, D, lanes)
    asm = next(iter(f.inspect_asm().values()))
    res = {}
    for ins in ("vsqrtpd", "vsqrtsd", "vdivpd", "vdivsd"):
        res[ins] = len(re.findall(rf"^\s*{ins}\b", asm, re.M))
    packed = re.findall(r"^\s*v\w+pd\s+(.*)$", asm, re.M)
    res["packed_on_zmm"] = sum("zmm" in p for p in packed)
    res["packed_on_ymm"] = sum("ymm" in p and "zmm" not in p for p in packed)
    res["vector_width"] = 8 if res["packed_on_zmm"] else 4 if res["packed_on_ymm"] else 1
    return res


LIBM = ("log", "log1p", "exp", "cos", "sin", "hypot", "pow", "atan2")  # libm's functions, called one value at a time


def _mix(asm: str) -> dict:
    """Packed (ymm/zmm) and scalar double instructions and the libm functions called in one function's machine code."""
    packed = re.findall(r"^\s*v\w+pd\s+(.*)$", asm, re.M)
    calls = set(re.findall(r"movabsq\s+\$(\w+),", asm)) & set(LIBM)
    return {"packed_zmm": sum("zmm" in p for p in packed), "packed_ymm": sum("ymm" in p and "zmm" not in p
                                                                              for p in packed),
            "scalar_sd": len(re.findall(r"^\s*v\w+sd\s", asm, re.M)), "libm": sorted(calls)}


def control_period_mix(lanes: int = 16) -> dict:
    """Instruction mix of each stage of the env's control period, compiled afresh here (no cache) on a vector env's
    arrays of ``lanes`` lanes: the controller's lane stages (``sense_lanes``: noise variates, sensors, the model at
    the measured states), the rest of the controller per lane (``controller_law``), the loop around them
    (``lanes_period``: checks, metrics, copies), the plant right-hand side (``lane_rhs``) and the env's step
    (``advance``: grouping, statistics, reward, observation). Each entry: packed_zmm, packed_ymm, scalar_sd (static
    counts) and the libm functions the stage calls (scalar: numba has no vector libm here, and one would change the
    last bits)."""
    from ehss_gym.core.controller import controller_law, sense_lanes
    from ehss_gym.core.loop import lanes_period
    from ehss_gym.envs.kernels import advance
    from ehss_gym.envs.vector import EHSSTrackingVectorEnv

    v = EHSSTrackingVectorEnv(lanes)
    v.reset(seed=0)
    L = v._lanes
    k, h, substeps, events, filt = 1, L.cfg.control_period, L.cfg.substeps, L.events, L.filt
    c, X, U, work, lwork = L.c[0], L.X[0], L.U[0], L.work[0], L.lwork[0]
    fresh = {}
    for f in (sense_lanes, controller_law, lanes_period, lane_rhs, advance):
        opts = dict(f.targetoptions)
        opts.pop("cache", None)
        fresh[f.__name__] = nb.njit(**opts)(f.py_func)
    z, ctrl, info = L.z, L.ctrl, L.info_ok
    kv = np.full(L.B, k)  # every lane at sample k
    fresh["sense_lanes"](z, kv, ctrl, c, lwork[6])
    fresh["lane_rhs"](X, lwork[5, 0], U, c, lwork[0], X.shape[1])
    fresh["controller_law"](z[0].copy(), k, h, 0.0, 1.0, 0.0, ctrl[0], L.ref[0], filt[0], np.zeros(N_INFO),
                            work.copy())
    act = np.zeros(L.B, dtype=np.bool_)  # no lane active: compiled, nothing advanced
    fresh["lanes_period"](z, kv, h, substeps, L.plant, L.model, ctrl, L.ref, events, filt, L.u_res, act, info, L.acc,
                          c, X, U, np.zeros_like(z), work, lwork, act.copy(), L.peek)
    fresh["advance"](*L._args)
    v.close()
    return {name: _mix(next(iter(f.inspect_asm().values()))) for name, f in fresh.items()}
