"""Plant parameters (Table I of the paper) as one typed, validated record."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .layout import N_PARAM
from .validate import check_positive


class PlantParams(NamedTuple):
    """Parameters of the EHSS model, Eq. (1) and Table I. SI units unless noted.

    Attributes:
        J: total inertia of motor and load [kg*m^2 = N*m*s^2/rad].
        B: viscous damping coefficient [N*m*s/rad].
        d_m: volumetric displacement of the motor [m^3/rad].
        beta: fluid bulk modulus [Pa].
        V_m: total oil volume of the motor [m^3].
        c_d: valve discharge coefficient [-].
        rho: fluid mass density [kg/m^3].
        c_sm: motor leakage coefficient [m^5/(N*s)].
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

    def as_array(self) -> np.ndarray:
        """The record as a flat float64 array, in field order (for the kernels)."""
        return np.array(self, dtype=np.float64)

    def scaled(self, **factors: float) -> PlantParams:
        """A copy with named fields multiplied by factors (model mismatch)."""
        scaled = {k: getattr(self, _known(k)) * check_positive(k, f) for k, f in factors.items()}
        return make_plant_params(base=self, **scaled)


def _known(name: str) -> str:
    if name not in PlantParams._fields:
        raise ValueError(f"unknown plant parameter {name!r}; valid names: {', '.join(PlantParams._fields)}")
    return name


def make_plant_params(base: PlantParams | None = None, **values: float) -> PlantParams:
    """The one factory for :class:`PlantParams`: Table I with validated overrides.

    Args:
        base: record to start from (default: Table I).
        **values: field overrides; each must be finite and > 0.

    Raises:
        ValueError: an unknown name, or a value that is not finite and positive.
    """
    base = PlantParams() if base is None else base
    checked = {_known(k): check_positive(k, v) for k, v in values.items()}
    return base._replace(**checked)


# Named indices into PlantParams.as_array(), for the compiled kernels.
P_J, P_B, P_DM, P_BETA, P_VM, P_CD, P_RHO, P_CSM, P_PS, P_K, P_TAU, P_DV, P_DF, P_DPT = range(len(PlantParams._fields))
assert PlantParams._fields[P_DPT] == "dp_transition"
assert len(PlantParams._fields) == N_PARAM  # the envs' buffer layout sizes its parameter blocks by N_PARAM
