"""The CLF laws: Lin-Sontag's bound and its V-decrease, against Lin & Sontag's formula in exact arithmetic; the
adaptive boundary layer; the scripted-policy names."""

import math

import mpmath as mp
import numpy as np
import pytest
from hypothesis import example, given, settings, strategies

from ehss_gym import Scenario, simulate
from ehss_gym.controllers import CLFPolicy, parse_scripted
from ehss_gym.core.laws import lin_sontag, sontag
from ehss_gym.core.params import PlantParams
from ehss_gym.core.physics import lie_derivatives
from ehss_gym.core.signals import step
from ehss_gym.envs import EHSSTrackingEnv
from ehss_gym.envs.config import DEFAULTS, EnvConfig
from ehss_gym.evaluation import parse_policy
from ehss_gym.evaluation.loading import PolicyError

mp.mp.dps = 40
EPS = np.finfo(float).eps


def _log_uniform(lo, hi):
    return strategies.floats(math.log10(lo), math.log10(hi)).map(lambda x: 10.0**x)


SIGNED = strategies.tuples(strategies.sampled_from((-1.0, 1.0)), _log_uniform(1e-8, 1e12)).map(lambda t: t[0] * t[1])
N = strategies.sampled_from((2, 4, 6, 8))
LIMIT = _log_uniform(0.1, 1e3)
SIGMA = _log_uniform(1.0, 1e9)
WIDTH = strategies.one_of(strategies.just(0.0), _log_uniform(1e-3, 1e6))


def _states():
    """Plant states of the operating range (x3 within +-P_s, x4 within +-K * 20 mA) and a task."""
    p = PlantParams()
    return strategies.tuples(strategies.floats(-50.0, 50.0), strategies.floats(-p.P_s, p.P_s),
                             strategies.floats(-1.6e-5, 1.6e-5), strategies.sampled_from((3, 4)))


@settings(max_examples=600, deadline=None)
@given(psi=SIGNED, G=SIGNED, s=SIGNED, n=N, sigma=SIGMA, w=WIDTH, U=LIMIT)
def test_lin_sontag_never_exceeds_the_limit(psi, G, s, n, sigma, w, U):
    u = lin_sontag(psi, G, s, n, sigma, w, U)
    assert math.isfinite(u) and abs(u) <= U


@settings(max_examples=400, deadline=None)
@given(x=_states(), e=strategies.lists(SIGNED, min_size=4, max_size=4), n=N, sigma=SIGMA, w=WIDTH, U=LIMIT)
def test_lin_sontag_never_exceeds_the_limit_on_plant_states(x, e, n, sigma, w, U):
    """psi and G from the model's Lie derivatives at random states of both tasks, s and the error terms random."""
    x2, x3, x4, m = x
    F, G = lie_derivatives(np.array([0.0, x2, x3, x4]), PlantParams().as_array(), m, np.zeros(4))
    psi = F + e[0] + e[1] * 1e-3
    u = lin_sontag(psi, G, e[2], n, sigma, w, U)
    assert math.isfinite(u) and abs(u) <= U


def _exact_vdot_sign(psi, G, s, u):
    """sign(s) (psi + G u) in exact arithmetic: the sign of V' = (s/sigma)^(n-1)/sigma (psi + G u), n even."""
    return (1 if s > 0 else -1) * (mp.mpf(psi) + mp.mpf(G) * mp.mpf(u))


@settings(max_examples=600, deadline=None)
@given(psi=SIGNED, G=SIGNED, s=SIGNED, n=N, sigma=SIGMA, w=WIDTH, U=LIMIT)
def test_v_decreases_where_lin_sontags_formula_says_it_must(psi, G, s, n, sigma, w, U):
    """Where |psi| < U |G| the formula (smoothed or not) gives V' < 0 for every s != 0 (docs/MODEL.md, "Laws").

    The exact margin of the formula, M = -sign(s) (psi + G u) = |sg| (hypot(psi, |G| U b) - sign(s) psi
    sqrt(1 + b^2)) / den with b = |s/sigma|^(n-1) U |G| / sigma, is computed in 60-digit arithmetic (where the
    drift pushes s away, sign(s) psi > 0, in the cancellation-free form b^2 (G^2 U^2 - psi^2) / (hypot + |psi|
    sqrt(1 + b^2))); where it exceeds what the float command's rounding can move (|G| times a few ulp of the
    command), the float law's exact V' must be negative.
    """
    if not abs(psi) < U * abs(G):
        return
    u = lin_sontag(psi, G, s, n, sigma, w, U)
    sgn = 1 if s > 0 else -1
    P, Gm = mp.mpf(psi), mp.mpf(G)
    sg = mp.mpf(s) / mp.sqrt(mp.mpf(s) ** 2 + mp.mpf(w) ** 2) if w > 0 else mp.mpf(sgn)
    b = (abs(mp.mpf(s)) / sigma) ** (n - 1) * U * abs(Gm) / sigma
    den = 1 + abs(sg) * mp.sqrt(1 + b * b)
    hyp = mp.sqrt(P**2 + (abs(Gm) * U * b) ** 2)
    if sgn * psi > 0:
        margin = abs(sg) * b * b * (Gm**2 * U**2 - P**2) / (hyp + abs(P) * mp.sqrt(1 + b * b)) / den
    else:
        margin = abs(sg) * (hyp + abs(P) * mp.sqrt(1 + b * b)) / den
    assert margin > 0  # the formula's own claim, exactly
    if margin > 64 * EPS * abs(G) * max(abs(u), abs(psi / G), U):
        assert _exact_vdot_sign(psi, G, s, u) < 0


@settings(max_examples=400, deadline=None)
@given(psi=SIGNED, G=SIGNED, s=SIGNED, n=N, sigma=SIGMA, U=LIMIT)
@example(psi=-1e8, G=-1.0, s=1.0, n=2, sigma=1.0, U=1.0)  # |rho| = 1e8 beta_U: the unrationalised form gave 0
def test_lin_sontag_is_lin_and_sontags_formula(psi, G, s, n, sigma, U):
    """The kernel's rearranged form against the formula as published (unit ball, v = u/U), in exact arithmetic:

    v = -(a + sqrt(a^2 + b_v^4)) b_v / (b_v^2 (1 + sqrt(1 + b_v^2))),  a = (s/sigma)^(n-1) psi / sigma,
    b_v = (s/sigma)^(n-1) U G / sigma, clipped to |v| <= 1 where the formula asks for more.
    """
    q = (mp.mpf(s) / sigma) ** (n - 1) / sigma
    a, bv = q * psi, q * U * G
    if bv == 0:
        return
    v = -(a + mp.sqrt(a * a + bv**4)) * bv / (bv * bv * (1 + mp.sqrt(1 + bv * bv)))
    v = max(min(v, 1), -1)
    u = lin_sontag(psi, G, s, n, sigma, 0.0, U)
    assert abs(mp.mpf(u) - U * v) <= 1e-9 * U


@settings(max_examples=400, deadline=None)
@given(psi=SIGNED, G=SIGNED, s=SIGNED, n=N, sigma=SIGMA, w=WIDTH)
def test_sontag_decreases_v_everywhere(psi, G, s, n, sigma, w):
    """Sontag's formula (and its smoothed form) gives V' < 0 for every s != 0."""
    u = sontag(psi, G, s, n, sigma, w)
    if not math.isfinite(u):
        return
    sgn = 1 if s > 0 else -1
    sg = mp.mpf(s) / mp.sqrt(mp.mpf(s) ** 2 + mp.mpf(w) ** 2) if w > 0 else mp.mpf(sgn)
    beta = (abs(mp.mpf(s)) / sigma) ** (n - 1) * abs(G) / sigma
    margin = abs(sg) * abs(G) * mp.sqrt((mp.mpf(psi) / G) ** 2 + beta**2)  # -sign(s) (psi + G u), exactly
    if margin > 64 * EPS * abs(G) * max(abs(u), abs(psi / G)):
        assert _exact_vdot_sign(psi, G, s, u) < 0


def test_lin_sontag_clips_in_the_direction_that_minimises_v_dot():
    """Where |psi| > U |G| no bounded current makes V' < 0; the law then gives -U sign(s G), V's fastest descent."""
    for s, G in ((1.0, 2.0), (-1.0, 2.0), (1.0, -2.0), (-1.0, -2.0)):
        psi = 100.0 * (1 if s > 0 else -1)  # the drift pushes s away, 5x more than U |G| = 20 can answer
        u = lin_sontag(psi, G, s, 2, 1.0, 0.0, 10.0)
        assert u == -10.0 * math.copysign(1.0, s * G)


def test_lin_sontags_command_stays_within_the_limit_in_closed_loop():
    """A position step from rest: the law's own command (before the plant's limit) never exceeds 10 mA."""
    sc = Scenario(task="position", fr=20.0, sigma=1e7, law="lin-sontag", current_limit=10.0, control_period=5e-5,
                  substeps=1, t_end=0.5, reference=step(1.0, 0.1), friction=(), log_interval=5e-5)
    tr = simulate(sc)
    assert not tr.diverged
    assert np.max(np.abs(tr.u_base)) <= 10.0
    assert np.max(np.abs(tr.u_base)) == pytest.approx(10.0)  # the step asks for the whole bound


def test_lin_sontag_needs_a_current_limit():
    with pytest.raises(ValueError, match=r"law 'lin-sontag' bounds the current by current_limit.*> 0 \(mA\)"):
        Scenario(law="lin-sontag", current_limit=None)


@pytest.mark.parametrize("bad,match", [
    (dict(law="bang-bang"), r"law must be one of \['sontag', 'lin-sontag', 'min-norm'\], got 'bang-bang'"),
    (dict(estimator="kalman"), r"estimator must be one of \['foh', 'zoh', 'analog', 'state', 'eso'\], got 'kalman'"),
    (dict(layer_gain=-1.0), r"layer_gain must be in \[0, 100\], got -1"),
    (dict(layer_gain=1e3), r"layer_gain must be in \[0, 100\], got 1000"),
    (dict(smoothing=-1.0), r"smoothing must be in \[0, inf\), got -1"),
    (dict(observer_hz=0.0), r"observer_hz must be in \(0, inf\), got 0"),
    (dict(estimator_hz=-5.0), r"estimator_hz must be in \(0, inf\), got -5"),
    (dict(pressure_domain=1.5), r"pressure_domain must be in \(0, 1\], got 1.5"),
    (dict(ref_accel=-1.0, task="position"), r"ref_accel must be in \[0, inf\), got -1"),
    (dict(ref_accel=100.0), r"ref_accel shapes the position task's reference.*'velocity'"),
    (dict(bumpless=1), r"bumpless must be True or False, got 1"),
])
def test_bad_law_and_estimator_settings_name_the_parameter_and_range(bad, match):
    with pytest.raises(ValueError, match=match):
        Scenario(current_limit=10.0, **bad)
    with pytest.raises(ValueError, match=match):
        EnvConfig.from_kwargs(bad)


def test_adaptive_layer_follows_the_noise_of_s():
    """The adaptive width (3 running std of s) is ~0 in noise-free tracking and grows in proportion to the noise;
    a fixed w below it is replaced, one above it kept."""
    base = dict(task="velocity", fr=60.0, sigma=1e5, smoothing=0.0, layer_gain=3.0, current_limit=10.0,
                control_period=5e-5, substeps=1, t_end=0.4, friction=(), estimator="state", bumpless=True,
                log_interval=5e-5)
    med = []
    for k in (0.0, 1.0, 4.0):
        tr = simulate(Scenario(**base, noise_std=(0.0, 0.0, 2e3 * k, 0.0), seed=3))
        quiet = tr.t >= 0.3  # past the start-up transient, whose fast change of s also widens the layer
        med.append(float(np.median(tr.width[quiet])))
        if k > 0:  # the noise std of s from its logged samples: the layer is 3 of them (within the estimate's spread)
            ds = np.diff(tr.s[quiet])
            assert med[-1] == pytest.approx(3.0 * np.std(ds) / math.sqrt(2.0), rel=0.2)
    # Noise-free, s still moves on the discrete loop's own chattering (one sample's sign flip of the law steps s by
    # about G u h), a few units of s: the layer holds that too, a small fraction of what 1x pressure noise gives.
    assert med[0] < 0.05 * med[1]
    assert med[2] / med[1] == pytest.approx(4.0, rel=0.15)
    wide = simulate(Scenario(**{**base, "smoothing": 10 * med[2]}, noise_std=(0.0, 0.0, 8e3, 0.0), seed=3))
    assert np.all(wide.width == 10 * med[2])


@pytest.mark.parametrize("name,kw", [
    ("clf-n2", {"n": 2, "mode": "residual"}),
    ("lin-sontag-n4", {"n": 4, "mode": "residual", "law": "lin-sontag"}),
    ("sontag-foh-n2", {"n": 2, "mode": "residual", "law": "sontag", "estimator": "foh"}),
    ("lin-sontag-eso-n6", {"n": 6, "mode": "residual", "law": "lin-sontag", "estimator": "eso"}),
])
def test_scripted_names_map_to_env_settings(name, kw):
    assert parse_scripted(name) == kw
    cfg = EnvConfig.from_kwargs({**kw, "task": "position"})
    assert cfg.n == kw["n"] and cfg.law == kw.get("law", cfg.law)
    if kw.get("law") == "lin-sontag":  # a named law gets its own sigma, not the default law's
        assert cfg.sigma == DEFAULTS.position.sigma_for("lin-sontag")


def test_unknown_scripted_names_are_not_scripted_laws():
    assert parse_scripted("pid") is None and parse_scripted("sontag-tustin-n2") is None
    with pytest.raises(ValueError, match=r"an estimator variant names its law"):
        parse_scripted("clf-foh-n2")


def _episode(env, policy, phys):
    """One episode of ``policy`` from a pinned physical scenario; (per-step infos, the actions, the metrics)."""
    obs, _ = env.reset(options={"scenario": phys})
    state, start, infos, acts = None, True, [], []
    while True:
        action, state = policy.predict(obs, state, np.array([start]))
        start = False
        acts.append(float(np.asarray(action).reshape(-1)[0]))
        obs, _, term, trunc, info = env.step(action)
        infos.append(info)
        if term or trunc:
            return infos, np.array(acts), info["metrics"]


PHYS = {"reference": step(0.5, 0.05), "friction": ((1.8, 0.1, 0.2),), "t_end": 0.3,
        "noise_std": (1e-5, 1e-4, 2e3, 1e-10), "seed": 7}


@pytest.mark.parametrize("task", ["velocity", "position"])
@pytest.mark.parametrize("name", ["sontag-n2", "lin-sontag-n4", "lin-sontag-eso-n2", "sontag-state-n6",
                                  "sontag-foh-n2"])
def test_scripted_policy_of_each_law_is_that_law(name, task):
    """The scripted policy ``name`` (SB3 predict) acting every control period in direct mode applies the law the
    residual env applies itself with a zero residual: the same episode to the float32 observation's rounding.
    Lin-Sontag's command, the policy's action included, never leaves the bound."""
    kw = {**parse_scripted(name), "task": task, "agent_period": 1}
    res = EHSSTrackingEnv(**kw)
    direct = EHSSTrackingEnv(**{**kw, "mode": "direct"})
    assert res.config.law == kw.get("law", DEFAULTS.velocity.law if task == "velocity" else DEFAULTS.position.law)
    i_res, a_res, m_res = _episode(res, CLFPolicy(res), PHYS)
    i_dir, a_dir, m_dir = _episode(direct, CLFPolicy(direct), PHYS)
    assert np.all(a_res == 0.0)  # residual mode: the base law alone
    assert not m_res["diverged"] and not m_dir["diverged"]
    u_res = np.array([i["u_applied"] for i in i_res])
    u_dir = np.array([i["u_applied"] for i in i_dir])
    assert np.max(np.abs(u_dir - u_res)) <= 1e-3 * direct.config.current_limit
    if kw.get("law") == "lin-sontag":
        u_base = np.array([i["u_base"] for i in i_res])
        assert np.max(np.abs(u_base)) <= res.config.current_limit
        assert np.all(np.abs(a_dir) <= 1.0) and not any(i["clipped"] for i in i_dir)


def test_harness_accepts_the_variants_by_name():
    spec = parse_policy("lin-sontag-n4")
    assert spec.kind == "clf" and spec.env_kwargs == {"n": 4, "mode": "residual", "law": "lin-sontag"}
    spec = parse_policy("sontag-foh-n2")
    assert spec.env_kwargs == {"n": 2, "mode": "residual", "law": "sontag", "estimator": "foh"}
    assert parse_policy("clf-n6").env_kwargs == {"n": 6, "mode": "residual"}
    with pytest.raises(PolicyError, match=r"power factor must be an even integer"):
        parse_policy("lin-sontag-n3")
    with pytest.raises(PolicyError, match=r"an estimator variant names its law"):
        parse_policy("clf-eso-n2")
