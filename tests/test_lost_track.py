"""Issue 16 bug 5: a lost-track oscillation (a saturated swing within the state bounds) is flagged, in the core
metrics, the env's info and the harness's rate, and can end an episode; normal tracking is not flagged."""

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from ehss_gym import Scenario, simulate, sine, step
from ehss_gym.core.scenarios import heldout_scenarios
from ehss_gym.envs import EHSSTrackingEnv, EHSSTrackingVectorEnv
from ehss_gym.envs.config import LEGACY_LOOP, EnvConfig
from ehss_gym.evaluation import EvalConfig, evaluate, object_spec


class BangBang:
    """A direct-mode 'policy' that swings the full current every ``half`` agent steps: a saturated oscillation
    (RMSE ~35 rad/s on held-out episode 9, the issue's case, within omega_max = 1000 rad/s)."""

    def __init__(self, half: int = 800):
        self.half = half

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        k = np.zeros(len(obs), dtype=np.int64) if state is None else state
        a = np.where((k // self.half) % 2 == 0, 1.0, -1.0).astype(np.float32).reshape(-1, 1)
        return a, k + 1


def _episode9(env):
    return heldout_scenarios(16, env.unwrapped.scenario_template)[9]


def _run(env, sc, policy):
    obs, _ = env.reset(options={"scenario": sc})
    state, infos, done = None, [], False
    while not done:
        a, state = policy.predict(obs[None], state)
        obs, _, term, trunc, info = env.step(a[0])
        infos.append(info)
        done = term or trunc
    return infos


def test_saturated_oscillation_is_flagged_not_diverged():
    env = EHSSTrackingEnv(mode="direct")
    infos = _run(env, _episode9(env), BangBang())
    m = infos[-1]["metrics"]
    assert not m["diverged"] and not infos[-1]["diverged"]
    assert m["rmse"] > 10.0  # the case: RMSE ~35 rad/s, never flagged before
    assert m["lost_track"] and infos[-1]["lost_track"]
    assert 0.2 <= m["t_lost_track"] < 0.3
    first = next(i for i, info in enumerate(infos) if info["lost_track"])
    assert all(info["lost_track"] for info in infos[first:])  # sticky once set
    assert not any(info["lost_track"] for info in infos[:first])


def test_the_base_law_tracking_the_same_episode_is_not_flagged():
    env = EHSSTrackingEnv()
    infos = _run(env, _episode9(env), type("Zero", (), {"predict": lambda s, o, st=None: (np.zeros((1, 1)), None)})())
    assert not infos[-1]["metrics"]["lost_track"] and infos[-1]["metrics"]["t_lost_track"] is None
    assert not any(info["lost_track"] for info in infos)


def test_no_false_alarm_on_the_velocity_heldout_suite():
    """The default law tracks every held-out velocity episode (windowed RMS error below 7 % of the amplitude)."""
    tmpl = EnvConfig.from_kwargs({}).template()
    trajs = [simulate(sc) for sc in heldout_scenarios(12, tmpl)]
    assert not any(t.metrics()["lost_track"] for t in trajs)


def _windowed_rms_first_crossing(traj):
    """Independent reference: the 0.1 s exponential moving mean of e^2 from 0.2 s on (scipy's lfilter over the
    full-rate log) and the first sample where it exceeds the bound squared."""
    sc = traj.scenario
    h = sc.control_period
    sel = traj.t >= 0.2 - 1e-12
    a = min(1.0, h / 0.1)
    ema = lfilter([a], [1.0, -(1.0 - a)], traj.e[sel] ** 2)
    spec = sc.reference.spec  # amplitude: |A| (slot 4), or the sum of the multi-sine's |A_i| (slots 8, 11, ...)
    amp = sum(abs(spec[8 + 3 * i]) for i in range(4)) if sc.reference.family == "multisine" else abs(spec[4])
    bound = sc.lost_track * amp
    over = np.flatnonzero(ema > bound**2)
    return (float(traj.t[sel][over[0]]) if over.size else None), float(np.sqrt(ema.max())) / bound


CASES = (0, 1, 3, 22, 23, 41)  # held-out position episodes: sine/step/chirp/multi-sine, tracked and lost
# the env's position loop before issue 14, whose base law loses track on some of them (the defaults since lose none,
# reports/noise), so the detector is checked on both outcomes
# the loop with the position law's settings as they were when these cases were chosen (the defaults before the
# baselines' retune); in this legacy loop the retuned sigma and f_r lose track on all six
OLD_POSITION_LOOP = {"task": "position", **LEGACY_LOOP, "estimator": "foh", "sigma": 103663.2928437698, "fr": 60.0,
                     "smoothing": 36.51741272548377}


@pytest.mark.parametrize("index", CASES)
def test_detection_matches_an_independent_windowed_rms(index):
    """Position task in the loop before issue 14 (whose base law loses track on some randomised episodes): the
    compiled detector flags exactly the runs, at exactly the times, a numpy reference does."""
    tmpl = EnvConfig.from_kwargs(OLD_POSITION_LOOP).template()
    sc = heldout_scenarios(48, tmpl)[index].replace(log_interval=tmpl.control_period)
    traj = simulate(sc)
    m = traj.metrics()
    t_ref, ratio = _windowed_rms_first_crossing(traj)
    assert m["lost_track"] == (t_ref is not None)
    if t_ref is not None:
        assert m["t_lost_track"] == pytest.approx(t_ref, abs=1e-9)
    assert abs(ratio - 1.0) > 1e-3  # not a knife-edge case


def test_the_position_suite_has_both_outcomes():
    """The position cases above include runs that lose track and runs that do not (the test is not vacuous)."""
    tmpl = EnvConfig.from_kwargs(OLD_POSITION_LOOP).template()
    scs = heldout_scenarios(48, tmpl)
    flags = [simulate(scs[i]).lost_track for i in CASES]
    assert any(flags) and not all(flags)
    assert {scs[i].reference.family for i in CASES} == {"sine", "step", "chirp", "multisine"}


def test_terminate_on_lost_track_ends_the_episode():
    env = EHSSTrackingEnv(mode="direct", terminate_on_lost_track=True)
    infos = _run(env, _episode9(env), BangBang())
    last = infos[-1]
    assert last["lost_track"] and not last["diverged"] and "divergence_reason" not in last
    assert last["metrics"]["lost_track"] and last["t"] < 0.3  # ended right after 0.2 s, not at 2 s


def test_vector_env_reports_and_terminates_like_the_single_env():
    venv = EHSSTrackingVectorEnv(2, mode="direct", terminate_on_lost_track=True)
    env = EHSSTrackingEnv(mode="direct", terminate_on_lost_track=True)
    sc = _episode9(env)
    ref = _run(env, sc, BangBang())
    obs, _ = venv.reset(options={"scenario": sc})
    pol, state = BangBang(), None
    for k in range(len(ref)):
        a, state = pol.predict(obs, state)
        obs, _, term, trunc, info = venv.step(a)
        assert list(info["lost_track"]) == [ref[k]["lost_track"]] * 2
        assert not info["diverged"].any()
    assert term.all() and not trunc.any()


def test_the_harness_reports_a_lost_track_rate():
    cfg = EvalConfig(suites=("heldout",), tasks=("velocity",), heldout_episodes=2, n_boot=100)
    res = evaluate([object_spec("bang-bang", BangBang(), env_kwargs={"mode": "direct", "task": "velocity"})], cfg,
                   workers=1, progress=False)
    rates = {d["policy"]: d["lost_track_rate"] for d in res.summary}
    assert rates == {"clf-n2": 0.0, "bang-bang": 1.0}
    assert all(r["lost_track"] == (r["policy"] == "bang-bang") for r in res.rows)


def test_scenario_setting_is_validated_and_can_be_turned_off():
    with pytest.raises(ValueError, match=r"lost_track must be in \(0, inf\)"):
        Scenario(lost_track=0.0)
    assert Scenario(lost_track=None).lost_track_bound == math.inf
    assert Scenario(reference=sine(0.0, 2.0)).lost_track_bound == math.inf  # nothing to lose track of
    assert Scenario(reference=step(0.5, 0.1, offset=0.2), lost_track=2.0).lost_track_bound == pytest.approx(1.0)
    with pytest.raises(ValueError, match="terminate_on_lost_track must be True or False"):
        EHSSTrackingEnv(terminate_on_lost_track="yes")
    with pytest.raises(ValueError, match="lost_track"):
        EHSSTrackingEnv(lost_track=-1.0)
