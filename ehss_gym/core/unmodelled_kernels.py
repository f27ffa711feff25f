"""The unmodelled valve and sensors in the loop, as pure compiled functions (:mod:`ehss_gym.core.unmodelled`).

Two calls, one line each: :func:`valve_input` in the loop (:func:`ehss_gym.core.loop.lanes_period`) turns the current
the controller applies into the current that drives the valve's lag, and :func:`sense_unmodelled` in the controller
(:func:`ehss_gym.core.controller.controller_sense`) turns the sensors' reading into what the controller receives.
Their state is part of the flat loop state z: the play operator's output z[Z_PLAY] [mA] and the delay line
z[Z_DELAY:]. With every effect off (the controller row's C_THRESHOLD .. C_VEL_STEP all 0) both return at once and
touch nothing, so the loop is bit for bit the model's.
"""

from __future__ import annotations

import math

from .jit import jit
from .layout import N_PLANT, X_OMEGA, X_THETA, Z_DELAY, Z_PLAY
from .settings import C_DELAY, C_HYSTERESIS, C_POS_STEP, C_THRESHOLD, C_VEL_STEP


@jit
def dead_band(u, th):
    """The continuous dead zone: 0 for |u| <= ``th``, else u - sign(u) th (same unit as u, here mA)."""
    if u > th:
        return u - th
    if u < -th:
        return u + th
    return 0.0


@jit
def play(y, u, r):
    """The play (backlash) operator of half-width ``r``: its new output from its last output ``y`` and input ``u``.

    The output stays where it is while |u - y| <= r and is dragged along at distance r otherwise; exact for an input
    held between updates (the loop's current is held over each control period).
    """
    if u - r > y:
        return u - r
    if u + r < y:
        return u + r
    return y


@jit
def quantise(x, q):
    """``x`` rounded to the nearest multiple of ``q`` > 0 (halves up): error <= q/2."""
    return q * math.floor(x / q + 0.5)


@jit
def valve_input(z, u, ctrl):
    """The current [mA] that drives the valve's lag x4' = (K u_eff - x4)/tau when the amplifier applies ``u`` [mA].

    The dead band of width ctrl[C_THRESHOLD] [mA] first, then the play operator of total width ctrl[C_HYSTERESIS]
    [mA], whose output (kept in z[Z_PLAY], 0 at rest) is u_eff. Both 0: ``u`` itself, z untouched.
    """
    th = ctrl[C_THRESHOLD]
    hw = ctrl[C_HYSTERESIS]
    if th == 0.0 and hw == 0.0:
        return u
    y = play(z[Z_PLAY], dead_band(u, th), 0.5 * hw)
    z[Z_PLAY] = y
    return y


@jit
def sense_unmodelled(z, xm, k, ctrl):
    """What the controller receives at sample ``k`` from the sensors' reading ``xm`` (x1..x4, with their noise),
    in place: x1 on the encoder's grid ctrl[C_POS_STEP] [rad], x2 on its grid ctrl[C_VEL_STEP] [rad/s], then all
    four delayed by ctrl[C_DELAY] samples (:func:`delay_line`). Every slot 0: ``xm`` and z untouched."""
    qp = ctrl[C_POS_STEP]
    if qp > 0.0:
        xm[X_THETA] = quantise(xm[X_THETA], qp)
    qv = ctrl[C_VEL_STEP]
    if qv > 0.0:
        xm[X_OMEGA] = quantise(xm[X_OMEGA], qv)
    d = int(ctrl[C_DELAY])
    if d > 0:
        delay_line(z, xm, k, d)


@jit
def delay_line(z, xm, k, d):
    """Swap ``xm`` (sample k's reading) with the reading of sample k - ``d`` kept in the ring z[Z_DELAY:].

    Slot k mod d was written at sample k - d; at k = 0 every slot is filled with the first reading (the plant was at
    rest at its initial state before it).
    """
    if k == 0:
        for j in range(d):
            for i in range(N_PLANT):
                z[Z_DELAY + j * N_PLANT + i] = xm[i]
    base = Z_DELAY + (k % d) * N_PLANT
    for i in range(N_PLANT):
        old = z[base + i]
        z[base + i] = xm[i]
        xm[i] = old


__all__ = ["dead_band", "play", "quantise", "valve_input", "sense_unmodelled", "delay_line"]
