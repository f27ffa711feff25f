"""An oracle friction feed-forward: proof that the residual channel has authority, not a controller."""

from __future__ import annotations

import math

import numpy as np

from ehss_gym.core.params import PlantParams
from ehss_gym.core.physics import lie_derivatives

from .base import ScriptedPolicy


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
