"""Compensators of the valve and sensor effects the law's model leaves out, as pure compiled functions.

Two loop settings (:class:`ehss_gym.core.settings.Scenario`; 0 = off, and then each function returns at once and
the loop is bit for bit the one without them):

- **reference delay** (``reference_delay``, d samples, C_REF_DELAY): the law tracks the reference model's output and
  its derivatives of d control samples earlier (:func:`law_errors`). With a sensor delay of d samples the law
  otherwise drives the *measured* output, which is d samples old, onto today's y_d, so the true output leads y_d by
  about d h y_d' (docs/MODEL.md, "Compensating the unmodelled valve and sensors"); against y_d of d samples before,
  the measured output y(t - d h) meets y_d(t - d h) and the true output tracks y_d itself. The delayed values come
  from a ring of the reference model's own outputs (z[Z_REF_RING:]), so the law's reference and its derivatives are
  those of one signal, shifted; a fractional d interpolates linearly between two samples. Before the first sample
  the ring holds the first sample's values (the reference model at rest there, as the delay line has the plant).
- **valve inverse** (``inverse_threshold`` and ``inverse_hysteresis``, C_INV_THRESHOLD and C_INV_HYSTERESIS [mA]): a
  pre-compensator on the commanded current (:func:`valve_inverse`): the current that makes the valve's dead band and
  play operator (:mod:`ehss_gym.core.unmodelled_kernels`) with those parameters put out the command itself, computed
  from a model of the play operator's output (z[Z_VINV]), which the loop advances with the applied current
  (:func:`inverse_model_update`). With the valve's true
  parameters the model's output is the valve's own to the last bit, and the valve is driven by the command exactly
  (within the current limit): :func:`inverse_model_update` runs beside the valve's own
  :func:`~ehss_gym.core.unmodelled_kernels.valve_input` in the loop (:func:`ehss_gym.core.loop.lanes_period`).
"""

from __future__ import annotations

from .jit import jit, jit_inline
from .layout import I_E, I_YD, I_YE, N_YD, REF_RING, Z_REF_RING, Z_VINV
from .settings import C_INV_HYSTERESIS, C_INV_THRESHOLD, C_REF_DELAY
from .unmodelled_kernels import dead_band, play


@jit
def dead_band_inverse(p, th):
    """The current whose continuous dead zone of width ``th`` gives ``p``: p + sign(p) th (0 for p = 0) [mA]."""
    if p > 0.0:
        return p + th
    if p < 0.0:
        return p - th
    return 0.0


@jit
def play_inverse(v, y, r):
    """The input that moves a play operator of half-width ``r`` from its output ``y`` to the output ``v``: v + r
    upwards, v - r downwards, ``y`` itself when v = y (its output then stays) [mA]."""
    if v > y:
        return v + r
    if v < y:
        return v - r
    return y


@jit
def valve_inverse(z, v, ctrl):
    """The current [mA] to command so that the valve's dead band (ctrl[C_INV_THRESHOLD]) then play operator (total
    width ctrl[C_INV_HYSTERESIS]), whose output the model z[Z_VINV] holds, put out ``v`` [mA]; both 0: ``v``. Reads
    z only (the env's look-ahead may call it twice a sample; :func:`inverse_model_update` advances the model)."""
    th = ctrl[C_INV_THRESHOLD]
    hw = ctrl[C_INV_HYSTERESIS]
    if th == 0.0 and hw == 0.0:
        return v
    return dead_band_inverse(play_inverse(v, z[Z_VINV], 0.5 * hw), th)


@jit
def inverse_model_update(z, u, ctrl):
    """Advance the valve inverse's model of the play operator's output z[Z_VINV] [mA] with the applied current ``u``
    [mA] (once a control period, as the valve itself); off: nothing."""
    th = ctrl[C_INV_THRESHOLD]
    hw = ctrl[C_INV_HYSTERESIS]
    if th == 0.0 and hw == 0.0:
        return
    z[Z_VINV] = play(z[Z_VINV], dead_band(u, th), 0.5 * hw)


@jit_inline
def law_errors(z, k, m, ctrl, info):
    """The law's errors e^(i) = y_e^(i) - y_d^(i)(t_k - d h), i < m, into info[I_E + i], and its reference's top
    derivative y_d^(m)(t_k - d h) returned [output unit / s^m], for the reference delay d = ctrl[C_REF_DELAY]
    [control samples]; d = 0: today's y_d (info[I_YD + i]) itself.

    The reference model's outputs of sample k (info[I_YD:I_YD + m + 1]) enter the ring z[Z_REF_RING:] first; at k = 0
    every slot gets them. A fractional d = j + f interpolates between samples k - j and k - j - 1 (f = 0 reads sample
    k - j alone, exactly).
    """
    d = ctrl[C_REF_DELAY]
    if d == 0.0:
        for i in range(m):
            info[I_E + i] = info[I_YE + i] - info[I_YD + i]
        return info[I_YD + m]
    slot = Z_REF_RING + (k % REF_RING) * N_YD
    for i in range(m + 1):
        z[slot + i] = info[I_YD + i]
    if k == 0:
        for j in range(1, REF_RING):
            for i in range(m + 1):
                z[Z_REF_RING + j * N_YD + i] = info[I_YD + i]
    j = int(d)
    f = d - j
    a = Z_REF_RING + ((k - j) % REF_RING) * N_YD
    b = Z_REF_RING + ((k - j - 1) % REF_RING) * N_YD
    top = 0.0
    for i in range(m + 1):
        yd = z[a + i] if f == 0.0 else z[a + i] + f * (z[b + i] - z[a + i])
        if i < m:
            info[I_E + i] = info[I_YE + i] - yd
        else:
            top = yd
    return top


__all__ = ["dead_band_inverse", "play_inverse", "valve_inverse", "inverse_model_update", "law_errors"]
