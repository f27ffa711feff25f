"""Reference signals r(t): the paper's sine, plus step, chirp and multi-sine, and any signal given as samples
(:func:`from_array`) or as a Python function (:func:`from_function`).

Each reference is a flat float64 spec row (layout ``R_*``) evaluated by one compiled function
(:func:`ehss_gym.core.references.reference_value`), so a batch of scenarios can mix families; the families are the
rows of :data:`ehss_gym.core.registry.REFERENCE_FAMILIES`. A sampled ("table") reference carries its samples
in its row, so its row is longer: :func:`~ehss_gym.core.sim.simulate` and
:func:`~ehss_gym.core.sim.simulate_batch` run it; the env, whose lanes hold fixed-size rows, does not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .layout import MAX_SINES, N_REF, R_A1, R_KIND, R_MS0, R_OFFSET, R_P1, R_T0, R_T1, R_TAB0, R_TAB_N, R_W1, R_W_END
from .registry import REFERENCE_FAMILIES, code
from .validate import check_finite

FAMILIES = tuple(f.name for f in REFERENCE_FAMILIES if f.parametric)  # the parametric families (the env's and CLI's)
MAX_TABLE = 1_000_000  # samples of a table reference


@dataclass(frozen=True)
class Reference:
    """A reference signal r(t). Build with :func:`sine`, :func:`step`, :func:`chirp`, :func:`multisine`,
    :func:`from_array` or :func:`from_function`.

    Attributes:
        family: its family's name (a row of :data:`ehss_gym.core.registry.REFERENCE_FAMILIES`).
        spec: the flat parameter row read by the compiled kernels.
        description: human-readable parameters.
    """

    family: str
    spec: np.ndarray = field(repr=False)
    description: str = ""

    def __call__(self, t):
        """Evaluate r at time(s) t [s] (with the compiled kernel the simulator uses)."""
        from .references import reference_value  # numba only when a signal is evaluated: the CLI reads this module

        t = np.asarray(t, dtype=np.float64)
        out = np.array([reference_value(float(ti), self.spec) for ti in t.ravel()])
        return out.reshape(t.shape)

    @property
    def amplitude(self) -> float:
        """The largest |r - offset| the family's parameters allow [output unit] (multi-sine: the sum of the
        components' amplitudes; a table: half its range)."""
        kind = int(self.spec[R_KIND])
        if kind == code(REFERENCE_FAMILIES, "table"):
            n = int(self.spec[R_TAB_N])
            r = self.spec[R_TAB0 + n:R_TAB0 + 2 * n]
            return float(0.5 * (r.max() - r.min()))
        if kind == code(REFERENCE_FAMILIES, "multisine"):
            return float(sum(abs(self.spec[R_MS0 + 3 * i]) for i in range(MAX_SINES)))
        return float(abs(self.spec[R_A1]))

    @property
    def offset(self) -> float:
        """The constant offset of r [output unit]."""
        return float(self.spec[R_OFFSET])

    def to_dict(self) -> dict:
        return {"family": self.family, "description": self.description, "spec": self.spec.tolist()}


def _row(family: str) -> np.ndarray:
    row = np.zeros(N_REF)
    row[R_KIND] = code(REFERENCE_FAMILIES, family)
    return row


def sine(amplitude: float = 1.0, omega: float = 2.0, phase: float = 0.0, offset: float = 0.0) -> Reference:
    """r = offset + amplitude sin(omega t + phase). The paper: amplitude 1, omega 2 rad/s.

    Args:
        amplitude: output unit (rad/s velocity task, rad position task).
        omega: angular frequency [rad/s], >= 0.
        phase: [rad].
        offset: output unit.
    """
    row = _row("sine")
    row[R_A1] = check_finite("amplitude", amplitude)
    row[R_W1] = check_finite("omega", omega, low=0.0)
    row[R_P1] = check_finite("phase", phase)
    row[R_OFFSET] = check_finite("offset", offset)
    return Reference("sine", row, f"sine A={amplitude:g} w={omega:g} rad/s")


def step(amplitude: float = 1.0, t_step: float = 0.1, offset: float = 0.0) -> Reference:
    """r = offset + amplitude * [t >= t_step].

    Args:
        amplitude: output unit.
        t_step: switching time [s], >= 0.
        offset: output unit.
    """
    row = _row("step")
    row[R_A1] = check_finite("amplitude", amplitude)
    row[R_T0] = check_finite("t_step", t_step, low=0.0)
    row[R_OFFSET] = check_finite("offset", offset)
    return Reference("step", row, f"step A={amplitude:g} at {t_step:g} s")


def chirp(amplitude: float = 1.0, omega_start: float = 1.0, omega_end: float = 20.0, t_start: float = 0.0,
          t_end: float = 20.0, phase: float = 0.0, offset: float = 0.0) -> Reference:
    """Linear chirp from omega_start to omega_end [rad/s] between t_start and t_end [s], plus ``offset``.

    Holds omega_end after t_end, omega_start before t_start.
    """
    row = _row("chirp")
    row[R_OFFSET] = check_finite("offset", offset)
    row[R_A1] = check_finite("amplitude", amplitude)
    row[R_W1] = check_finite("omega_start", omega_start, low=0.0)
    row[R_W_END] = check_finite("omega_end", omega_end, low=0.0)
    row[R_T0] = check_finite("t_start", t_start, low=0.0)
    row[R_T1] = check_finite("t_end", t_end, low=row[R_T0], low_open=True)
    row[R_P1] = check_finite("phase", phase)
    return Reference("chirp", row, f"chirp A={amplitude:g} {omega_start:g}->{omega_end:g} rad/s")


def multisine(amplitudes, omegas, phases=None, offset: float = 0.0) -> Reference:
    """Sum of up to 4 sines: sum_i A_i sin(w_i t + phi_i) + offset."""
    amplitudes = list(amplitudes)
    omegas = list(omegas)
    phases = [0.0] * len(amplitudes) if phases is None else list(phases)
    if not 1 <= len(amplitudes) <= MAX_SINES or len(omegas) != len(amplitudes) or len(phases) != len(amplitudes):
        raise ValueError(f"multisine needs 1 to {MAX_SINES} components with equal-length amplitudes, omegas "
                         f"and phases; got {len(amplitudes)}, {len(omegas)}, {len(phases)}")
    row = _row("multisine")
    row[R_OFFSET] = check_finite("offset", offset)
    for i, (a, w, ph) in enumerate(zip(amplitudes, omegas, phases)):
        j = R_MS0 + 3 * i
        row[j] = check_finite(f"amplitudes[{i}]", a)
        row[j + 1] = check_finite(f"omegas[{i}]", w, low=0.0)
        row[j + 2] = check_finite(f"phases[{i}]", ph)
    desc = " + ".join(f"{a:g}sin({w:g}t)" for a, w in zip(amplitudes, omegas))
    return Reference("multisine", row, f"multisine {desc}")


def from_array(t, values, description: str | None = None) -> Reference:
    """A reference given by samples: r interpolated linearly between them, held at the first and last value
    outside them.

    Args:
        t: sample times [s], strictly increasing, at least 2, at most :data:`MAX_TABLE`.
        values: r at those times [output unit: rad/s velocity, rad position], finite.
        description: label (default: the number of samples and the time span).

    Raises:
        ValueError: naming ``t`` or ``values`` and what they must be.
    """
    t = np.asarray(t, dtype=np.float64).ravel()
    v = np.asarray(values, dtype=np.float64).ravel()
    if not 2 <= t.size <= MAX_TABLE:
        raise ValueError(f"t must hold 2 to {MAX_TABLE} sample times, got {t.size}")
    if v.size != t.size:
        raise ValueError(f"values must have one entry per sample time ({t.size}), got {v.size}")
    if not (np.all(np.isfinite(t)) and np.all(np.diff(t) > 0.0)):
        raise ValueError("t must be finite and strictly increasing [s]")
    if not np.all(np.isfinite(v)):
        raise ValueError("values must be finite numbers [output unit]")
    row = np.zeros(R_TAB0 + 2 * t.size)
    row[R_KIND] = code(REFERENCE_FAMILIES, "table")
    row[R_TAB_N] = t.size
    row[R_TAB0:R_TAB0 + t.size] = t
    row[R_TAB0 + t.size:] = v
    return Reference("table", row, description or f"table of {t.size} samples, {t[0]:g}..{t[-1]:g} s")


def from_function(fn, t_end: float, dt: float = 1e-4, description: str | None = None) -> Reference:
    """A reference from a Python function r = fn(t), sampled every ``dt`` over [0, t_end] (:func:`from_array`).

    ``fn`` gets a NumPy array of times [s] (or, if that fails, one float at a time) and returns r [output unit].
    Sampling at 1e-4 s (the default) resolves what the reference model (20 Hz) passes on.

    Args:
        fn: the function.
        t_end: last sample time [s] (> 0).
        dt: sampling interval [s] (> 0, at most t_end).
        description: label (default: the function's name).
    """
    t_end = check_finite("t_end", t_end, low=0.0, low_open=True)
    dt = check_finite("dt", dt, low=0.0, high=t_end, low_open=True)
    n = int(math.floor(t_end / dt + 1e-9)) + 1
    if n > MAX_TABLE:
        raise ValueError(f"t_end / dt gives {n} samples, more than {MAX_TABLE}; raise dt")
    t = np.arange(n) * dt
    try:
        v = np.asarray(fn(t), dtype=np.float64)
        if v.shape != t.shape:
            raise ValueError
    except Exception:  # a scalar function: one call per sample
        v = np.array([float(fn(float(ti))) for ti in t])
    name = getattr(fn, "__name__", type(fn).__name__)
    return from_array(t, v, description or f"function {name} sampled every {dt:g} s")


def paper_reference() -> Reference:
    """The paper's input: amplitude 1, 2 rad/s sine (Section IV)."""
    return sine(1.0, 2.0)


__all__ = ["Reference", "sine", "step", "chirp", "multisine", "from_array", "from_function", "paper_reference",
           "FAMILIES"]
