"""A block of lanes computes each lane as a block of one does: the controller's lane stages (sensors, the model at the
measured states) and the plant run as loops over the lanes of a block, so a lane's arithmetic must not depend on the
other lanes, on their laws and estimators, or on the block's size."""

from __future__ import annotations

import math

import numpy as np
import pytest
from mixed_scenarios import cycled_scenarios

from ehss_gym.core.controller import CW_TODO, controller_sense, law_lanes, model_constants, sense_lanes
from ehss_gym.core.layout import (
    DIV_NONE,
    DIV_NONFINITE,
    N_INFO,
    N_LOG,
    N_LOOP,
    N_METRICS,
    N_PARAM,
    N_PLANT,
    Z_DELAY,
    Z_REF_RING,
    Z_SHIFT,
    Z_VINV,
)
from ehss_gym.core.loop import check_state, run_lanes
from ehss_gym.core.metrics import init_accumulator
from ehss_gym.core.params import P_PS
from ehss_gym.core.physics import N_LANE_CONST, lane_constants
from ehss_gym.core.settings import (
    C_DELAY,
    C_INV_HYSTERESIS,
    C_OMEGA_MAX,
    C_P_BOUND,
    C_REF_DELAY,
    C_SHIFT_ON,
    N_CTRL,
)
from ehss_gym.core.sim import LoopArrays
from ehss_gym.core.unmodelled import Unmodelled
from ehss_gym.envs.buffers import HOT_BLOCKS, N_H
from ehss_gym.envs.kernels import hot_blocks
from ehss_gym.envs.lanes import hot_block
from ehss_gym.envs.vector import EHSSTrackingVectorEnv

BLOCK = 256


def _mixed_scenarios(task: str, count: int, t_end: float) -> list:
    """``count`` randomised scenarios of ``task`` cycling through every law, estimator and n (noise on most; the
    unmodelled valve and sensors on every fifth)."""

    def extra(i, sc):
        out = {"dob_hz": 200.0 if i % 7 == 0 else sc.dob_hz}
        if i % 5 == 0:  # the unmodelled valve and sensors (their state is in the loop state)
            out["unmodelled"] = Unmodelled(threshold=1.0, hysteresis=2.0, delay=1 + i % 4, encoder_counts=4096,
                                           velocity_step=0.01)
        return out

    return cycled_scenarios(task, count, t_end, 1000, extra)


def _run_block(scenarios: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """run_lanes on ``scenarios`` as one block: the logs, the accumulators and the log row counts."""
    sc = scenarios[0]
    a = LoopArrays.build(scenarios)
    B = len(scenarios)
    log = np.zeros((B, (sc.n_steps + sc.log_every - 1) // sc.log_every, N_LOG))
    acc = np.zeros((B, N_METRICS))
    n_log = np.zeros(B, dtype=np.int64)
    for j, s in enumerate(scenarios):
        init_accumulator(acc[j], s.lost_track_bound)
    run_lanes(a.z0.copy(), sc.control_period, sc.substeps, sc.n_steps, sc.log_every, a.plant, a.model, a.ctrl, a.ref,
              a.events, a.filt, log, acc, n_log)
    return log, acc, n_log


@pytest.mark.parametrize("task", ["velocity", "position"])
def test_a_block_of_lanes_equals_blocks_of_one_bitwise(task):
    scenarios = _mixed_scenarios(task, BLOCK, 0.03)
    assert len({s.grid() for s in scenarios}) == 1
    log, acc, n_log = _run_block(scenarios)
    assert (n_log > 0).all()
    for j, sc in enumerate(scenarios):
        log1, acc1, n1 = _run_block([sc])
        assert n1[0] == n_log[j]
        assert log1[0].tobytes() == log[j].tobytes(), f"lane {j} ({sc.law}, {sc.estimator}, n = {sc.n})"
        assert acc1[0].tobytes() == acc[j].tobytes(), f"lane {j} ({sc.law}, {sc.estimator}, n = {sc.n})"


@pytest.mark.parametrize("k", [0, 1, 57])
def test_the_law_over_the_lanes_equals_the_one_lane_controller_bitwise(k):
    """The law over the lanes (ehss_gym.core.controller.law_lanes after sense_lanes) is compiled once per relative
    degree, with the degree a constant; the one-lane controller (controller_sense) reads it at run time and runs no
    lane stages. On a block of both tasks, every law, estimator and n, the disturbance observer, the unmodelled
    effects and noise, both give every lane the same info and loop state, bit for bit: at the first sample (the
    bumpless start), the second, and mid-run."""
    scenarios = [sc for pair in zip(_mixed_scenarios("velocity", 30, 0.02), _mixed_scenarios("position", 30, 0.02))
                 for sc in pair]
    a = LoopArrays.build(scenarios)
    B, h = len(scenarios), scenarios[0].control_period
    z = a.z0.copy()
    if k > 0:  # the loop run to sample k first, so the filters, observers and delay lines hold a history
        log = np.zeros((B, k + 1, N_LOG))
        acc = np.zeros((B, N_METRICS))
        run_lanes(z, h, scenarios[0].substeps, k, k + 1, a.plant, a.model, a.ctrl, a.ref, a.events, a.filt, log,
                  acc, np.zeros(B, dtype=np.int64))
    c = np.zeros((N_LANE_CONST, B))
    lane_constants(a.plant, c)
    model_constants(a.model, a.ctrl, c)
    cw = np.zeros((N_LOOP, B))
    cw[CW_TODO] = 1.0
    kv = np.full(B, k, dtype=np.int64)
    zl, info_l, work = z.copy(), np.zeros((B, N_INFO)), np.zeros((8, 4))
    sense_lanes(zl, kv, a.ctrl, c, cw)
    law_lanes(zl, kv, h, a.ctrl, a.ref, a.filt, info_l, work, cw)
    for b, sc in enumerate(scenarios):
        z1, info1 = z[b].copy(), np.zeros(N_INFO)
        controller_sense(z1, k, h, a.model[b], a.ctrl[b], a.ref[b], a.filt[b], info1, np.zeros((8, 4)))
        what = f"lane {b} ({sc.task}, {sc.law}, {sc.estimator}, n = {sc.n})"
        assert info1.tobytes() == info_l[b].tobytes(), what
        assert z1.tobytes() == zl[b].tobytes(), what


def test_the_vector_env_in_parallel_chunks_equals_one_call_bitwise():
    """The vector env's lanes in parallel chunks (threads > 1, the last chunk padded) step as in one call: each chunk
    reads and writes its own lanes' rows of the shared hot blocks (ehss_gym.envs.buffers), so observations, rewards,
    ends and the lanes' buffers agree bit for bit."""
    runs = []
    for threads, chunk in ((1, None), (2, 2)):
        env = EHSSTrackingVectorEnv(5, threads=threads, chunk=chunk, episode_seconds=0.05)
        obs, _ = env.reset(seed=4)
        out = [obs.tobytes()]
        actions = np.random.default_rng(4).uniform(-1.0, 1.0, (40, 5) + env.single_action_space.shape)
        for a in actions:  # 40 steps of 5 periods: past the 0.05 s episodes' ends, so autoreset runs too
            obs, rew, term, trunc, _ = env.step(a.astype(np.float32))
            out += [obs.tobytes(), rew.tobytes(), term.tobytes(), trunc.tobytes()]
        L = env._lanes
        out += [b[:5].tobytes() for b in (L.z, L.acc, L.info_ok, L.F)]
        env.close()
        runs.append(out)
    assert runs[0] == runs[1]


def test_the_kernels_hot_blocks_are_the_buffers_table_in_order():
    """The compiled step's views of the hot blocks (kernels.hot_blocks, written out for numba) are the blocks the
    buffer's table lists (buffers.HOT_BLOCKS, which the lanes' Python views and the reset use), in the same order."""
    B = 3
    H = np.arange(B * N_H, dtype=np.float64)
    views = hot_blocks(H, B, 0, B)
    assert len(views) == len(HOT_BLOCKS)
    for v, (off, width) in zip(views, HOT_BLOCKS):
        assert np.array_equal(v, hot_block(H, B, off, width))
    # a chunk's rows: lanes 1..2 of the same blocks
    for v, (off, width) in zip(hot_blocks(H, B, 1, 2), HOT_BLOCKS):
        assert np.array_equal(v, hot_block(H, B, off, width)[1:3])


# Each add-on of the loop state, its rows (layout) and a setting that turns it on: written here from the layout, not
# read from loop.live_span, which the check uses.
ADDON_ROWS = {
    "sensor delay of 2 samples": (C_DELAY, 2.0, range(Z_DELAY, Z_DELAY + 2 * N_PLANT)),
    "valve inverse": (C_INV_HYSTERESIS, 0.1, range(Z_VINV, Z_VINV + 1)),
    "reference delay": (C_REF_DELAY, 1.5, range(Z_REF_RING, Z_SHIFT)),
    "reference action's filter": (C_SHIFT_ON, 1.0, range(Z_SHIFT, N_LOOP)),
}


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("addon", [None, *ADDON_ROWS])
def test_the_divergence_check_names_any_non_finite_entry_of_a_live_row(bad, addon):
    """check_state (written without an exit per entry) against math.isfinite: a NaN or infinite entry in any live row
    of the loop state (the core rows, and the rows of each add-on that is on) is DIV_NONFINITE, wherever it is; a
    finite state within the bounds is DIV_NONE, one with a huge finite entry too. With every add-on off, the add-ons'
    rows are not read (nothing writes them: tests/test_live_rows.py)."""
    ctrl, plant = np.zeros(N_CTRL), np.zeros(N_PARAM)
    ctrl[C_OMEGA_MAX], ctrl[C_P_BOUND], plant[P_PS] = 1e3, 1.0, 1e7
    live = list(range(Z_DELAY))
    if addon is not None:
        key, value, rows = ADDON_ROWS[addon]
        ctrl[key] = value
        live += list(rows)
    for where in live:
        z = np.full(N_LOOP, 0.0)
        z[[r for r in live if r >= N_PLANT]] = 1e300  # finite however large: x - x is 0 (the plant's within bounds)
        assert not math.isfinite(bad) and check_state(z, ctrl, plant) == DIV_NONE
        z[where] = bad
        assert check_state(z, ctrl, plant) == DIV_NONFINITE, where
    if addon is None:
        for where in range(Z_DELAY, N_LOOP):
            z = np.zeros(N_LOOP)
            z[where] = bad
            assert check_state(z, ctrl, plant) == DIV_NONE, where
