"""The observation: which controller quantities it holds, their scales, and how to decode it."""

from __future__ import annotations

import math

import numpy as np

from ehss_gym.core.layout import I_E, I_S, I_SHIFT, I_UAPP, I_UBASE, I_URES, I_W, I_XM, I_YD
from ehss_gym.core.settings import UNITS

from .actions import SCHEDULE_RANGES, action_dims, action_mode
from .buffers import MEM_APREV2, MEM_EINT, N_MEM
from .config import EnvConfig

# Observation normalisation (see the class docstring).
OBS_BOUND = 10.0  # observations are clipped to [-OBS_BOUND, OBS_BOUND] after the symlog squash
U_SCALE = 0.1  # [mA], order of the nominal tracking current
Y_SCALE = 1.0  # [output unit]
W_Y = 10.0  # [rad/s], time scale of the reference derivatives


def observation_layout(cfg: EnvConfig) -> list[tuple[str, int, float, bool, str]]:
    """(name, info index, scale, squashed, unit) of each observation entry; see the class docstring."""
    m = cfg.order
    unit = UNITS[cfg.task]
    wr = 2.0 * math.pi * cfg.fr
    p = cfg.plant.controller_model  # the scales the designer knows: the controller's model of the rig
    out = []
    for i in range(m):
        out.append((f"e_d{i}" if i else "e", I_E + i, cfg.error_scale * wr**i, True, f"{unit}/s^{i}"))
    out.append(("s", I_S, cfg.error_scale * wr ** (m - 1), True, f"{unit}/s^{m - 1}"))
    for i in range(m + 1):
        out.append((f"y_ref_d{i}" if i else "y_ref", I_YD + i, Y_SCALE * W_Y**i, True, f"{unit}/s^{i}"))
    out.append(("x1", I_XM + 0, 1.0, True, "rad"))
    out.append(("x2", I_XM + 1, 1.0, True, "rad/s"))
    out.append(("x3", I_XM + 2, p.P_s, True, "Pa"))
    out.append(("x4", I_XM + 3, p.K * U_SCALE, True, "m^2"))
    out.append(("u_applied", I_UAPP, U_SCALE, True, "mA"))
    out.append(("u_base", I_UBASE, U_SCALE, True, "mA"))
    out.append(("last_action", I_URES, cfg.residual_scale, False, "-"))
    if cfg.memory_tau is not None:  # memory features: source -1 - index into the lane's memory block (MEM_*)
        out.append(("e_int", -1 - MEM_EINT, cfg.error_scale * cfg.memory_tau, True, f"{unit}*s"))
        out.append(("prev_action", -1 - MEM_APREV2, 1.0, False, "-"))
    return out + action_entries(cfg)


def action_entries(cfg: EnvConfig) -> list[tuple[str, int, float, bool, str]]:
    """The entries an action mode but "current" appends (:mod:`ehss_gym.envs.actions`): its last action (each entry
    [-], linear; source -1 - its index in the lane's block of extras) and what the mode moves: the reference shift
    Delta at the next sample (over its bound, linear) where it shifts the reference, the boundary-layer width in use
    (scaled as s) where it schedules it. The
    rate and filtered residual is ``last_action`` (the residual of the last period over ``residual_scale``)."""
    row = action_mode(cfg.action)
    if row.name == "current":
        return []
    k = action_dims(row, cfg.dob_hz)
    if row.entries:
        names = [f"action_{e}" for e in row.entries]
    else:
        names = ["action"] if k == 1 else ["action_shift"] * row.shift + [
            f"action_{r[0]}" for r in SCHEDULE_RANGES[:k - row.shift]]
    out = [(name, -1 - (N_MEM + i), 1.0, False, "-") for i, name in enumerate(names)]
    unit = UNITS[cfg.task]
    if row.shift:
        out.append(("ref_shift", I_SHIFT, cfg.action_bound, False, unit))
    if row.schedule is not None:
        m = cfg.order
        out.append(("width", I_W, cfg.error_scale * (2.0 * math.pi * cfg.fr) ** (m - 1), True, f"{unit}/s^{m - 1}"))
    return out


def symlog_inverse(v):
    """Inverse of the observation squash sign(x) log(1 + |x|)."""
    v = np.asarray(v, dtype=np.float64)
    return np.sign(v) * np.expm1(np.abs(v))


def decode_observation(obs, layout) -> dict[str, np.ndarray]:
    """Physical values (in the units of :func:`observation_layout`) from observations (..., D)."""
    obs = np.asarray(obs, dtype=np.float64)
    out = {}
    for i, (name, _, scale, squash, _) in enumerate(layout):
        v = obs[..., i]
        out[name] = (symlog_inverse(v) if squash else v) * scale
    return out
