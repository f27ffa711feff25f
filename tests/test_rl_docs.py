"""Issue 16 feature 12: docs/RL.md's numbers are the env's, its example runs, and info["metrics"] carries the
nominal settled RMSE and the control TV."""

import math
import os
import re
import subprocess
import sys

import numpy as np
import pytest

from ehss_gym import simulate
from ehss_gym.agents.specs import AGENTS
from ehss_gym.core.scenarios import heldout_scenarios
from ehss_gym.envs import DEFAULTS, EHSSTrackingEnv
from ehss_gym.envs.config import EnvConfig

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOC = open(os.path.join(ROOT, "docs", "RL.md"), encoding="utf-8").read()


def test_the_time_scales_are_the_envs():
    cfg = EnvConfig.from_kwargs({})
    dt = cfg.agent_dt
    assert f"{DEFAULTS.agent_period} control periods = {dt * 1e3:g} ms" in DOC
    assert f"acts at {1 / dt / 1e3:g} kHz" in DOC
    assert f"{round(2.0 / dt):,} agent steps" in DOC and f"{round(20.0 / dt):,} agent steps" in DOC
    horizon = 1 / (1 - 0.99)
    half = math.log(0.5) / math.log(0.99)
    assert f"{horizon:.0f} steps = {horizon * dt * 1e3:.0f} ms" in DOC
    assert f"halves after {half:.0f} steps = {half * dt * 1e3:.0f} ms" in DOC
    spec = AGENTS["residual-ppo"]
    env_kw = spec.env_kwargs
    agent_dt = EnvConfig.from_kwargs(env_kw).agent_dt  # the recipe's agent period at the env's control period
    assert f"act every {agent_dt * 1e3:g} ms" in DOC and f"{round(2.0 / agent_dt):,} steps an episode" in DOC
    steps = 1 / (1 - spec.gamma)
    assert f"gamma {spec.gamma:g} ({steps:.0f} steps = {steps * agent_dt * 1e3:.0f} ms)" in DOC


def test_the_saturation_claim_about_the_tracking_term():
    term = lambda e: 1 / (1 + e * e / 0.01**2)  # noqa: E731  (w_track = 1, error_scale 0.01)
    assert f"raises the tracking term by {100 * (term(5e-4) / term(1e-3) - 1):.2f} %" in DOC


def test_the_evaluate_policy_example_runs(tmp_path):
    code = re.search(r"<!-- rl-eval-example -->\s*```python\n(.*?)```", DOC, re.S).group(1)
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("return")]
    assert len(lines) == 2 and all("lost track False" in ln for ln in lines)


@pytest.mark.parametrize("index", [0, 3])
def test_info_metrics_carry_the_settled_nominal_rmse_and_tv(index):
    """Against the same episode simulated with a full-rate log: RMSE over t >= 0.2 s with no friction torque
    and TV per second, computed in numpy."""
    env = EHSSTrackingEnv()
    sc = heldout_scenarios(8, env.unwrapped.scenario_template)[index]
    env.reset(options={"scenario": sc})
    done = False
    while not done:
        _, _, term, trunc, info = env.step(np.zeros(1, dtype=np.float32))
        done = term or trunc
    m = info["metrics"]
    traj = simulate(sc.replace(log_interval=sc.control_period))
    active = np.zeros_like(traj.t, dtype=bool)
    for a, t0, t1 in sc.friction:
        active |= (a != 0.0) & (traj.t >= t0) & (traj.t < t1)
    sel = (traj.t >= 0.2 - 1e-12) & ~active
    assert sel.sum() > 1000 and active.any() == bool(sc.friction)
    assert m["rmse_nominal_settled"] == pytest.approx(np.sqrt(np.mean(traj.e[sel] ** 2)), rel=1e-9)
    tv = np.sum(np.abs(np.diff(traj.u_applied))) / sc.t_end
    assert m["tv_u_rate"] == pytest.approx(tv, rel=1e-9)


def test_the_zoo_extra_has_what_rl_zoo3_enjoy_imports():
    """rl_zoo3.enjoy -> rl_zoo3.load_from_hub imports requests, which rl-zoo3 does not declare."""
    text = open(os.path.join(ROOT, "pyproject.toml"), encoding="utf-8").read()  # (tomllib needs Python 3.11)
    zoo = re.search(r"^zoo = \[(.*?)\]", text, re.M).group(1)
    assert '"rl-zoo3"' in zoo and '"requests"' in zoo


def test_sb3_refusing_the_native_vector_env_names_the_adapter_that_it_takes():
    """Before: SB3 refused gym.make_vec(..., vectorization_mode="vector_entry_point") with 'not a Gymnasium
    environment' and no hint; its message prints the env's type, which names NativeVecEnv now."""
    import gymnasium as gym
    from stable_baselines3 import PPO

    venv = gym.make_vec("ehss_gym:EHSSTracking-v0", num_envs=2, vectorization_mode="vector_entry_point")
    with pytest.raises(ValueError, match=r"EHSSTrackingVectorEnv.*ehss_gym\.train\.vec_env\.NativeVecEnv"):
        PPO("MlpPolicy", venv, device="cpu")
    assert "NativeVecEnv" in DOC and "vector_entry_point" in DOC


def test_the_native_vector_env_training_example_runs(tmp_path):
    code = re.search(r"<!-- rl-vec-example -->\s*```python\n(.*?)```", DOC, re.S).group(1)
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "trained 512 steps on 8 envs" in r.stdout
