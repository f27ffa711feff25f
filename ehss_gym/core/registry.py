"""The extension points of the loop, one table each: CLF laws, output-derivative estimators, reference families.

A row names its kernel (a compiled function, by name) and carries its one-line doc, its defaults and its validation.
Its *code*, what the kernels read from the controller row or the reference row, is its index in the table. From the
tables come the kernels' dispatch (:func:`ehss_gym.core.jit.dispatch`), the validation of
:class:`~ehss_gym.core.settings.Scenario` and the env's settings, the CLI's choices and their help, and the names of
the scripted policies (``<law>-<estimator>-n<k>``, :mod:`ehss_gym.controllers.clf`).

**Adding a law** is its kernel in :mod:`ehss_gym.core.laws` plus one row of :data:`LAWS`. A law kernel takes any of
``psi, G, s, n, sigma, smoothing, ulim`` (by these names; ``s' = psi + G u``, ``V = (s/sigma)^n / n``, ``smoothing``
the boundary layer's width in use, ``ulim`` the current limit [mA]) and returns the base current [mA]. An estimator
is its kernels in :mod:`ehss_gym.core.estimators` (the derivatives at a sample, the filter advance) plus a row of
:data:`ESTIMATORS`; a reference family its kernel in :mod:`ehss_gym.core.references`, its builder in
:mod:`ehss_gym.core.signals` and a row of :data:`REFERENCE_FAMILIES`.

Plain data (no numpy, no numba): the command line reads these tables without loading the simulator.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class Law:
    """A CLF law: the base current from s' = psi + G u and V = (s/sigma)^n / n (docs/MODEL.md, "Laws").

    Attributes:
        name: its name in settings, on the command line and in scripted-policy names.
        kernel: its function in :mod:`ehss_gym.core.laws`.
        doc: one line: what it is.
        needs_limit: it bounds the current by ``current_limit``, which must then be finite.
    """

    name: str
    kernel: str
    doc: str
    needs_limit: bool = False


@dataclass(frozen=True)
class Estimator:
    """An output-derivative estimator: how the controller forms y', ..., y^(m-1) (docs/MODEL.md, "Estimators").

    Attributes:
        name: its name in settings, on the command line and in scripted-policy names.
        sense: its kernel in :mod:`ehss_gym.core.estimators` that writes the derivatives at a sample.
        advance: its kernel that advances its state over the period (None: it keeps none, or the plant's integrator
            advances it).
        doc: one line: what it is.
        svf: the scheme its state-variable filter and the reference model run ("foh", "zoh" or "analog";
            :mod:`ehss_gym.core.filters`).
        analog: its filters (and the reference model) are continuous, integrated with the plant by its RK4.
        observer: it needs the extended-state observer's filter block (bandwidth ``observer_hz``).
    """

    name: str
    sense: str
    advance: str | None
    doc: str
    svf: str = "foh"
    analog: bool = False
    observer: bool = False


@dataclass(frozen=True)
class ReferenceFamily:
    """A family of reference signals r(t) (:mod:`ehss_gym.core.signals`).

    Attributes:
        name: its name (``Reference.family``; ``--reference`` on the command line).
        kernel: its function in :mod:`ehss_gym.core.references`: r(t) from the offset and the spec row.
        doc: one line: what it is.
        parametric: its spec row has the fixed length (the env's lanes hold only those; a sampled table does not).
    """

    name: str
    kernel: str
    doc: str
    parametric: bool = True


LAWS: tuple[Law, ...] = (
    Law("sontag", "sontag", "Sontag's universal formula (the paper's law)"),
    Law("lin-sontag", "lin_sontag", "Lin & Sontag's formula for currents bounded by current_limit",
        needs_limit=True),
    Law("min-norm", "min_norm", "the pointwise min-norm current: -a/b where V' = a + b u has a > 0, else 0"),
)

ESTIMATORS: tuple[Estimator, ...] = (
    Estimator("foh", "svf_sense", "svf_advance", "the paper's state-variable filter, first-order hold: O(h^2) to "
              "the analog filter", svf="foh"),
    Estimator("zoh", "svf_sense", "svf_advance", "the state-variable filter, zero-order hold with the top "
              "derivative from the current sample: biased by O(h)", svf="zoh"),
    Estimator("analog", "svf_sense", None, "the continuous state-variable filter, integrated with the plant (the "
              "reference)", svf="analog", analog=True),
    Estimator("state", "state_sense", None, "the model's Lie derivatives of the measured state"),
    Estimator("eso", "eso_sense", "eso_advance", "an extended-state observer of the velocity and a lumped "
              "disturbance acceleration (bandwidth observer_hz)", observer=True),
)

REFERENCE_FAMILIES: tuple[ReferenceFamily, ...] = (
    ReferenceFamily("sine", "sine_value", "offset + A sin(w t + phi)"),
    ReferenceFamily("step", "step_value", "offset + A from t_step on"),
    ReferenceFamily("chirp", "chirp_value", "offset + A sin of a linear frequency sweep"),
    ReferenceFamily("multisine", "multisine_value", "offset + a sum of up to 4 sines"),
    ReferenceFamily("table", "table_value", "samples interpolated linearly, held outside them", parametric=False),
)


def names(table: Sequence) -> tuple[str, ...]:
    """The names of a table's rows, in table (code) order."""
    return tuple(row.name for row in table)


def code(table: Sequence, name: str, what: str = "name") -> int:
    """The code of row ``name`` (its index); ValueError naming ``what`` and the valid names otherwise."""
    for i, row in enumerate(table):
        if row.name == name:
            return i
    raise ValueError(f"{what} must be one of {list(names(table))}, got {name!r}")


def entry(table: Sequence, name: str, what: str = "name"):
    """The row named ``name``; ValueError naming ``what`` and the valid names otherwise."""
    return table[code(table, name, what)]


def choices_help(table: Sequence) -> str:
    """``name (doc); name (doc); ...`` of every row, for help texts."""
    return "; ".join(f"{row.name} ({row.doc})" for row in table)


__all__ = ["Law", "Estimator", "ReferenceFamily", "LAWS", "ESTIMATORS", "REFERENCE_FAMILIES", "names", "code", "entry",
           "choices_help"]
