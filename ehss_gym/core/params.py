"""Plant parameters (Table I of the paper) as one typed, validated, immutable record.

Every way of making a :class:`PlantParams` (the constructor, :func:`make_plant_params`, :meth:`PlantParams.scaled`,
``dataclasses.replace``) runs the same checks: each field must be a real number (an int or a float; text such as
``"0.02"`` is refused) inside its accepted range (:data:`FIELDS`), and the error names the field, its unit and the
range. The ranges are physical, wide enough for any servo rig and narrow enough to catch a value given in the wrong
unit (a supply pressure in bar, a displacement per revolution, a volume in litres). B = 0 (no damping) and c_sm = 0
(no leakage) are accepted: the model never divides by them. Every other field is strictly positive: the model
divides by J, V_m, rho, tau and the controller by its input gain G, which is proportional to d_m, beta, c_d and K
(docs/MODEL.md, "Lie derivatives"); the sigmoid and orifice constants keep the flow law smooth only when > 0.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np

from .layout import N_PARAM
from .validate import check_number, check_positive


class Field(NamedTuple):
    """One field of :class:`PlantParams`: its unit, what it is, and its accepted range.

    Attributes:
        name: the field's name.
        unit: its unit.
        text: what it is (for errors and docs).
        low, high: the accepted range [unit].
        low_open: ``low`` itself is excluded (the field must be > low).
    """

    name: str
    unit: str
    text: str
    low: float
    high: float
    low_open: bool = False


FIELDS: tuple[Field, ...] = (
    Field("J", "kg*m^2", "total inertia of motor and load", 1e-7, 1e3),
    Field("B", "N*m*s/rad", "viscous damping coefficient", 0.0, 1e4),
    Field("d_m", "m^3/rad", "motor displacement per radian", 1e-9, 1e-2),
    Field("beta", "Pa", "fluid bulk modulus", 1e7, 1e10),
    Field("V_m", "m^3", "oil volume under compression (both motor chambers and lines)", 1e-8, 1.0),
    Field("c_d", "-", "valve discharge coefficient", 0.0, 1.0, low_open=True),
    Field("rho", "kg/m^3", "fluid density", 500.0, 2000.0),
    Field("c_sm", "m^5/(N*s)", "motor leakage coefficient", 0.0, 1e-8),
    Field("P_s", "Pa", "supply pressure", 1e5, 1e8),
    Field("K", "m^2/mA", "servo-valve gain, opening area per current", 1e-12, 1e-3),
    Field("tau", "s", "servo-valve time constant", 1e-5, 1.0),
    Field("delta_valve", "m^4", "sigmoid constant of sign(x4)", 0.0, 1e-8, low_open=True),
    Field("delta_friction", "(rad/s)^2", "sigmoid constant of sign(x2) in the friction", 0.0, 1.0, low_open=True),
    Field("dp_transition", "Pa", "laminar transition pressure of the orifice", 0.0, 1e6, low_open=True),
)
FIELD_BY_NAME = {f.name: f for f in FIELDS}


@dataclass(frozen=True)
class PlantParams:
    """Parameters of the EHSS model, Eq. (1) and Table I. SI units unless noted; the accepted range of each field is
    in :data:`FIELDS` (a bad value raises ValueError naming the field, its unit and the range).

    Attributes:
        J: total inertia of motor and load [kg*m^2 = N*m*s^2/rad].
        B: viscous damping coefficient [N*m*s/rad] (0: no damping).
        d_m: volumetric displacement of the motor [m^3/rad].
        beta: fluid bulk modulus [Pa].
        V_m: total oil volume of the motor [m^3].
        c_d: valve discharge coefficient [-].
        rho: fluid mass density [kg/m^3].
        c_sm: motor leakage coefficient [m^5/(N*s)] (0: no leakage).
        P_s: supply pressure [Pa].
        K: servo-valve amplifier gain [m^2/mA]; the control u is in mA.
        tau: servo-valve time constant [s].
        delta_valve: sigmoid constant for sign(x4), Eq. (2) [m^4] (docs/MODEL.md, "Plant").
        delta_friction: sigmoid constant for sign(x2) in the friction law,
            Eq. (25) [(rad/s)^2].
        dp_transition: pressure below which the orifice turns laminar [Pa].
            sign(dp)*sqrt(|dp|/rho) is replaced by dp/sqrt(rho*sqrt(dp^2+dp_t^2)),
            which is smooth, never NaN, and differs from the turbulent root by
            less than 1e-7 relative for |dp| > 100*dp_t. Not in the paper.
    """

    J: float = 0.05
    B: float = 0.2
    d_m: float = 3e-6
    beta: float = 8e8
    V_m: float = 3e-4
    c_d: float = 0.61
    rho: float = 900.0
    c_sm: float = 9e-13
    P_s: float = 9e6
    K: float = 8e-7
    tau: float = 0.01
    delta_valve: float = 1e-18
    delta_friction: float = 1e-3
    dp_transition: float = 1e3

    _fields: ClassVar[tuple[str, ...]]  # the field names in order (set below; the kernels' P_* indices)

    def __post_init__(self):
        """Check every field (the first bad one raises ValueError naming it, its unit and the accepted range)."""
        for f in FIELDS:
            v = check_number(f"{f.name} ({f.text})", getattr(self, f.name), unit=f.unit, low=f.low, high=f.high,
                             low_open=f.low_open)
            object.__setattr__(self, f.name, v)

    def __iter__(self):
        """The values in field order (``tuple(p)``, ``np.array(p)``)."""
        return (getattr(self, name) for name in self._fields)

    def as_array(self) -> np.ndarray:
        """The record as a flat float64 array, in field order (for the kernels)."""
        return np.array([getattr(self, name) for name in self._fields], dtype=np.float64)

    def as_dict(self) -> dict[str, float]:
        """Field name -> value [its unit]."""
        return {name: getattr(self, name) for name in self._fields}

    def scaled(self, **factors: float) -> PlantParams:
        """A copy with named fields multiplied by factors (model mismatch)."""
        scaled = {k: getattr(self, _known(k)) * check_positive(f"{k} factor", f) for k, f in factors.items()}
        return make_plant_params(base=self, **scaled)

    def replace(self, **values: float) -> PlantParams:
        """A validated copy with fields changed (:func:`make_plant_params`)."""
        return make_plant_params(base=self, **values)


PlantParams._fields = tuple(f.name for f in dataclasses.fields(PlantParams))
assert PlantParams._fields == tuple(f.name for f in FIELDS)


def _known(name: str) -> str:
    if name not in PlantParams._fields:
        raise ValueError(f"unknown plant parameter {name!r}; valid names: {', '.join(PlantParams._fields)}")
    return name


def make_plant_params(base: PlantParams | None = None, **values: float) -> PlantParams:
    """The factory of :class:`PlantParams`: Table I (or ``base``) with validated overrides.

    Args:
        base: record to start from (default: Table I).
        **values: field overrides, each in its accepted range (:data:`FIELDS`).

    Raises:
        ValueError: an unknown name, or a value that is not a number in its field's range.
    """
    base = PlantParams() if base is None else base
    for k in values:
        _known(k)
    return dataclasses.replace(base, **values)


# Named indices into PlantParams.as_array(), for the compiled kernels.
P_J, P_B, P_DM, P_BETA, P_VM, P_CD, P_RHO, P_CSM, P_PS, P_K, P_TAU, P_DV, P_DF, P_DPT = range(len(PlantParams._fields))
assert PlantParams._fields[P_DPT] == "dp_transition"
assert len(PlantParams._fields) == N_PARAM  # the envs' buffer layout sizes its parameter blocks by N_PARAM
