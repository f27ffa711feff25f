"""Held actions (a policy whose action does not depend on what it observes): ``step_held`` runs many agent steps in
one compiled call and must leave every sub-env as that many ``step`` calls do, bit for bit; the rollout loop holds a
fixed policy's actions, runs several policies side by side, and skips the base law's runs when no return is wanted."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from ehss_gym.controllers import CLFPolicy, PIDPolicy
from ehss_gym.controllers.feedforward import ConstantResidualPolicy
from ehss_gym.core.layout import N_INFO
from ehss_gym.core.scenarios import heldout_scenarios
from ehss_gym.envs import EHSSTrackingEnv, EHSSTrackingVectorEnv, EnvConfig
from ehss_gym.envs import lanes as lanes_mod
from ehss_gym.envs.actions import ACTION_NAMES
from ehss_gym.envs.rollouts import HOLD_STEPS, SideBySide, rollout
from ehss_gym.evaluation import harness
from ehss_gym.evaluation.suites import EvalConfig, build_episodes

# the residual agents' rewards (class, physical) and memory, so that the held steps' rewards and observations see them
RECIPE = {"agent_period": 4, "memory_tau": 0.1, "unmodelled_effects": True, "dob_hz": 20.0,
          "reward_weights": {"track": 1.0, "effort": 0.1, "rate": 0.1, "class": 1.0, "physical": 1.0,
                             "saturation": 1.0}}
NEEDS = {"compensation": {"reference_delay": 1.0, "inverse_threshold": 0.375, "inverse_hysteresis": 2.25}}
INFO_KEYS = ("t", "e", "s", "V", "u_base", "u_residual", "u_applied", "saturated", "sat_fraction", "friction_torque",
             "clipped", "n_clipped", "diverged", "lost_track")


def _pair(kw: dict, n: int, mode: AutoresetMode, seed: int = 3):
    envs = [EHSSTrackingVectorEnv(n, autoreset_mode=mode, **kw) for _ in range(2)]
    obs = [env.reset(seed=seed)[0] for env in envs]
    assert obs[0].tobytes() == obs[1].tobytes()
    return envs


def _flat(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        out.update(_flat(v, f"{prefix}{k}.") if isinstance(v, dict) else {prefix + k: np.asarray(v)})
    return out


def _same_info(a: dict, b: dict) -> None:
    """Two step infos agree entry for entry (every key, the episode-end metrics included), byte for byte."""
    fa, fb = _flat(a), _flat(b)
    assert set(fa) == set(fb) and all(key in fa for key in INFO_KEYS)
    for key, v in fa.items():
        w = fb[key]
        same = repr(v.tolist()) == repr(w.tolist()) if v.dtype == object else v.tobytes() == w.tobytes()
        assert same and v.dtype == w.dtype, key


def _held_against_steps(kw: dict, actions: np.ndarray, mode: AutoresetMode, calls: int, most: int) -> list[int]:
    """``calls`` calls of step_held(actions, most) on one env against as many step calls on a twin as each took;
    returns the steps each call took."""
    held, steps = _pair(kw, len(actions), mode)
    n_env = len(actions)
    taken = []
    for _ in range(calls):
        if mode == AutoresetMode.DISABLED and held._ended.all():
            break
        record = np.full((most, n_env, N_INFO), np.nan)
        o1, r1, te1, tr1, i1, n = held.step_held(actions, most, record=record)
        assert 1 <= n <= most
        total = None
        for k in range(n):
            stepped = ~(steps._ended | steps._autoreset)
            o2, r2, te2, tr2, i2 = steps.step(actions)
            total = r2.copy() if total is None else total + r2
            want = steps._lanes.info_ok[:n_env][stepped]
            assert record[k][stepped].tobytes() == want.tobytes(), f"sample of step {k}"
            if k < n - 1:  # no sub-env ends before the held call's last step
                assert not (te2 | tr2).any()
        assert o1.tobytes() == o2.tobytes() and total.tobytes() == r1.tobytes()
        assert te1.tobytes() == te2.tobytes() and tr1.tobytes() == tr2.tobytes()
        _same_info(i1, i2)
        taken.append(n)
    L1, L2 = held._lanes, steps._lanes
    for name in ("z", "acc", "info_ok", "F", "obs", "elog"):
        assert getattr(L1, name).tobytes() == getattr(L2, name).tobytes(), name
    assert L1.IB.tobytes() == L2.IB.tobytes() and L1.BB.tobytes() == L2.BB.tobytes()
    assert held._steps.tobytes() == steps._steps.tobytes() and held._n_clipped.tobytes() == steps._n_clipped.tobytes()
    return taken


@pytest.mark.parametrize("action", ACTION_NAMES)
def test_held_steps_equal_steps_one_by_one_in_every_action_mode(action):
    """Each mode's action held over the steps: states, observations, summed rewards, infos, samples and ends equal
    one step at a time, byte for byte; a clipped action (counted once a step) included."""
    kw = {**RECIPE, "task": "position", "action": action, "episode_seconds": 0.02, **NEEDS.get(action, {})}
    env = EHSSTrackingVectorEnv(3, **kw)
    env.reset(seed=3)
    k = env.single_action_space.shape[0]
    actions = np.random.default_rng(5).uniform(-0.8, 0.8, (3, k)).astype(np.float32)
    actions[1, 0] = 1.5  # clipped, and counted every step
    taken = _held_against_steps(kw, actions, AutoresetMode.DISABLED, 40, 7)
    assert max(taken) == 7 and sum(taken) == env._lanes.T[0] and len(taken) > 2


@pytest.mark.parametrize("threads", [1, 2])
def test_held_steps_stop_at_each_end_and_after_each_autoreset(threads):
    """With autoreset (NEXT_STEP), a held call stops after the step in which a sub-env ends, and the call that resets
    it takes one step; a sub-env that loses track ends its episode there (terminate_on_lost_track): the held calls
    equal the steps one by one all along, in one compiled call or in parallel chunks."""
    kw = {"task": "velocity", "mode": "direct", "episode_seconds": 0.5, "terminate_on_lost_track": True,
          "threads": threads, "chunk": 2 if threads > 1 else None}
    actions = np.array([[0.0], [1.0], [-1.0]], dtype=np.float32)  # full current one way: the loop loses track
    taken = _held_against_steps(kw, actions, AutoresetMode.NEXT_STEP, 12, 4000)
    assert 1 in taken and max(taken) < 4000  # ends cut the calls short


def test_held_steps_reject_bad_arguments():
    env = EHSSTrackingVectorEnv(2, episode_seconds=0.01)
    env.reset(seed=0)
    a = np.zeros((2, 1), dtype=np.float32)
    for bad in (0, -1, 1.5, True, "3"):
        with pytest.raises(ValueError, match="max_steps must be an integer >= 1"):
            env.step_held(a, bad)
    for bad in (np.zeros((3, 2, N_INFO)), np.zeros((2, 2, N_INFO), dtype=np.float32), [[0.0]]):
        with pytest.raises(ValueError, match=r"record must be None or a float64 numpy array of shape \(2, 2, "):
            env.step_held(a, 2, record=bad)


def _no_fixed(policy):
    """The same policy without its fixed action: the rollout asks it every step."""
    return type("StepByStep", (), {"predict": lambda self, *a, **k: policy.predict(*a, **k)})()


@pytest.mark.parametrize("make", [lambda cfg, n: CLFPolicy(cfg),
                                  lambda cfg, n: ConstantResidualPolicy(cfg, currents=np.linspace(-2.0, 3.0, n))])
def test_a_fixed_policy_rolls_out_as_step_by_step(make):
    """A fixed policy's rollout (held steps) equals its step-by-step rollout: metrics and agent-rate traces bit for
    bit; the return within 1e-12 relative (a held stretch's rewards are summed before they are added)."""
    kw = {**RECIPE, "task": "velocity", "agent_period": 2}
    cfg = EnvConfig.from_kwargs(kw)
    scs = [sc.replace(t_end=0.05 + 0.01 * i) for i, sc in enumerate(heldout_scenarios(3, cfg.template()))]
    policy = make(cfg, len(scs))
    assert policy.fixed_action(len(scs)) is not None
    fast = rollout(policy, kw, scs, trace=True)
    slow = rollout(_no_fixed(policy), kw, scs, trace=True)
    for f, s in zip(fast, slow):
        assert repr(f.metrics) == repr(s.metrics)
        assert {k: v.tobytes() for k, v in f.trace.items()} == {k: v.tobytes() for k, v in s.trace.items()}
        assert math.isclose(f.ret, s.ret, rel_tol=1e-12) and f.ret != 0.0
    assert [r.metrics["agent_steps"] for r in fast] == [round(sc.t_end / 1e-4) for sc in scs]
    assert HOLD_STEPS >= 1000  # the held path ran (far fewer calls than steps)


def test_a_rollout_without_returns_runs_no_base_law_and_equals_one_with_them(monkeypatch):
    """``returns=False``: the env skips the base law's run of each episode (the reward's constants), the return is
    NaN, and the metrics and traces are those of the rollout with the rewards, bit for bit."""
    kw = {**RECIPE, "task": "position"}
    cfg = EnvConfig.from_kwargs(kw)
    scs = [sc.replace(t_end=0.04) for sc in heldout_scenarios(2, cfg.template())]
    pid = PIDPolicy(cfg, (2.0, 1.0, 0.0))
    with_returns = rollout(pid, kw, scs, trace=True)

    def refuse(*args, **kwargs):
        raise AssertionError("the base law ran")

    monkeypatch.setattr(lanes_mod, "base_law_runs", refuse)
    monkeypatch.setattr(lanes_mod, "base_law_run", refuse)
    with pytest.raises(AssertionError, match="the base law ran"):
        rollout(pid, kw, scs)
    without = rollout(pid, kw, scs, trace=True, returns=False)
    for a, b in zip(with_returns, without):
        assert repr(a.metrics) == repr(b.metrics) and math.isnan(b.ret) and math.isfinite(a.ret)
        assert {k: v.tobytes() for k, v in a.trace.items()} == {k: v.tobytes() for k, v in b.trace.items()}


def test_policies_side_by_side_act_as_each_alone():
    """SideBySide gives each policy its own lanes' observations and recurrent state (two PIDs with different gains):
    each part's episodes equal the same policy's rollout alone, bit for bit."""
    kw = {"task": "velocity", "mode": "direct"}
    cfg = EnvConfig.from_kwargs(kw)
    scs = [sc.replace(t_end=0.03 + 0.01 * i) for i, sc in enumerate(heldout_scenarios(3, cfg.template()))]
    a, b = PIDPolicy(cfg, (3.0, 20.0, 0.0)), PIDPolicy(cfg, (1.0, 5.0, 0.001))
    both = rollout(SideBySide([(a, 3), (b, 3)]), kw, scs + scs, trace=True)
    alone = rollout(a, kw, scs, trace=True) + rollout(b, kw, scs, trace=True)
    assert [repr(r.metrics) for r in both] != [repr(r.metrics) for r in both[3:] + both[:3]]  # the gains differ
    for x, y in zip(both, alone):
        assert repr(x.metrics) == repr(y.metrics)
        assert {k: v.tobytes() for k, v in x.trace.items()} == {k: v.tobytes() for k, v in y.trace.items()}
    assert SideBySide([(a, 3), (CLFPolicy(cfg), 3)]).fixed_action(6) is None
    fixed = SideBySide([(CLFPolicy(EnvConfig.from_kwargs({})), 2), (CLFPolicy(EnvConfig.from_kwargs({})), 1)])
    assert fixed.fixed_action(3).shape == (3, 1)


def test_the_runs_of_a_policy_share_a_job_and_give_what_each_gives_alone():
    """make_jobs puts the batches that differ only in their run into one job; the job's per-batch results equal each
    batch run as a job of its own (two PID 'runs' with different gains on the same held-out episodes)."""
    cfg = EvalConfig.quick()
    eps = [ep for ep in build_episodes(cfg) if ep.suite == "heldout" and ep.task == "velocity"][:3]
    eps = [type(ep)(**{**ep.__dict__, "physical": {**ep.physical, "t_end": 0.05}}) for ep in eps]
    kw = {"task": "velocity", "mode": "direct"}
    env_cfg = EnvConfig.from_kwargs(kw)
    batches = [harness.EpisodeBatch(r, "pid", r, "velocity", kw, eps) for r in range(2)]
    assert harness.make_jobs(batches) == [batches]
    assert len(harness.make_jobs(batches + [harness.EpisodeBatch(2, "pid", 0, "velocity", kw, eps[:2])])) == 2
    items = {("pid", 0, "velocity"): ("object", PIDPolicy(env_cfg, (3.0, 20.0, 0.0))),
             ("pid", 1, "velocity"): ("object", PIDPolicy(env_cfg, (1.0, 5.0, 0.001)))}
    together = harness._eval_job({"batches": batches, "items": ["a", "b"]}, 0, items)
    for batch, digest, res in zip(batches, ["c", "d"], together):
        alone = harness._eval_job({"batches": [batch], "items": [digest]}, 0, items)[0]
        assert repr(alone["metrics"]) == repr(res["metrics"])
    assert repr(together[0]["metrics"]) != repr(together[1]["metrics"])


def test_a_rollouts_trace_is_what_a_single_env_reports_step_by_step():
    """The rollout's trace (stacked per agent step over the lanes, each lane's rows up to its end) against the single
    env's info, step by step, for lanes that end at different steps: the same times, errors, applied currents and
    friction torques, bit for bit, and as many rows as the episode has agent steps."""
    kw = {"task": "position", "mode": "direct", "agent_period": 3}
    cfg = EnvConfig.from_kwargs(kw)
    scs = [sc.replace(t_end=0.006 + 0.003 * i) for i, sc in enumerate(heldout_scenarios(3, cfg.template()))]
    pid = PIDPolicy(cfg, (2.0, 1.0, 0.0))
    results = rollout(pid, kw, scs, trace=True)
    for sc, res in zip(scs, results):
        env = EHSSTrackingEnv(**kw)
        obs, _ = env.reset(options={"scenario": sc})
        state, start, rows = None, np.ones(1, dtype=bool), []
        done = False
        while not done:
            a, state = pid.predict(obs[None], state=state, episode_start=start, deterministic=True)
            start[:] = False
            obs, _, term, trunc, info = env.step(np.asarray(a, dtype=np.float32).reshape(-1))
            rows.append((info["t"], info["e"], info["u_applied"], info["friction_torque"]))
            done = term or trunc
        want = np.array(rows)
        assert len(res.trace["t"]) == len(rows) == res.metrics["agent_steps"]
        for j, key in enumerate(("t", "e", "u", "friction")):
            assert res.trace[key].tobytes() == want[:, j].tobytes(), key
    assert len({len(r.trace["t"]) for r in results}) == 3  # the lanes ended at different steps
