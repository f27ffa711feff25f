"""The loop state's live rows: the period's state copy at t_k, a diverged lane's restore from it and the env's
look-ahead copy only the rows a lane's settings can write (ehss_gym.core.loop.live_span), and the divergence check
of a lane without add-ons reads only those. That is only right if no code of the lane writes or reads any other row.
Here those rows are filled with a sentinel no run produces (1e300, finite, so the divergence check lets it be
wherever it reads it; any arithmetic on it overflows) before a run: a writer that touched one would overwrite the
sentinel, a reader would carry it into the results. The run must give the same results, bit for bit, as the run with
the rows at their reset value (0), and the sentinel must still be there at the end."""

from __future__ import annotations

import numpy as np
import pytest
from mixed_scenarios import cycled_scenarios

from ehss_gym.core.layout import (
    DIV_OMEGA,
    M_DIVERGED,
    MAX_DELAY,
    N_LOG,
    N_LOOP,
    N_METRICS,
    N_PLANT,
    Z_DELAY,
    Z_REF_RING,
    Z_SHIFT,
    Z_VINV,
)
from ehss_gym.core.loop import N_SPANS, copy_live, core_only, live_span, run_lanes
from ehss_gym.core.metrics import init_accumulator
from ehss_gym.core.settings import (
    C_DELAY,
    C_INV_THRESHOLD,
    C_OMEGA_MAX,
    C_REF_DELAY,
    C_SHIFT,
    C_SHIFT_ON,
    N_CTRL,
)
from ehss_gym.core.sim import LoopArrays
from ehss_gym.core.unmodelled import Unmodelled
from ehss_gym.envs.vector import EHSSTrackingVectorEnv

SENTINEL = 1e300


def dead_rows(ctrl_row: np.ndarray) -> np.ndarray:
    """Boolean mask of the loop state's rows outside every live span of a lane."""
    dead = np.ones(N_LOOP, dtype=bool)
    for j in range(N_SPANS):
        lo, hi = live_span(ctrl_row, j)
        dead[lo:hi] = False
    return dead


def _scenarios(task: str, count: int) -> list:
    """``count`` scenarios of ``task`` through every law, estimator and n, with every add-on of the loop state in
    turn: sensor delays of 0 to MAX_DELAY samples (with the valve's threshold and hysteresis and quantisation), the
    valve inverse, the reference delay (integer and fractional)."""
    return cycled_scenarios(task, count, 0.05, 2000, lambda i, sc: {
        "reference_delay": (0.0, 1.0, 2.5)[i % 3], "inverse_threshold": 1.0 if i % 4 == 1 else 0.0,
        "inverse_hysteresis": 5.0 if i % 4 == 2 else 0.0,
        "unmodelled": Unmodelled(threshold=1.0, hysteresis=2.0, delay=i % (MAX_DELAY + 1), encoder_counts=4096,
                                 velocity_step=0.01)})


def _run(a: LoopArrays, sc, z0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    B = z0.shape[0]
    log = np.zeros((B, (sc.n_steps + sc.log_every - 1) // sc.log_every, N_LOG))
    acc = np.zeros((B, N_METRICS))
    for b in range(B):
        init_accumulator(acc[b], sc.lost_track_bound)
    z = z0.copy()
    run_lanes(z, sc.control_period, sc.substeps, sc.n_steps, sc.log_every, a.plant, a.model, a.ctrl, a.ref, a.events,
              a.filt, log, acc, np.zeros(B, dtype=np.int64))
    return z, log, acc


def test_the_live_spans_follow_the_layout_and_the_settings():
    """The spans, written out from the layout: the core rows always, then each add-on's rows only when it is on."""
    ctrl = np.zeros(N_CTRL)
    assert (~dead_rows(ctrl)).sum() == Z_DELAY
    ctrl[C_DELAY] = 3  # three samples
    live = np.flatnonzero(~dead_rows(ctrl))
    assert live.tolist() == list(range(Z_DELAY)) + list(range(Z_DELAY, Z_DELAY + 3 * N_PLANT))
    ctrl[C_INV_THRESHOLD], ctrl[C_REF_DELAY], ctrl[C_SHIFT_ON] = 0.5, 0.25, 1.0
    live = set(np.flatnonzero(~dead_rows(ctrl)))
    assert {Z_VINV, Z_REF_RING, Z_SHIFT - 1, Z_SHIFT, N_LOOP - 1} <= live
    ctrl[C_DELAY] = MAX_DELAY
    assert not dead_rows(ctrl).any()


@pytest.mark.parametrize("first", [0, N_PLANT])
@pytest.mark.parametrize("addons", [(), ((C_DELAY, 2.0),), ((C_INV_THRESHOLD, 0.5),), ((C_REF_DELAY, 0.25),),
                                    ((C_SHIFT_ON, 1.0),), ((C_DELAY, MAX_DELAY), (C_SHIFT_ON, 1.0))])
def test_the_live_copy_copies_the_live_rows_from_first_and_no_other(addons, first):
    """copy_live (a fixed core copy for a lane without add-ons, the spans otherwise) against the spans: the rows
    i >= ``first`` of the live spans, each once, and nothing else."""
    ctrl = np.zeros(N_CTRL)
    for key, value in addons:
        ctrl[key] = value
    assert core_only(ctrl) == (not addons)
    src = np.arange(1.0, N_LOOP + 1.0)
    dst = np.zeros(N_LOOP)
    copy_live(dst, src, ctrl, first)
    copied = ~dead_rows(ctrl) & (np.arange(N_LOOP) >= first)
    assert np.array_equal(dst, np.where(copied, src, 0.0))


@pytest.mark.parametrize("task", ["velocity", "position"])
def test_no_code_of_a_lane_writes_or_reads_a_row_outside_its_live_spans(task):
    scenarios = _scenarios(task, 36)
    sc = scenarios[0]
    a = LoopArrays.build(scenarios)
    a.ctrl[1::2, C_SHIFT_ON] = 1.0  # the reference action's filter on every other lane, driven by a shift
    a.ctrl[1::2, C_SHIFT] = 1e-3
    a.ctrl[5, C_OMEGA_MAX] = 1e-9  # this lane leaves the velocity bound at once: the diverged lane's restore runs
    dead = np.array([dead_rows(row) for row in a.ctrl])
    assert dead.any(axis=1).sum() >= len(scenarios) - 4 and (~dead[:, Z_DELAY + 4 * N_PLANT:]).any()
    z0 = a.z0.copy()
    assert (z0[dead] == 0.0).all()  # the reset value
    z_ref, log_ref, acc_ref = _run(a, sc, z0)
    poisoned = z0.copy()
    poisoned[dead] = SENTINEL
    z, log, acc = _run(a, sc, poisoned)
    assert acc_ref[5, M_DIVERGED] == DIV_OMEGA
    assert log.tobytes() == log_ref.tobytes()
    assert acc.tobytes() == acc_ref.tobytes()
    assert z[~dead].tobytes() == z_ref[~dead].tobytes()
    assert (z[dead] == SENTINEL).all(), "a lane's code wrote a row outside its live spans"
    assert (z_ref[dead] == 0.0).all()


def test_the_env_never_writes_or_reads_a_row_outside_the_live_spans():
    """The vector env (look-ahead, pre-sensed periods, the reference action's filter, the sensors' delay line, the
    valve inverse and the reference delay): the sentinel in every lane's dead rows after the reset changes no
    observation, reward, end or info, and stays."""
    runs = []
    for poison in (False, True):
        env = EHSSTrackingVectorEnv(6, episode_seconds=0.5, action="reference", unmodelled_effects=True,
                                    reference_delay=1.0, inverse_threshold=0.5, task="position")
        obs, _ = env.reset(seed=11)
        L = env._lanes
        dead = np.array([dead_rows(row) for row in L.ctrl[:6]])
        assert dead.any()
        if poison:
            z = L.z
            z[:6][dead] = SENTINEL
        out = [obs.tobytes()]
        actions = np.random.default_rng(11).uniform(-1.0, 1.0, (30, 6) + env.single_action_space.shape)
        for act in actions:  # 30 steps of 5 periods: within the episodes
            obs, rew, term, trunc, info = env.step(act.astype(np.float32))
            out += [obs.tobytes(), rew.tobytes(), term.tobytes(), trunc.tobytes()]
            out += [(key, np.asarray(v).tobytes()) for key, v in sorted(info.items()) if key != "metrics"]
        zl = L.z[:6]
        out.append(zl[~dead].tobytes())
        if poison:
            assert (zl[dead] == SENTINEL).all()
        env.close()
        runs.append(out)
    assert runs[0] == runs[1]
