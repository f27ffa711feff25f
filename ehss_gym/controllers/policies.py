r"""Scripted policies for EHSSTracking-v0 with stable-baselines3's ``predict`` interface.

Every policy here has ``predict(observation, state=None, episode_start=None, deterministic=True) ->
(actions, state)`` and works on one observation (D,) or a batch (n_envs, D), so SB3's
``evaluate_policy`` accepts them. They read the physical values from the observation with
:func:`ehss_gym.envs.observation.decode_observation`.

- :class:`CLFPolicy`: the Sontag/CLF law for the env's n. Residual mode: a zero residual (the base law
  alone). Direct mode: the Sontag current the env reports in the observation (``u_base``), over
  ``residual_scale``, held for the agent period.
- :class:`PIDPolicy`: a PID on the tracking error, u = -(kp e + ki int e dt + kd e') [mA], with the
  integrator clamped (anti-windup) so that |ki int e dt| <= the current limit. Direct mode: u is the
  whole valve current. Residual mode: u is added to the CLF law (CLF + PID).
  Gains come from :func:`tune_pid`, a documented, reproducible procedure:

  1. *Relay experiment* (Astrom-Hagglund): the loop (direct mode: the bare valve; residual mode: the
     CLF loop) under a relay u = -d sign(e) of amplitude d = ``relay_ma`` around r = 0, no friction,
     no noise, for ``relay_seconds``; from the second half, the ultimate period T_u (mean spacing of
     upward zero crossings of e) and the oscillation amplitude a ((max - min) / 2), so the ultimate
     gain is K_u = 4 d / (pi a).
  2. *Candidate rules* from (K_u, T_u), with k_i = K_p / T_i and k_d = K_p T_d:
     Ziegler-Nichols PID (0.6 K_u, T_u/2, T_u/8), ZN PI (0.45 K_u, T_u/1.2, 0),
     Tyreus-Luyben PID (0.45 K_u, 2.2 T_u, T_u/6.3), ZN "some overshoot" (0.33 K_u, T_u/2, T_u/3),
     ZN "no overshoot" (0.2 K_u, T_u/2, T_u/3).
  3. *Selection*: each candidate runs the tuning scenario (the paper's 1 rad/s, 2 rad/s sine -- 1 rad
     for position -- with a 1.8 N*m friction event from 1.5 s to 2.5 s, 3 s, no noise); the lowest
     RMSE wins (a diverged run scores inf).
  4. *Refinement*: coordinate search from the winner -- two rounds; in each, for kp, ki, kd in turn,
     the gain times 0.5, 0.7, 1.4 and 2 is tried on the tuning scenario and kept if it lowers the RMSE.

  :data:`PID_GAINS` stores the result of this procedure for the default settings of each task and
  mode; ``tests/test_policies.py`` re-runs the procedure and checks it reproduces them.
- :class:`FrictionFeedforwardPolicy`: an *oracle* residual that knows the friction events and adds a
  current doublet centred on each friction edge, sized so that G * int int u = Delta T_f / J cancels
  the torque step (G from the model's Lie derivatives at the measured state). It exists to show that
  the residual channel has authority (the env's residual-authority check), not as a controller.
"""

from __future__ import annotations

import math

import numpy as np

from ehss_gym.core.params import PlantParams
from ehss_gym.core.physics import lie_derivatives
from ehss_gym.core.signals import sine
from ehss_gym.envs import EnvConfig, decode_observation, observation_layout


def _config_of(env) -> EnvConfig:
    """The EnvConfig of an env, a wrapped env, a vector env, an SB3 VecEnv, or an EnvConfig itself."""
    if isinstance(env, EnvConfig):
        return env
    for getter in (lambda e: e.unwrapped.config, lambda e: e.config, lambda e: e.get_attr("config")[0],
                   lambda e: e.envs[0].unwrapped.config):
        try:
            cfg = getter(env)
        except Exception:  # noqa: BLE001 - try the next way to reach the config
            continue
        if isinstance(cfg, EnvConfig):
            return cfg
    raise ValueError(f"cannot find an EHSSTracking-v0 config in {env!r}; pass the env (or its EnvConfig)")


class ScriptedPolicy:
    """Base class: SB3-style ``predict`` on top of :meth:`act` (batch of observations -> actions)."""

    @staticmethod
    def _fresh_state(obs, state, episode_start):
        """One float of memory per env, zeroed where an episode starts."""
        n = obs.shape[0]
        if state is None or np.shape(state) != (n, 1):
            state = np.zeros((n, 1))
        else:
            state = np.array(state, dtype=np.float64)
        state[episode_start] = 0.0
        return state

    def __init__(self, env):
        self.config = _config_of(env)
        self.layout = observation_layout(self.config)
        self._index = {row[0]: (i, row[2], row[3]) for i, row in enumerate(self.layout)}

    def act(self, obs: np.ndarray, state, episode_start: np.ndarray):
        """Actions (n, 1) for observations (n, D); returns (actions, state)."""
        raise NotImplementedError

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        """SB3 interface: actions with the observation's batch shape, and the next state."""
        obs = np.asarray(observation, dtype=np.float32)
        single = obs.ndim == 1
        obs2 = obs.reshape(1, -1) if single else obs
        n = obs2.shape[0]
        if episode_start is None:
            starts = np.zeros(n, dtype=bool) if state is not None else np.ones(n, dtype=bool)
        else:
            starts = np.asarray(episode_start, dtype=bool).reshape(-1)
            if starts.size == 1 and n > 1:
                starts = np.repeat(starts, n)
        actions, state = self.act(obs2, state, starts)
        actions = np.clip(np.asarray(actions, dtype=np.float32).reshape(n, 1), -1.0, 1.0)
        return (actions[0] if single else actions), state

    def decode(self, obs: np.ndarray) -> dict:
        """All physical values of observations (n, D); see :func:`ehss_gym.envs.observation.decode_observation`."""
        return decode_observation(obs, self.layout)

    def value(self, obs: np.ndarray, name: str) -> np.ndarray:
        """One physical value (n,) of observations (n, D), e.g. "e" or "u_base"."""
        i, scale, squash = self._index[name]
        v = obs[:, i].astype(np.float64)
        return (np.sign(v) * np.expm1(np.abs(v)) if squash else v) * scale


class CLFPolicy(ScriptedPolicy):
    """The Sontag/CLF law (for the env's n): zero residual, or the Sontag current in direct mode."""

    def act(self, obs, state, episode_start):
        if self.config.mode == "residual":
            return np.zeros((obs.shape[0], 1)), state
        u = self.value(obs, "u_base")
        return (u / self.config.residual_scale).reshape(-1, 1), state


class PIDPolicy(ScriptedPolicy):
    """PID on the tracking error (see the module docstring).

    Args:
        env: the env (or its config).
        gains: (kp [mA/U], ki [mA/(U s)], kd [mA s/U]) with U the output unit; None = :data:`PID_GAINS`
            for default settings, else :func:`tune_pid` is run for this env's settings.
    """

    def __init__(self, env, gains: tuple[float, float, float] | None = None):
        super().__init__(env)
        if gains is None:
            gains = default_pid_gains(self.config)
        if len(gains) != 3 or not all(math.isfinite(float(g)) and float(g) >= 0.0 for g in gains):
            raise ValueError(f"gains must be three finite numbers >= 0 (kp, ki, kd), got {gains!r}")
        self.kp, self.ki, self.kd = (float(g) for g in gains)
        lim = self.config.current_limit
        self.i_limit = (lim if lim is not None else self.config.residual_scale) / self.ki if self.ki > 0 else 0.0

    def act(self, obs, state, episode_start):
        state = self._fresh_state(obs, state, episode_start)
        e, de = self.value(obs, "e"), self.value(obs, "e_d1")
        integ = np.clip(state[:, 0] + e * self.config.agent_dt, -self.i_limit, self.i_limit)
        state[:, 0] = integ
        u = -(self.kp * e + self.ki * integ + self.kd * de)
        return (u / self.config.residual_scale).reshape(-1, 1), state


class FrictionFeedforwardPolicy(ScriptedPolicy):
    """Oracle residual: a current doublet centred on each known friction edge (see the module docstring).

    Args:
        env: the env (or its config); residual mode.
        friction: the episode's friction events ((amplitude N*m, start s, end s), ...).
        amplitude: doublet current [mA]; None = residual_scale (a unit action).
        start_at_edge: start the doublet at each edge instead of centring it there: what a policy that
            cannot see the future could do with the same knowledge (it barely helps; docs/ENV.md).
    """

    def __init__(self, env, friction, amplitude: float | None = None, start_at_edge: bool = False):
        super().__init__(env)
        if self.config.mode != "residual":
            raise ValueError("FrictionFeedforwardPolicy needs mode='residual'")
        self.friction = tuple(tuple(float(v) for v in ev) for ev in friction)
        self.amplitude = self.config.residual_scale if amplitude is None else float(amplitude)
        self.start_at_edge = bool(start_at_edge)
        self.model = PlantParams().as_array()
        self.J = PlantParams().J

    def _edges(self):
        for amp, t0, t1 in self.friction:
            yield t0, amp, 1.0
            yield t1, amp, -1.0

    def act(self, obs, state, episode_start):
        n = obs.shape[0]
        state = self._fresh_state(obs, state, episode_start)
        cfg = self.config
        dt = cfg.agent_dt
        d = self.decode(obs)
        vel = d["y_ref"] if cfg.task == "velocity" else d["y_ref_d1"]
        x = np.stack([d["x1"], d["x2"], d["x3"], d["x4"]], axis=1)
        hbuf = np.zeros(4)
        out = np.zeros(n)
        U = self.amplitude
        for b in range(n):
            t0 = state[b, 0] * dt
            _, G = lie_derivatives(x[b], self.model, cfg.order, hbuf)
            G = abs(G)
            u = 0.0
            for te, amp, on in self._edges():
                if G <= 0.0 or amp <= 0.0:
                    continue
                T1 = math.sqrt(amp / self.J / (G * U))
                if self.start_at_edge:
                    te += T1
                if not (te - T1 - dt <= t0 <= te + T1):
                    continue
                # The friction torque opposes motion: cancel its step in x2' = (... - T_f)/J.
                sgn = on * math.copysign(1.0, vel[b])
                # mean of the doublet (+U on [te-T1, te), -U on [te, te+T1)) over [t0, t0+dt)
                pos = max(0.0, min(t0 + dt, te) - max(t0, te - T1))
                neg = max(0.0, min(t0 + dt, te + T1) - max(t0, te))
                u += sgn * U * (pos - neg) / dt
            out[b] = u
        state[:, 0] += 1.0
        return (out / cfg.residual_scale).reshape(-1, 1), state


# ---------------------------------------------------------------------------------------------------
# PID tuning procedure

REFINE_ROUNDS = 2
REFINE_FACTORS = (0.5, 0.7, 1.4, 2.0)
RULES = {  # name: (Kp / Ku, Ti / Tu, Td / Tu)
    "ziegler-nichols-pid": (0.6, 0.5, 0.125),
    "ziegler-nichols-pi": (0.45, 1 / 1.2, 0.0),
    "tyreus-luyben-pid": (0.45, 2.2, 1 / 6.3),
    "zn-some-overshoot": (0.33, 0.5, 1 / 3),
    "zn-no-overshoot": (0.2, 0.5, 1 / 3),
}


def _run(env, policy, options) -> tuple[dict, np.ndarray]:
    obs, _ = env.reset(seed=0, options=options)
    state = None
    start = True
    es = []
    while True:
        a, state = policy.predict(obs, state, np.array([start]))
        start = False
        obs, _, term, trunc, info = env.step(a)
        es.append(info["e"])
        if term or trunc:
            return info["metrics"], np.asarray(es)


class _RelayPolicy(ScriptedPolicy):
    def __init__(self, env, d):
        super().__init__(env)
        self.d = d

    def act(self, obs, state, episode_start):
        e = self.value(obs, "e")
        u = np.where(e > 0.0, -self.d, self.d)  # sign(0) taken as -1: kicks the loop off rest
        return (u / self.config.residual_scale).reshape(-1, 1), state


def _tuning_env(env_or_config):
    from ehss_gym.envs import EHSSTrackingEnv

    cfg = _config_of(env_or_config) if env_or_config is not None else EnvConfig.from_kwargs({})
    return EHSSTrackingEnv(**{k: getattr(cfg, k) for k in EnvConfig.KEYS if k not in ("scenario", "episode_seconds")})


def relay_experiment(env_or_config=None, relay_ma: float = 0.05, relay_seconds: float = 2.0):
    """Step 1 of :func:`tune_pid`: (K_u [mA/U], T_u [s], a [U]) from a relay of amplitude ``relay_ma`` [mA]."""
    env = env_or_config if hasattr(env_or_config, "step") else _tuning_env(env_or_config)
    relay = {"reference": sine(0.0, 0.0), "friction": (), "t_end": relay_seconds}
    _, e = _run(env, _RelayPolicy(env, relay_ma), {"scenario": relay})
    tail = e[len(e) // 2:]
    up = np.nonzero((tail[:-1] < 0.0) & (tail[1:] >= 0.0))[0]
    if len(up) < 3:
        raise RuntimeError(f"relay experiment did not oscillate (found {len(up)} upward zero crossings)")
    Tu = float(np.mean(np.diff(up))) * env.unwrapped.config.agent_dt
    a = 0.5 * float(tail[up[0]:up[-1] + 1].max() - tail[up[0]:up[-1] + 1].min())
    return 4.0 * relay_ma / (math.pi * a), Tu, a


def tune_pid(env_or_config=None, relay_ma: float = 0.05, relay_seconds: float = 2.0, progress: bool = True) -> dict:
    """Run the PID tuning procedure of the module docstring for an env's settings.

    Args:
        env_or_config: an EHSSTracking env or EnvConfig (default: the default velocity residual env).
        relay_ma: relay amplitude d [mA].
        relay_seconds: relay experiment duration [s].
        progress: show a progress bar over the tuning runs (about 30 episodes of 3 s).

    Returns:
        dict with "gains" (kp, ki, kd), "rule" (the winning rule), "rmse" (of the final gains on the
        tuning scenario), "Ku" [mA/U], "Tu" [s], "amplitude" a [U], and "scores" (RMSE of every
        candidate rule).
    """
    from tqdm import tqdm

    env = _tuning_env(env_or_config)
    bar = tqdm(total=1 + len(RULES) + REFINE_ROUNDS * 3 * len(REFINE_FACTORS), desc="tune_pid", disable=not progress,
               leave=False)
    Ku, Tu, a = relay_experiment(env, relay_ma, relay_seconds)
    bar.update()
    tune = {"reference": sine(1.0, 2.0), "friction": ((1.8, 1.5, 2.5),), "t_end": 3.0}

    def score(gains):
        m, _ = _run(env, PIDPolicy(env, tuple(gains)), {"scenario": tune})
        bar.update()
        return math.inf if m["diverged"] else m["rmse"]

    scores = {}
    cands = {}
    for name, (fp, fi, fd) in RULES.items():
        kp = fp * Ku
        cands[name] = (kp, kp / (fi * Tu), kp * fd * Tu)
        scores[name] = score(cands[name])
    best = min(scores, key=lambda k: (scores[k], k))
    gains, rmse = list(cands[best]), scores[best]
    for _ in range(REFINE_ROUNDS):
        for j in range(3):
            for f in REFINE_FACTORS:
                trial = list(gains)
                trial[j] *= f
                sc = score(trial)
                if sc < rmse:
                    gains, rmse = trial, sc
    bar.close()
    return {"gains": tuple(gains), "rule": best, "rmse": rmse, "Ku": Ku, "Tu": Tu, "amplitude": a,
            "scores": scores}


# Output of tune_pid() for the default settings of each (task, mode), (kp, ki, kd); regenerate with
# {key: tune_pid(EnvConfig.from_kwargs({"task": t, "mode": m}))["gains"]}; checked by tests/test_policies.py.
# Tuning-scenario RMSE at the defaults re-derived on the corrected loop (h = 50 us, f_r 60 / 20 Hz):
# velocity residual 1.463e-3 rad/s (Tyreus-Luyben PID), velocity direct 7.597e-2 rad/s, position residual
# 2.99e-4 rad, position direct 1.909e-2 rad (ZN-PID).
PID_GAINS: dict[tuple[str, str], tuple[float, float, float]] = {
    ("velocity", "residual"): (125.91967545728258, 170.34588130043636, 0.20986612576213765),
    ("velocity", "direct"): (0.14329896123699692, 1.320727753336377, 0.003886984323553541),
    ("position", "residual"): (64.74400704355006, 811.3284090670434, 1.8452042007411764),
    ("position", "direct"): (0.8061566651706392, 29.70050871681302, 0.030633953276484285),
}


# Relay-experiment ultimate points (K_u [mA/U], T_u [s]) behind PID_GAINS.
PID_RELAY: dict[tuple[str, str], tuple[float, float]] = {
    ("velocity", "residual"): (71.38303597351621, 0.0105),
    ("velocity", "direct"): (0.06092642909736264, 0.1085),
    ("position", "residual"): (55.05442775812081, 0.057),
    ("position", "direct"): (0.9597103156793325, 0.152),
}


def default_pid_gains(cfg: EnvConfig) -> tuple[float, float, float]:
    """Stored gains when ``cfg`` has the default settings of its task and mode, else :func:`tune_pid`."""
    key = (cfg.task, cfg.mode)
    if key in PID_GAINS and _is_default(cfg):
        return PID_GAINS[key]
    return tune_pid(cfg)["gains"]


def _is_default(cfg: EnvConfig) -> bool:
    ref = EnvConfig.from_kwargs({"task": cfg.task, "mode": cfg.mode})
    skip = ("scenario", "episode_seconds", "reward_weights", "error_scale")
    return all(getattr(cfg, k) == getattr(ref, k) for k in EnvConfig.KEYS if k not in skip)


__all__ = ["ScriptedPolicy", "CLFPolicy", "PIDPolicy", "FrictionFeedforwardPolicy", "tune_pid", "relay_experiment",
           "PID_GAINS", "PID_RELAY", "RULES", "default_pid_gains"]
