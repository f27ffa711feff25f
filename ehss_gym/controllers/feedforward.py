"""Oracle residuals: a friction feed-forward that knows the events (proof that the residual channel has authority, not
a controller), and a constant residual current per episode (the headroom study's best-bias oracle)."""

from __future__ import annotations

import math

import numpy as np

from ehss_gym.core.physics import lie_derivatives

from .base import ScriptedPolicy


def _events(friction) -> tuple:
    """Friction events as a tuple of (amplitude N*m, start s, end s) float triples."""
    return tuple(tuple(float(v) for v in ev) for ev in friction)


class FrictionFeedforwardPolicy(ScriptedPolicy):
    """Oracle residual: a current doublet centred on each known friction edge (see the module docstring).

    Args:
        env: the env (or its config); residual mode.
        friction: the episode's friction events ((amplitude N*m, start s, end s), ...), the same for every env of a
            batch.
        amplitude: doublet current [mA]; None = residual_scale (a unit action).
        start_at_edge: start the doublet at each edge instead of centring it there: what a policy that
            cannot see the future could do with the same knowledge (it barely helps; docs/ENV.md).
        friction_by_lane: one tuple of events per env of the batch (env b of a batched ``predict`` gets entry b),
            instead of ``friction``: pinned episodes with different events side by side.
    """

    def __init__(self, env, friction=(), amplitude: float | None = None, start_at_edge: bool = False, *,
                 friction_by_lane=None):
        super().__init__(env)
        if self.config.mode != "residual":
            raise ValueError("FrictionFeedforwardPolicy needs mode='residual'")
        self.friction = _events(friction)
        self.friction_by_lane = None if friction_by_lane is None else tuple(_events(f) for f in friction_by_lane)
        self.amplitude = self.config.residual_scale if amplitude is None else float(amplitude)
        self.start_at_edge = bool(start_at_edge)
        model = self.config.plant.controller_model  # the controller's model of the env's rig
        self.model = model.as_array()
        self.J = model.J

    def _edges(self, b: int):
        for amp, t0, t1 in self.friction if self.friction_by_lane is None else self.friction_by_lane[b]:
            yield t0, amp, 1.0
            yield t1, amp, -1.0

    def act(self, obs, state, episode_start):
        n = obs.shape[0]
        if self.friction_by_lane is not None and len(self.friction_by_lane) != n:
            raise ValueError(f"friction_by_lane gives events for {len(self.friction_by_lane)} envs, the batch has {n}")
        state = self._fresh_state(obs, state, episode_start)
        cfg = self.config
        dt = cfg.agent_dt
        # only the values it needs (decoding every field costs more than the env's step at agent period 1)
        vel = self.value(obs, "y_ref" if cfg.task == "velocity" else "y_ref_d1")
        x = np.stack([self.value(obs, k) for k in ("x1", "x2", "x3", "x4")], axis=1)
        hbuf = np.zeros(4)
        out = np.zeros(n)
        U = self.amplitude
        for b in range(n):
            edges = [e for e in self._edges(b) if e[1] > 0.0]
            if not edges:  # no event to cancel: the model's G is not needed
                continue
            t0 = state[b, 0] * dt
            _, G = lie_derivatives(x[b], self.model, cfg.order, hbuf)
            G = abs(G)
            u = 0.0
            for te, amp, on in edges:
                if G <= 0.0:
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


class ConstantResidualPolicy(ScriptedPolicy):
    """A constant residual current per env of the batch, added to the base law for the whole episode.

    The headroom study's best-bias oracle (``ehss headroom``) searches each episode's best constant with it; the
    agent period does not change its episodes (the current never changes).

    Args:
        env: the env (or its config); residual mode.
        currents: the residual current of each env of a batch [mA] (env b of a batched ``predict`` gets entry b), each
            within +-residual_scale.
    """

    def __init__(self, env, *, currents):
        super().__init__(env)
        if self.config.mode != "residual":
            raise ValueError("ConstantResidualPolicy needs mode='residual'")
        c = np.asarray(currents, dtype=np.float64).reshape(-1)
        lim = self.config.residual_scale
        if c.size == 0 or not np.all(np.isfinite(c)) or np.any(np.abs(c) > lim):
            raise ValueError(f"currents must be finite currents within +-{lim:g} mA (residual_scale), one per env, "
                             f"got {currents!r}")
        self.currents = c

    observes = False  # the same currents whatever the envs show

    def act(self, obs, state, episode_start):
        if obs.shape[0] != self.currents.size:
            raise ValueError(f"currents gives {self.currents.size} envs, the batch has {obs.shape[0]}")
        return (self.currents / self.config.residual_scale).reshape(-1, 1), state
