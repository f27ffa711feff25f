"""The physical reward (reward weight ``physical``): its formula recomputed from a full-rate log on a path the kernel
does not share, the ruler's order of fixed policies on the unmodelled suite, the vector env, and off by default."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from ehss_gym.core.layout import L_T, L_UAPP, L_X, L_YD, QUIET_GUARD, QUIET_STARTUP
from ehss_gym.core.resolution import CURRENT_FLOOR, ERROR_RESOLUTION, TV_FLOOR
from ehss_gym.core.scenarios import sample_scenario
from ehss_gym.core.sim import simulate
from ehss_gym.envs import EHSSTrackingEnv, EHSSTrackingVectorEnv, EnvConfig
from ehss_gym.evaluation.scoring import episode_log_ratios
from ehss_gym.evaluation.suites import EvalConfig, build_episodes

PHYSICAL_ONLY = {"track": 0.0, "effort": 0.0, "rate": 0.0, "physical": 1.0}
AP = 20  # the agent period of these tests [control periods]


def _log(sc):
    """(t [s], e_t [U], u [mA]) at every control sample of a law-only run (``simulate`` with a full-rate log)."""
    tr = simulate(sc.replace(log_interval=sc.control_period))
    y = tr.log[:, L_X + (0 if sc.task == "position" else 1)]
    return tr.log[:, L_T], y - tr.log[:, L_YD], tr.log[:, L_UAPP]


def _windows(t, friction):
    """Per sample: 0 start-up, 1 disturbance, 2 tracking (the ruler's windows, from their definition)."""
    win = np.full(len(t), 2)
    for _, t0, t1 in friction:
        win[(t >= t0) & (t < t1 + QUIET_GUARD)] = 1
    win[t < QUIET_STARTUP] = 0
    return win


def _rewards_from_log(sc, base_sc):
    """The physical reward of every agent step, from the full-rate logs of the run and of the base law's run."""
    e_f, h = ERROR_RESOLUTION[sc.task], sc.control_period
    t, e, u = _log(sc)
    _, eb, ub = _log(base_sc)
    win = _windows(t, sc.friction)
    trk, dst = win == 2, win == 1
    tvb = np.abs(np.diff(ub)).sum() / (len(ub) * h)
    scale = {"ms": e_f**2 + np.mean(eb[trk] ** 2), "ma": e_f + np.mean(np.abs(eb[trk])),
             "pk": e_f + np.abs(eb[dst]).max(), "dma": e_f + np.mean(np.abs(eb[dst])),
             "tv": TV_FLOOR + tvb, "u2": CURRENT_FLOOR**2 + np.mean(ub**2)}
    K, C, N = len(t) // AP, 1 + trk.any() + dst.any(), len(t)
    du = np.abs(np.diff(u, prepend=u[0]))  # the first sample has no TV
    out = []
    for j in range(K):
        s = slice(j * AP, (j + 1) * AP)
        ej, wj = e[s], win[s]
        r = 0.0
        if (wj == 2).any():
            x = ej[wj == 2]
            r += (wj == 2).sum() / trk.sum() * (0.25 * math.log1p(np.mean(x**2) / scale["ms"])
                                                 + 0.5 * math.log1p(np.mean(np.abs(x)) / scale["ma"]))
        if (wj == 1).any():
            x = ej[wj == 1]
            r += (wj == 1).sum() / dst.sum() * 0.5 * (math.log1p(np.abs(ej).max() / scale["pk"])
                                                       + math.log1p(np.mean(np.abs(x)) / scale["dma"]))
        r += AP / N * (0.5 * math.log1p(du[s].sum() / (AP * h) / scale["tv"])
                       + 0.25 * math.log1p(np.mean(u[s] ** 2) / scale["u2"]))
        out.append(-K / C * r)
    return np.array(out)


@pytest.mark.parametrize(("task", "seed", "dob_hz", "noisy"),
                         [("velocity", 7, 0.0, True), ("position", 1, 20.0, False)])
def test_every_step_reward_is_its_formula_recomputed_from_a_full_rate_log(task, seed, dob_hz, noisy):
    """A training episode with friction (and noise in the first case), the law (with the disturbance observer in the
    second case, whose base law is the law without it) at agent period 20: each step's reward against the formula of
    the env's docstring evaluated on full-rate logs of the run and of the base law's run (the windows from their
    definition, e_t = y - y_d, the TV from the applied current), not the kernel's accumulator differences."""
    tmpl = EnvConfig.from_kwargs({"task": task, "dob_hz": dob_hz}).template()
    sc = sample_scenario(seed, tmpl, 1.0)
    assert sc.friction and any(v > 0 for v in sc.noise_std) == noisy
    env = EHSSTrackingEnv(task=task, agent_period=AP, reward_weights=PHYSICAL_ONLY, dob_hz=dob_hz)
    env.reset(options={"scenario": sc})
    got = []
    while True:
        _, r, term, trunc, _ = env.step(np.zeros(1, np.float32))
        got.append(r)
        if term or trunc:
            break
    want = _rewards_from_log(sc, sc.replace(dob_hz=0.0))
    assert len(got) == len(want) == 1.0 / (AP * sc.control_period)
    # the kernel takes a step's sums as differences of the episode's running sums: exact to ~1e-12 of the episode's
    # totals, so a quiet step's tiny reward carries an absolute error of that order (a wrong window, weight or scale
    # misses by 1e-3 or more)
    assert np.allclose(got, want, rtol=1e-9, atol=1e-9 * np.abs(want).max())


def _episode_return(task, physical, policy, **kw):
    env = EHSSTrackingEnv(task=task, agent_period=AP, reward_weights=PHYSICAL_ONLY, **kw)
    env.reset(options={"scenario": env.unwrapped.scenario_template.replace(**physical)})
    ret, k = 0.0, 0
    while True:
        _, r, term, trunc, info = env.step(np.array([policy(k)], np.float32))
        ret, k = ret + r, k + 1
        if term or trunc:
            return ret, info["metrics"]


MARGIN = 0.02  # [-] pairs whose ruler figures differ by more than 2 % must be ordered alike


@pytest.mark.parametrize("task", ["velocity", pytest.param("position", marks=pytest.mark.xfail(strict=True, reason=(
    "open: at the retuned position law one pair of one episode is ordered against the ruler (unmodelled-2: the "
    "ruler's log figures chatter 0.114, observer 0.090; returns -1036 and -1057). The disturbance peak: the ruler "
    "takes the episode's largest |e_t| in the window (the observer's 22 % below chatter's, log ratio -0.25), the "
    "reward each of the window's 465 steps' own (their mean 0.277 against 0.302 of the scale), so the return pays "
    "the observer 6.8 for it where the ruler's rate (K/C x 1/2 = 333 a unit of summed log ratio) pays 42; the "
    "effort class, priced near that rate (the observer's TV twice the base law's: -79 against -71), outweighs "
    "the rest")))])
def test_the_return_orders_fixed_policies_as_the_ruler_does_on_the_unmodelled_suite(task):
    """The unmodelled suite's first four episodes; the base law, a harmful constant bias (0.5 mA), a chattering
    residual (+-0.2 mA, alternating each agent step), the disturbance observer (20 Hz) and the delay compensation
    knowing the episode's delay (``reference_delay``): every pair of policies whose overall figures (the ruler's,
    physical floors) differ by more than MARGIN is ordered alike by the episode return. (Pairs within it are as good
    as tied: the ruler's CIs are wider.)"""
    eps = build_episodes(EvalConfig(suites=("unmodelled",), tasks=(task,), heldout_episodes=4))
    checked = 0
    for ep in eps:
        ph, um = ep.physical, ep.physical["unmodelled"]
        pols = {"base": (lambda k: 0.0, {}), "bias": (lambda k: 0.05, {}),
                "chatter": (lambda k: 0.02 * (-1) ** k, {}), "dob": (lambda k: 0.0, {"dob_hz": 20.0}),
                "delay": (lambda k: 0.0, {"reference_delay": float(um.delay)})}
        runs = {n: _episode_return(task, ph, f, **kw) for n, (f, kw) in pols.items()}
        noisy = any(v > 0.0 for v in ph["noise_std"])
        log_g = {n: float(np.mean(list(episode_log_ratios(m, runs["base"][1], noisy, task).values())))
                 for n, (_, m) in runs.items()}
        for a, b in itertools.combinations(runs, 2):
            if abs(log_g[a] - log_g[b]) > math.log1p(MARGIN):
                checked += 1
                assert (log_g[a] < log_g[b]) == (runs[a][0] > runs[b][0]), (ep.episode_id, a, b, log_g, runs)
    assert checked >= 25  # most of the 40 pairs are apart by more than the margin


def test_the_vector_env_pays_what_the_single_env_pays():
    kw = dict(task="position", reward_weights={"physical": 1.0}, agent_period=AP, episode_seconds=0.3,
              unmodelled_effects=True)
    venv = EHSSTrackingVectorEnv(2, **kw)
    venv.reset(seed=[4, 9])
    envs = [EHSSTrackingEnv(**kw) for _ in range(2)]
    for e, s in zip(envs, (4, 9)):
        e.reset(seed=s)
    for k in range(15):
        a = np.full((2, 1), 0.03 * (-1) ** k, np.float32)
        _, vr, *_ = venv.step(a)
        for i, e in enumerate(envs):
            assert e.step(a[i])[1] == vr[i]


def test_off_by_default_and_a_bad_weight_names_itself():
    a, b = EHSSTrackingEnv(task="velocity"), EHSSTrackingEnv(task="velocity", reward_weights={"physical": 0.0})
    assert a.config.reward_weights["physical"] == 0.0
    a.reset(seed=1)
    b.reset(seed=1)
    for k in range(30):
        act = np.array([0.1 * math.cos(k)], np.float32)
        sa, sb = a.step(act), b.step(act)
        assert np.array_equal(sa[0], sb[0]) and sa[1] == sb[1]
    with pytest.raises(ValueError, match="physical"):
        EHSSTrackingEnv(reward_weights={"physical": -1.0})
