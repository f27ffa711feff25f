"""A block of lanes computes each lane as a block of one does: the controller's lane stages (sensors, the model at the
measured states) and the plant run as loops over the lanes of a block, so a lane's arithmetic must not depend on the
other lanes, on their laws and estimators, or on the block's size."""

from __future__ import annotations

import numpy as np
import pytest

from ehss_gym.core.layout import N_LOG, N_METRICS
from ehss_gym.core.loop import run_lanes
from ehss_gym.core.metrics import init_accumulator
from ehss_gym.core.registry import ESTIMATORS, LAWS, names
from ehss_gym.core.scenarios import sample_scenario
from ehss_gym.core.sim import LoopArrays
from ehss_gym.core.unmodelled import Unmodelled
from ehss_gym.envs import EnvConfig
from ehss_gym.envs.vector import EHSSTrackingVectorEnv

BLOCK = 256


def _mixed_scenarios(task: str, count: int, t_end: float) -> list:
    """``count`` randomised scenarios of ``task`` cycling through every law, estimator and n (noise on most; the
    unmodelled valve and sensors on every fifth)."""
    tmpl = EnvConfig.from_kwargs({"task": task}).template()
    laws, ests = names(LAWS), names(ESTIMATORS)
    out = []
    for i in range(count):
        sc = sample_scenario(1000 + i, tmpl)
        est = ests[(i // 3) % len(ests)]
        change = {"t_end": t_end, "law": laws[i % len(laws)], "estimator": est, "n": (2, 4, 6)[i % 3],
                  "dob_hz": 200.0 if i % 7 == 0 else sc.dob_hz}
        if est == "analog":  # the reference shaper drives a digital reference model only
            change["ref_accel"] = 0.0
        if i % 5 == 0:  # the unmodelled valve and sensors (their state is in the loop state)
            change["unmodelled"] = Unmodelled(threshold=1.0, hysteresis=2.0, delay=1 + i % 4, encoder_counts=4096,
                                              velocity_step=0.01)
        out.append(sc.replace(**change))
    return out


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
