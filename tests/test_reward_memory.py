"""The class reward (reward weights ``class``, ``saturation``) against the ruler's figures on fixed episodes, and the
memory features (``memory_tau``): off by default, their filter against its definition, their anti-windup."""

import math

import numpy as np
import pytest

from ehss_gym.envs import EHSSTrackingEnv, EHSSTrackingVectorEnv
from ehss_gym.envs.kernels import CLASS_EPS, memory_update
from ehss_gym.evaluation.scoring import NUMERIC_FLOORS, episode_log_ratios

CLASS_ONLY = {"track": 0.0, "effort": 0.0, "rate": 0.0, "class": 1.0}


def _episode(task, seed, policy, rw, dob_hz=0.0, **kw):
    env = EHSSTrackingEnv(task=task, agent_period=20, reward_weights=rw, dob_hz=dob_hz, episode_seconds=2.0, **kw)
    env.reset(seed=seed)
    ret, k = 0.0, 0
    while True:
        obs, r, term, trunc, info = env.step(np.array([policy(k)], np.float32))
        ret, k = ret + r, k + 1
        if term or trunc:
            return ret, info["metrics"], k


def _sums(m: dict) -> dict:
    """The episode totals of the class reward's parts, from the ruler's metrics (the summary, not the kernel's sums)."""
    return {"trk_e2": m["trk_rmse"] ** 2 * m["steps_tracking"], "trk_abs": m["trk_iae"], "dst_abs": m["dst_iae"],
            "dst_max": m["dst_peak"], "tv": m["tv_u"], "u2": m["rms_u"] ** 2 * m["steps"]}


PART_WEIGHTS = {"trk_e2": ("tracking", 0.25), "trk_abs": ("tracking", 0.5), "dst_abs": ("disturbance", 0.5),
                "dst_max": ("disturbance", 0.5), "tv": ("effort", 0.5), "u2": ("effort", 0.25)}


def test_class_return_is_minus_the_episodes_log_figure():
    """Over an episode the class reward telescopes: the base law earns 0, and a policy earns minus w_class times the
    ruler's overall log figure of the episode with each part's totals offset by 1 % of the base law's (recomputed here
    from the ruler's metrics of both runs, which the kernel never reads)."""
    w = 3.0
    ret0, m0, K = _episode("position", 2, lambda k: 0.0, {**CLASS_ONLY, "class": w})
    assert K == 2000 and not m0["diverged"] and abs(ret0) < 1e-9
    ret1, m1, _ = _episode("position", 2, lambda k: 0.03 * math.sin(0.01 * k), {**CLASS_ONLY, "class": w})
    s0, s1 = _sums(m0), _sums(m1)
    n_cls = 3 if m0["steps_disturbance"] else 2
    want = -w * sum(wp / n_cls * math.log((s1[p] + CLASS_EPS * s0[p]) / (s0[p] * (1 + CLASS_EPS)))
                    for p, (_, wp) in PART_WEIGHTS.items())
    assert ret1 == pytest.approx(want, rel=1e-6)
    G = math.exp(np.mean(list(episode_log_ratios(m1, m0, False, "position", NUMERIC_FLOORS).values())))
    assert ret1 < 0.0 and G > 1.0


@pytest.mark.parametrize(("task", "seed"), [("position", 1), ("position", 2), ("position", 3), ("velocity", 1),
                                            ("velocity", 2), ("velocity", 3)])
def test_class_return_ranks_policies_as_the_ruler_does(task, seed):
    """Base law, base law + a harmful constant bias, + a chattering residual, and the disturbance observer, on
    training episodes with friction events: the class return orders them as the episode's overall figure G does
    (the default reward does not: docs/RL.md)."""
    policies = {"base": (lambda k: 0.0, 0.0), "bias": (lambda k: 0.05, 0.0),
                "chatter": (lambda k: 0.02 * (-1) ** k, 0.0), "dob": (lambda k: 0.0, 20.0)}
    runs = {n: _episode(task, seed, p, CLASS_ONLY, dob) for n, (p, dob) in policies.items()}
    base = runs["base"][1]
    assert base["steps_disturbance"] > 0
    # the class reward spreads the ruler with its numeric floors (its own offsets: 1 % of the base law's totals)
    G = {n: math.exp(np.mean(list(episode_log_ratios(m, base, False, task, NUMERIC_FLOORS).values())))
         for n, (_, m, _) in runs.items()}
    by_g = sorted(G, key=G.get)
    by_return = sorted(runs, key=lambda n: -runs[n][0])
    assert by_return == by_g, (G, {n: r[0] for n, r in runs.items()})
    assert G["dob"] < 1.0 < G["bias"] and G["chatter"] > 1.0


def test_chattering_residual_pays_through_the_effort_class():
    ret0, m0, _ = _episode("position", 3, lambda k: 0.0, CLASS_ONLY)
    ret1, m1, _ = _episode("position", 3, lambda k: 0.02 * (-1) ** k, CLASS_ONLY)
    assert m1["tv_u_rate"] > m0["tv_u_rate"] and ret1 < ret0


def test_defaults_are_unchanged_by_the_new_settings():
    """Off by default: the same observations and rewards as with the new settings given at their off values."""
    a, b = EHSSTrackingEnv(task="position"), EHSSTrackingEnv(task="position", memory_tau=None,
                                                              reward_weights={"class": 0.0, "saturation": 0.0})
    oa, _ = a.reset(seed=5)
    ob, _ = b.reset(seed=5)
    assert oa.shape == (17,) and np.array_equal(oa, ob)
    for k in range(50):
        act = np.array([0.1 * math.sin(k)], np.float32)
        sa, sb = a.step(act), b.step(act)
        assert np.array_equal(sa[0], sb[0]) and sa[1] == sb[1]


def test_memory_features_follow_their_filter_and_clip():
    """e_int follows x <- exp(-dt/tau) x + tau (1 - exp(-dt/tau)) e (e the step's last measured error), recomputed
    here from info["e"]; prev_action is the action of the step before last; the integral is clipped to 10
    error_scale tau."""
    tau, dt = 0.05, 20 * 5e-5
    env = EHSSTrackingEnv(task="position", agent_period=20, memory_tau=tau, episode_seconds=2.0)
    names = [n for n, *_ in env.observation_layout]
    assert names[-2:] == ["e_int", "prev_action"] and env.observation_space.shape == (19,)
    scale = env.observation_layout[-2][2]
    obs, _ = env.reset(seed=4)
    assert obs[-2] == 0.0 and obs[-1] == 0.0
    x, acts = 0.0, [0.3, -0.2, 0.1] + [0.0] * 40
    d = math.exp(-dt / tau)
    for k, a in enumerate(acts):
        obs, _, _, _, info = env.step(np.array([a], np.float32))
        x = d * x + tau * (1.0 - d) * info["e"]
        assert np.sign(obs[-2]) * math.expm1(abs(obs[-2])) * scale == pytest.approx(x, rel=1e-5, abs=1e-12)
        assert obs[-1] == pytest.approx(acts[k - 1] if k else 0.0)
    # a held error far beyond the scale: the integral stops at its clip (the loop's base law keeps e small, so the
    # filter is driven directly)
    wts = env.unwrapped._lanes.wts
    mem = np.zeros(2)
    for _ in range(2000):
        memory_update(mem, -1.0, 0.25, wts)
    assert mem[0] == -10 * env.config.error_scale * tau and mem[1] == 0.25


def test_memory_and_class_reward_in_the_vector_env_equal_the_single_env():
    kw = dict(task="velocity", memory_tau=0.1, reward_weights={"class": 1.0, "saturation": 1.0}, agent_period=20,
              episode_seconds=0.2)
    venv = EHSSTrackingVectorEnv(2, **kw)
    vo, _ = venv.reset(seed=[7, 8])
    envs = [EHSSTrackingEnv(**kw) for _ in range(2)]
    so = [e.reset(seed=s)[0] for e, s in zip(envs, (7, 8))]
    assert np.array_equal(vo, np.stack(so))
    for k in range(20):
        a = np.full((2, 1), 0.05 * (-1) ** k, np.float32)
        vo, vr, *_ = venv.step(a)
        for i, e in enumerate(envs):
            o, r, *_ = e.step(a[i])
            assert np.array_equal(vo[i], o) and vr[i] == r


@pytest.mark.parametrize(("kw", "match"), [({"memory_tau": 0.0}, "memory_tau"), ({"memory_tau": "x"}, "memory_tau"),
                                           ({"reward_weights": {"class": -1.0}}, "class")])
def test_bad_settings_name_the_setting(kw, match):
    with pytest.raises(ValueError, match=match):
        EHSSTrackingEnv(**kw)
