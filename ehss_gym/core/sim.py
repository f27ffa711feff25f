"""Closed-loop simulator: the digital Sontag controller driving the EHSS plant.

The loop is what a digital controller does (see :func:`ehss_gym.core.control.controller_update`):
sample, compute, hold the current for one control period (ZOH) while the plant
is integrated with RK4 substeps. The reference model and the derivative estimator
are digital filters (``Scenario.estimator``: "foh", the default, or "zoh") or, with
"analog", continuous filters integrated together with the plant. Many scenarios run in one compiled, parallel
call; per-step metrics accumulate online at the full control rate, while the
trajectory is logged every ``log_interval``.

A run that produces a non-finite value or leaves the state bounds (|x2| >
``omega_max``, |x3| > ``pressure_bound`` * P_s) is stopped and reported as
diverged with its time; its log ends at the last finite sample and no NaN is
returned.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numba as nb
import numpy as np

from . import layout as L
from .control import check_state, controller_apply, controller_update, integrate_lanes
from .filters import butterworth_coefficients, observer_filter, padded_filter
from .metrics import summarize
from .params import PlantParams
from .physics import N_LANE_CONST, jit, jit_noalloc, lane_constants
from .signals import Reference, paper_reference
from .validate import check_bool, check_choice, check_even_n, check_finite, check_positive

LAYER_GAIN_MAX = 100.0  # largest adaptive boundary-layer gain accepted (w_eff = gain * noise std of s)

TASKS = {"velocity": 3, "position": 4}  # task -> relative degree m of its output
UNITS = {"velocity": "rad/s", "position": "rad"}  # task -> unit of its output y (and of e, y_d)
PAPER_FRICTION = ((1.8, 8.0, 10.0),)
MAX_LANES = 128  # scenarios integrated in lock-step by one thread


def check_friction(events) -> tuple[tuple[float, float, float], ...]:
    """Validate friction events (amplitude [N*m] >= 0, 0 <= start < end [s])."""
    out = []
    for i, ev in enumerate(events):
        try:
            a, t0, t1 = ev
        except (TypeError, ValueError):
            raise ValueError(f"friction[{i}] must be (amplitude, start, end), got {ev!r}") from None
        a = check_finite(f"friction[{i}].amplitude", a, low=0.0)
        t0 = check_finite(f"friction[{i}].start", t0, low=0.0)
        t1 = check_finite(f"friction[{i}].end", t1, low=t0, low_open=True)
        out.append((a, t0, t1))
    return tuple(out)


@dataclass(frozen=True)
class Scenario:
    """One closed-loop run. Every field is validated on construction.

    Attributes:
        task: "velocity" (output x2, relative degree 3) or "position" (x1, 4).
        n: CLF power factor, an even integer >= 2.
        fr: combined-error cutoff f_r [Hz] (Table I: 100 or 60).
        sigma: CLF scale sigma > 0, in the unit of s; 1 = the paper's law.
        smoothing: sign(s) smoothing width w >= 0 in the unit of s; 0 = plain law.
        current_limit: |u| limit [mA]; None = unlimited (the paper).
        control_period: controller sample time h [s].
        substeps: RK4 plant steps per control period (>= 1).
        t_end: simulated duration [s].
        log_interval: trajectory logging interval [s], rounded to a multiple of h.
        reference: the reference signal r(t).
        friction: events (amplitude [N*m], start [s], end [s]); default the paper's.
        plant: true plant parameters.
        model: the controller's model of the plant; None = the plant (no mismatch).
        noise_std: measurement noise std of (x1 [rad], x2 [rad/s], x3 [Pa], x4 [m^2]).
        seed: noise seed (integer >= 0).
        ref_model_hz: reference-model cutoff [Hz] (Table I: 20).
        estimator_hz: cutoff of the paper's state-variable filter (SVF) [Hz] (Table I: 1000).
        estimator: how the output derivatives are estimated. The paper's SVF (its reference model runs the
            same way): "foh" (default: first-order-hold discretisation with a feed-through term, O(h^2) to
            the analog filters), "zoh" (zero-order hold with the top derivative from the current sample:
            biased by O(h), wave 1's scheme) or "analog" (the continuous filters integrated with the
            plant's RK4; the reference). Without differentiating the output (reference model "foh"):
            "state" (the model's Lie derivatives of the measured state, y^(i) = L_f^i h(x_meas)) or "eso"
            (an extended-state observer of the velocity and a lumped disturbance acceleration, bandwidth
            ``observer_hz``). See docs/MODEL.md, "Digital filters" and "Estimators".
        observer_hz: error bandwidth of the "eso" observer [Hz] (unused by the other estimators).
        law: "sontag" (Sontag's universal formula, the paper's) or "lin-sontag" (Lin & Sontag's formula for
            controls bounded by ``current_limit``, which must then be finite). See docs/MODEL.md, "Laws".
        layer_gain: adaptive boundary layer: the width of the smooth sign is max(smoothing, layer_gain *
            the running noise std of s), in [0, LAYER_GAIN_MAX]; 0 = the fixed width ``smoothing``.
        bumpless: True = the reference model starts at the measured output (and the estimated derivatives)
            instead of at its steady state for r(0) (a bumpless start, as servo drives do).
        ref_accel: position task: acceleration bound a [rad/s^2] of the reference shaper, which turns r into a
            reference the valve can follow (|p''| <= a; r itself wherever |r''| <= a/2) ahead of the reference
            model; 0 = none (the paper's: r drives the reference model). See docs/MODEL.md, "Reference shaper".
        pressure_domain: the controller evaluates its model (Lie derivatives, F, G) at the measured state with
            the load pressure projected into |x3| <= pressure_domain * P_s of the model, in (0, 1]; None = at the
            measured x3 as is (before issue 14). Outside it a model with a lower P_s than the plant's reverses
            the sign of G. See docs/MODEL.md, "The model's pressure domain".
        omega_max: divergence bound on |x2| [rad/s].
        pressure_bound: divergence bound on |x3| as a multiple of P_s.
        lost_track: lost-track bound as a multiple of the reference's amplitude (> 0; None = never flagged): the
            run has lost track once the RMS of e over a sliding window (exponential, time constant
            ``LOST_TRACK_WINDOW`` = 0.1 s, from t = 0.2 s on) exceeds ``lost_track`` * ``reference.amplitude``
            (the amplitude's offset if it is 0; off if both are 0). Only reported (``metrics()["lost_track"]``,
            ``t_lost_track``): the run goes on. See :mod:`ehss_gym.core.metrics`.
    """

    task: str = "velocity"
    n: int = 2
    fr: float = 100.0
    sigma: float = 1.0
    smoothing: float = 0.0
    current_limit: float | None = None
    control_period: float = 1e-4
    substeps: int = 10
    t_end: float = 20.0
    log_interval: float = 1e-3
    reference: Reference = field(default_factory=paper_reference)
    friction: tuple = PAPER_FRICTION
    plant: PlantParams = field(default_factory=PlantParams)
    model: PlantParams | None = None
    noise_std: tuple = (0.0, 0.0, 0.0, 0.0)
    seed: int = 0
    ref_model_hz: float = 20.0
    estimator_hz: float = 1000.0
    estimator: str = "foh"
    observer_hz: float = 200.0
    law: str = "sontag"
    layer_gain: float = 0.0
    bumpless: bool = False
    ref_accel: float = 0.0
    pressure_domain: float | None = None  # the paper's loop; the env's default (0.95) is in envs.config
    omega_max: float = 1e3
    pressure_bound: float = 1.5
    lost_track: float | None = 1.0

    def __post_init__(self):
        if self.task not in TASKS:
            raise ValueError(f"task must be one of {sorted(TASKS)}, got {self.task!r}")
        check_choice("estimator", self.estimator, L.ESTIMATORS)
        check_choice("law", self.law, L.LAWS)
        object.__setattr__(self, "n", check_even_n(self.n))
        for name in ("fr", "sigma", "control_period", "t_end", "log_interval", "ref_model_hz", "estimator_hz",
                     "observer_hz", "omega_max", "pressure_bound"):
            object.__setattr__(self, name, check_positive(name, getattr(self, name)))
        object.__setattr__(self, "smoothing", check_finite("smoothing", self.smoothing, low=0.0))
        object.__setattr__(self, "layer_gain", check_finite("layer_gain", self.layer_gain, low=0.0,
                                                            high=LAYER_GAIN_MAX))
        object.__setattr__(self, "bumpless", check_bool("bumpless", self.bumpless))
        object.__setattr__(self, "ref_accel", check_finite("ref_accel", self.ref_accel, low=0.0))
        if self.pressure_domain is not None:
            object.__setattr__(self, "pressure_domain", check_finite("pressure_domain", self.pressure_domain, low=0.0,
                                                                     high=1.0, low_open=True))
        if self.ref_accel > 0.0 and (self.task != "position" or self.estimator == "analog"):
            raise ValueError(f"ref_accel shapes the position task's reference for a digital reference model: it must "
                             f"be 0 for task {self.task!r} with estimator {self.estimator!r}, got {self.ref_accel:g}")
        if self.current_limit is not None:
            object.__setattr__(self, "current_limit", check_positive("current_limit", self.current_limit))
        elif self.law == "lin-sontag":
            raise ValueError("law 'lin-sontag' bounds the current by current_limit, which must then be a finite "
                             "number > 0 (mA), got None")
        if isinstance(self.substeps, bool) or not float(self.substeps).is_integer() or self.substeps < 1:
            raise ValueError(f"substeps must be an integer >= 1, got {self.substeps!r}")
        object.__setattr__(self, "substeps", int(self.substeps))
        if self.t_end < self.control_period:
            raise ValueError(f"t_end must be >= control_period ({self.control_period:g} s), got {self.t_end:g}")
        object.__setattr__(self, "friction", check_friction(self.friction))
        if len(self.noise_std) != 4:
            raise ValueError(f"noise_std must have 4 entries (x1..x4), got {len(self.noise_std)}")
        object.__setattr__(self, "noise_std", tuple(check_finite(f"noise_std[{i}]", v, low=0.0)
                                                    for i, v in enumerate(self.noise_std)))
        if isinstance(self.seed, bool) or not float(self.seed).is_integer() or not 0 <= self.seed < 2**52:
            raise ValueError(f"seed must be an integer in [0, 2^52), got {self.seed!r}")
        if not isinstance(self.reference, Reference):
            raise ValueError(f"reference must be an ehss_gym.core.signals.Reference (sine, step, chirp, multisine), "
                             f"got {type(self.reference).__name__}")
        for name in ("plant", "model"):
            v = getattr(self, name)
            if v is not None and not isinstance(v, PlantParams):
                raise ValueError(f"{name} must be a PlantParams (use make_plant_params), got {type(v).__name__}")
        if self.lost_track is not None:
            object.__setattr__(self, "lost_track", check_positive("lost_track", self.lost_track))

    @property
    def order(self) -> int:
        """Relative degree m of the output: 3 (velocity) or 4 (position)."""
        return TASKS[self.task]

    @property
    def n_steps(self) -> int:
        """Number of control periods."""
        return int(round(self.t_end / self.control_period))

    @property
    def log_every(self) -> int:
        """Control periods per logged sample."""
        return max(1, int(round(self.log_interval / self.control_period)))

    @property
    def lost_track_bound(self) -> float:
        """The bound on the windowed RMS of e [output unit] that flags a lost track; inf = detection off."""
        scale = self.reference.amplitude or abs(self.reference.offset)
        return math.inf if self.lost_track is None or scale == 0.0 else self.lost_track * scale

    def grid(self) -> tuple:
        return (self.control_period, self.substeps, self.n_steps, self.log_every)

    def replace(self, **changes) -> Scenario:
        """A validated copy with fields changed."""
        return replace(self, **changes)


def lambdas(order: int, fr: float) -> np.ndarray:
    """Combined-error coefficients lambda_0..lambda_{m-2}: Butterworth of order m-1 at f_r [Hz]."""
    return butterworth_coefficients(order - 1, fr)


def ctrl_row(sc: Scenario) -> np.ndarray:
    """The controller row (layout C_*) of a scenario."""
    row = np.zeros(L.N_CTRL)
    row[L.C_ORDER] = sc.order
    row[L.C_N] = sc.n
    row[L.C_SIGMA] = sc.sigma
    row[L.C_SMOOTH] = sc.smoothing
    lam = lambdas(sc.order, sc.fr)
    row[L.C_LAM0:L.C_LAM0 + len(lam)] = lam
    row[L.C_ULIM] = math.inf if sc.current_limit is None else sc.current_limit
    row[L.C_SEED] = sc.seed
    row[L.C_NOISE_THETA:L.C_NOISE_THETA + 4] = sc.noise_std
    row[L.C_OMEGA_MAX] = sc.omega_max
    row[L.C_P_BOUND] = sc.pressure_bound
    row[L.C_BASE] = 1.0
    row[L.C_EST] = L.ESTIMATORS.index(sc.estimator)
    row[L.C_LAW] = L.LAWS.index(sc.law)
    row[L.C_LAYER_GAIN] = sc.layer_gain
    row[L.C_BUMPLESS] = 1.0 if sc.bumpless else 0.0
    row[L.C_REF_ACCEL] = sc.ref_accel
    row[L.C_PDOMAIN] = math.inf if sc.pressure_domain is None else sc.pressure_domain
    return row


def filter_block(order: int, ref_hz: float, est_hz: float, h: float, scheme: str = "foh",
                 observer_hz: float = 200.0) -> np.ndarray:
    """The (N_FB, 4, 4) filter block (layout FB_*) read by the controller kernels.

    ``scheme`` is the estimator (Scenario.estimator): an SVF scheme runs the reference model and the SVF that
    way; with "state" or "eso" the reference model runs "foh" (the SVF rows are then unused), and "eso" adds
    its observer (bandwidth ``observer_hz`` [Hz]).
    """
    svf = scheme if scheme in L.SVF_ESTIMATORS else "foh"
    cr, pr, er, dr = padded_filter(order, ref_hz, h, svf)
    ce, pe, ee, de = padded_filter(order - 1, est_hz, h, svf)
    f = np.zeros((L.N_FB, L.MAX_ORDER, L.MAX_ORDER))
    if scheme == "eso":
        po, eo, do = observer_filter(float(observer_hz), float(h))
        f[L.FB_PHI_OBS, :2, :2] = po
        f[L.FB_E_OBS, :2, :2] = eo
        f[L.FB_D_OBS, :2, :2] = do
    f[L.FB_PHI_REF] = pr
    f[L.FB_PHI_EST] = pe
    f[L.FB_VEC, L.FBV_C_REF] = cr
    f[L.FB_VEC, L.FBV_C_EST] = ce
    f[L.FB_VEC, L.FBV_E_REF] = er
    f[L.FB_VEC, L.FBV_E_EST] = ee
    f[L.FB_VEC2, L.FBV_D_REF] = dr
    f[L.FB_VEC2, L.FBV_D_EST] = de
    return f


def scenario_filter_block(sc: Scenario) -> np.ndarray:
    """The filter block of a scenario."""
    return filter_block(sc.order, sc.ref_model_hz, sc.estimator_hz, sc.control_period, sc.estimator, sc.observer_hz)


@jit
def init_filters(z, filt, r0):
    """Reference model at its steady state for r(0) = ``r0``, estimator at rest (y(0) = 0): z[4:] in place.

    The state w of a digital filter is z - D v at the sample (layout FB_*), so w = (r0, 0, ...) - D r0.
    """
    for i in range(L.N_PLANT, L.N_LOOP):
        z[i] = 0.0
    d = filt[L.FB_VEC2, L.FBV_D_REF]
    for i in range(L.MAX_ORDER):
        z[L.Z_REF + i] = (r0 if i == 0 else 0.0) - d[i] * r0


def initial_state(sc: Scenario, filt: np.ndarray | None = None) -> np.ndarray:
    """Plant at rest; reference model and estimator at their steady state for r(0) and y(0)."""
    z = np.zeros(L.N_LOOP)
    init_filters(z, scenario_filter_block(sc) if filt is None else filt, float(sc.reference(0.0)))
    return z


def _stack_rows(rows: Sequence[np.ndarray]) -> np.ndarray:
    """Reference spec rows stacked, zero-padded to the longest (a table reference's row is longer)."""
    out = np.zeros((len(rows), max(len(r) for r in rows)))
    for i, r in enumerate(rows):
        out[i, :len(r)] = r
    return out


@dataclass
class LoopArrays:
    """Stacked per-scenario arrays for the kernels (one row per scenario)."""

    z0: np.ndarray
    plant: np.ndarray
    model: np.ndarray
    ctrl: np.ndarray
    ref: np.ndarray
    events: np.ndarray
    filt: np.ndarray

    @classmethod
    def build(cls, scenarios: Sequence[Scenario]) -> LoopArrays:
        h = scenarios[0].control_period
        n_ev = max(1, max(len(s.friction) for s in scenarios))
        events = np.zeros((len(scenarios), n_ev, 3))
        events[:, :, 1] = events[:, :, 2] = math.inf  # padding never fires
        for i, s in enumerate(scenarios):
            if s.friction:
                events[i, :len(s.friction)] = s.friction
        cache = {}
        filt = np.empty((len(scenarios), L.N_FB, L.MAX_ORDER, L.MAX_ORDER))
        for i, s in enumerate(scenarios):
            key = (s.order, s.ref_model_hz, s.estimator_hz, s.estimator, s.observer_hz)
            if key not in cache:
                cache[key] = filter_block(*key[:3], h, s.estimator, s.observer_hz)
            filt[i] = cache[key]
        return cls(
            z0=np.stack([initial_state(s, f) for s, f in zip(scenarios, filt)]),
            plant=np.stack([s.plant.as_array() for s in scenarios]),
            model=np.stack([(s.model or s.plant).as_array() for s in scenarios]),
            ctrl=np.stack([ctrl_row(s) for s in scenarios]),
            ref=_stack_rows([s.reference.spec for s in scenarios]),
            events=events,
            filt=filt,
        )


@jit
def accumulate_window(acc, win, et, h):
    """Fold the true error ``et`` [output unit] of one sample into its metric window's class (layout WIN_*, M_SU_*,
    M_DST_*, M_TRK_*): steps, sum e^2, sum |e| h [output unit * s] and max |e|."""
    ae = abs(et)
    if win == L.WIN_TRACKING:
        acc[L.M_TRK_STEPS] += 1.0
        acc[L.M_TRK_SUM_E2] += et * et
        acc[L.M_TRK_SUM_ABS] += ae * h
    elif win == L.WIN_DISTURBANCE:
        acc[L.M_DST_STEPS] += 1.0
        acc[L.M_DST_SUM_ABS] += ae * h
        if ae > acc[L.M_DST_MAX]:
            acc[L.M_DST_MAX] = ae
    else:
        acc[L.M_SU_STEPS] += 1.0
        acc[L.M_SU_SUM_E2] += et * et
        acc[L.M_SU_SUM_ABS] += ae * h
        if ae > acc[L.M_SU_MAX]:
            acc[L.M_SU_MAX] = ae


@jit
def accumulate(acc, info, h, k):
    """Fold one control step's info into the metrics accumulator (layout M_*)."""
    e = info[L.I_E]
    ae = abs(e)
    et = info[L.I_E_TRUE]
    t = info[L.I_T]
    acc[L.M_SUM_E2_TRUE] += et * et
    acc[L.M_SUM_ER2] += info[L.I_E_R] * info[L.I_E_R]
    acc[L.M_SUM_ABS_ER] += abs(info[L.I_E_R]) * h
    accumulate_window(acc, info[L.I_WIN], et, h)
    acc[L.M_STEPS] += 1.0
    acc[L.M_SUM_E2] += e * e
    acc[L.M_SUM_ABS_E] += ae * h
    acc[L.M_SUM_T_ABS_E] += t * ae * h
    if ae > acc[L.M_MAX_E]:
        acc[L.M_MAX_E] = ae
    if info[L.I_FRIC_ON] > 0.0:
        acc[L.M_STEPS_FRIC] += 1.0
        if ae > acc[L.M_MAX_E_FRIC]:
            acc[L.M_MAX_E_FRIC] = ae
        if abs(et) > acc[L.M_MAX_E_FRIC_TRUE]:
            acc[L.M_MAX_E_FRIC_TRUE] = abs(et)
    else:
        acc[L.M_STEPS_NOFRIC] += 1.0
        acc[L.M_SUM_E2_NOFRIC] += e * e
    if info[L.I_QUIET] > 0.0:
        acc[L.M_STEPS_QUIET] += 1.0
        acc[L.M_SUM_E2_QUIET] += e * e
        acc[L.M_SUM_E2_QUIET_TRUE] += et * et
    if t >= L.QUIET_STARTUP:
        if info[L.I_FRIC_ON] == 0.0:
            acc[L.M_STEPS_SETTLED] += 1.0
            acc[L.M_SUM_E2_SETTLED] += e * e
        # lost track: the windowed RMS of e above its bound (from the start-up's end; the window starts empty)
        acc[L.M_LOST_EMA] += (e * e - acc[L.M_LOST_EMA]) * min(1.0, h / L.LOST_TRACK_WINDOW)
        if acc[L.M_LOST] == 0.0 and acc[L.M_LOST_EMA] > acc[L.M_LOST_BOUND] * acc[L.M_LOST_BOUND]:
            acc[L.M_LOST] = 1.0
            acc[L.M_T_LOST] = t
    u = info[L.I_UAPP]
    if k > 0:
        acc[L.M_TV_U] += abs(u - acc[L.M_LAST_U])
        if info[L.I_V] < acc[L.M_LAST_V]:
            acc[L.M_N_VDEC] += 1.0
    acc[L.M_LAST_U] = u
    acc[L.M_LAST_V] = info[L.I_V]
    uc = abs(info[L.I_UCMD])
    if uc > acc[L.M_PEAK_UCMD]:
        acc[L.M_PEAK_UCMD] = uc
    if abs(u) > acc[L.M_PEAK_UAPP]:
        acc[L.M_PEAK_UAPP] = abs(u)
    acc[L.M_SUM_U2] += u * u
    acc[L.M_N_SAT] += info[L.I_SAT]


@jit
def write_log(row, z, info):
    row[L.L_T] = info[L.I_T]
    for i in range(4):
        row[L.L_X + i] = z[i]
    row[L.L_R] = info[L.I_R]
    for i in range(5):
        row[L.L_YD + i] = info[L.I_YD + i]
    for i in range(4):
        row[L.L_YE + i] = info[L.I_YE + i]
        row[L.L_E + i] = info[L.I_E + i]
    row[L.L_S] = info[L.I_S]
    row[L.L_V] = info[L.I_V]
    row[L.L_UBASE] = info[L.I_UBASE]
    row[L.L_URES] = info[L.I_URES]
    row[L.L_UCMD] = info[L.I_UCMD]
    row[L.L_UAPP] = info[L.I_UAPP]
    row[L.L_TF] = info[L.I_TF]
    row[L.L_W] = info[L.I_W]
    row[L.L_RM] = info[L.I_RM]
    row[L.L_UMIN] = info[L.I_UAPP]  # the envelope of the sample's log interval starts here
    row[L.L_UMAX] = info[L.I_UAPP]


@jit
def widen_envelope(row, u):
    """Widen a log row's applied-current envelope (L_UMIN, L_UMAX) [mA] by one more period's current ``u``."""
    if u < row[L.L_UMIN]:
        row[L.L_UMIN] = u
    if u > row[L.L_UMAX]:
        row[L.L_UMAX] = u


@jit
def _diverge(acc, code, k, h):
    acc[L.M_DIVERGED] = code
    acc[L.M_T_DIVERGED] = (k + 1) * h


@jit_noalloc
def lanes_period(z, k, h, substeps, plant, model, ctrl, ref, events, filt, u_res, active, info, acc, c, X, U,
                 zprev, work, lwork, pre, peek):
    """Advance every active lane by one control period; returns the number still active.

    For each lane: the controller (with residual ``u_res[b]`` [mA]), then the
    plants of all lanes integrated together, then the divergence checks and the
    metrics. A lane that diverges is marked inactive, keeps its last finite
    state, and gets its DIV_* code and time in ``acc``. ``zprev`` receives the
    state at t_k (what the logged sample shows).

    A lane with ``pre[b]`` set has already been sensed at this k from this state
    (:func:`ehss_gym.core.control.controller_sense` and the filter advance, as the
    env's look-ahead does): ``peek[b, :N_INFO]`` holds that info and
    ``peek[b, N_INFO:]`` the loop state after the filter advance. The controller
    then only applies the residual (same arithmetic, bit for bit), and
    ``pre[b]`` is cleared. The simulator passes no such lanes.
    """
    B = z.shape[0]
    n_active = 0
    analog = False
    for b in range(B):
        if active[b] and ctrl[b, L.C_EST] == L.EST_ANALOG:
            analog = True
    nx = L.N_LOOP if analog else L.N_PLANT  # rows integrated: the plant, and with analog lanes the filters too
    ynoise = lwork[5, 1]
    for b in range(B):
        if not active[b]:
            U[b] = 0.0
            continue
        for i in range(z.shape[1]):  # element loops: an array assignment may allocate (no NRT here)
            zprev[b, i] = z[b, i]
        if pre[b]:
            pre[b] = False
            for i in range(L.N_INFO):
                info[b, i] = peek[b, i]
            u = controller_apply(info[b], ctrl[b], peek[b, L.I_UBASE], u_res[b])
            for i in range(L.N_PLANT, z.shape[1]):
                z[b, i] = peek[b, L.N_INFO + i]
        else:
            u = controller_update(z[b], k, h, plant[b], model[b], ctrl[b], ref[b], events[b], filt[b], u_res[b],
                                  info[b], work)
        if not (math.isfinite(u) and math.isfinite(info[b, L.I_V]) and math.isfinite(info[b, L.I_S])):
            _diverge(acc[b], L.DIV_CURRENT if not math.isfinite(u) else L.DIV_NONFINITE, k, h)
            active[b] = False
            for i in range(z.shape[1]):
                z[b, i] = zprev[b, i]
            U[b] = 0.0
            continue
        U[b] = u
        for i in range(nx):
            X[i, b] = z[b, i]
        # the sensor noise on the output at this sample, held over the period for an analog estimator
        ynoise[b] = info[b, L.I_YE] - z[b, L.X_THETA if ctrl[b, L.C_ORDER] == 4 else L.X_OMEGA]
        n_active += 1
    if n_active == 0:
        return 0
    integrate_lanes(X, U, k * h, h, substeps, c, events, lwork, analog, ctrl, ref, filt, ynoise)
    for b in range(B):
        if not active[b]:
            continue
        for i in range(nx):
            z[b, i] = X[i, b]
        code = check_state(z[b], ctrl[b], plant[b])
        if code != L.DIV_NONE:
            _diverge(acc[b], code, k, h)
            active[b] = False
            for i in range(z.shape[1]):
                z[b, i] = zprev[b, i]
            for i in range(nx):
                X[i, b] = z[b, i]
            n_active -= 1
            continue
        accumulate(acc[b], info[b], h, k)
    return n_active


@jit
def run_lanes(z, h, substeps, n_steps, log_every, plant, model, ctrl, ref, events, filt, log, acc, n_log):
    """Simulate B scenarios in lock-step from k = 0 with no residual, logging every ``log_every`` periods."""
    B = z.shape[0]
    c = np.zeros((N_LANE_CONST, B))
    lane_constants(plant, c)
    X = np.zeros((L.N_LOOP, B))
    U = np.zeros(B)
    u_res = np.zeros(B)
    active = np.ones(B, dtype=np.bool_)
    info = np.zeros((B, L.N_INFO))
    work = np.zeros((8, 4))
    lwork = np.zeros((6, L.N_LOOP, B))
    zprev = np.zeros_like(z)
    pre = np.zeros(B, dtype=np.bool_)  # no lane is pre-sensed in a plain simulation
    peek = np.zeros((B, L.N_INFO + L.N_LOOP))
    for b in range(B):
        acc[b, L.M_T_DIVERGED] = -1.0
        n_log[b] = 0
    for k in range(n_steps):
        if lanes_period(z, k, h, substeps, plant, model, ctrl, ref, events, filt, u_res, active, info, acc, c, X, U,
                        zprev, work, lwork, pre, peek) == 0:
            break
        log_now = k % log_every == 0
        for b in range(B):
            if not active[b]:
                continue
            if log_now:
                write_log(log[b, n_log[b]], zprev[b], info[b])
                n_log[b] += 1
            else:  # between samples: the current's envelope over the log interval (no aliasing of the switching)
                widen_envelope(log[b, n_log[b] - 1], info[b, L.I_UAPP])


@nb.njit(parallel=True, cache=True, error_model="numpy")
def run_batch(z, h, substeps, n_steps, log_every, plant, model, ctrl, ref, events, filt, log, acc, n_log, chunk):
    """Simulate a batch: chunks of ``chunk`` scenarios in parallel, lanes within a chunk."""
    B = z.shape[0]
    n_chunks = (B + chunk - 1) // chunk
    for i in nb.prange(n_chunks):
        s = i * chunk
        e = min(B, s + chunk)
        run_lanes(z[s:e], h, substeps, n_steps, log_every, plant[s:e], model[s:e], ctrl[s:e], ref[s:e],
                  events[s:e], filt[s:e], log[s:e], acc[s:e], n_log[s:e])


@dataclass
class Trajectory:
    """A simulated run: logged signals plus metrics accumulated at the control rate.

    Signals are logged every ``scenario.log_interval`` (the sample at t_k holds
    the state at t_k and what the controller did then). Units: t [s], y, y_ref,
    e in the output unit (rad/s velocity, rad position), u [mA], friction [N*m].
    """

    scenario: Scenario
    log: np.ndarray = field(repr=False)
    acc: np.ndarray = field(repr=False)

    t = property(lambda self: self.log[:, L.L_T])
    x = property(lambda self: self.log[:, L.L_X:L.L_X + 4], doc="plant states (x1..x4)")
    r = property(lambda self: self.log[:, L.L_R], doc="reference-model input r")
    s = property(lambda self: self.log[:, L.L_S], doc="combined error")
    V = property(lambda self: self.log[:, L.L_V], doc="CLF value")
    u = property(lambda self: self.log[:, L.L_UCMD], doc="commanded current [mA]")
    u_applied = property(lambda self: self.log[:, L.L_UAPP], doc="applied current [mA]")
    u_base = property(lambda self: self.log[:, L.L_UBASE], doc="Sontag current [mA]")
    friction = property(lambda self: self.log[:, L.L_TF], doc="friction torque [N*m]")
    u_applied_min = property(lambda self: self.log[:, L.L_UMIN],
                             doc="smallest applied current over each sample's log interval [mA]")
    u_applied_max = property(lambda self: self.log[:, L.L_UMAX],
                             doc="largest applied current over each sample's log interval [mA]")
    width = property(lambda self: self.log[:, L.L_W], doc="boundary-layer width in use [unit of s]")
    r_model = property(lambda self: self.log[:, L.L_RM], doc="the reference model's input (r, or the shaped r)")
    e = property(lambda self: self.log[:, L.L_E], doc="tracking error y - y_d")

    @property
    def y(self):
        """Plant output: x2 (velocity) or x1 (position)."""
        return self.x[:, 1 if self.scenario.task == "velocity" else 0]

    @property
    def y_ref(self):
        """Reference-model output y_d."""
        return self.log[:, L.L_YD]

    @property
    def y_ref_derivs(self):
        """y_d, y_d', ..., y_d^(m) (m+1 columns)."""
        return self.log[:, L.L_YD:L.L_YD + self.scenario.order + 1]

    @property
    def y_est_derivs(self):
        """Measured y and the estimated y', ..., y^(m-1) (m columns)."""
        return self.log[:, L.L_YE:L.L_YE + self.scenario.order]

    @property
    def diverged(self) -> bool:
        return self.acc[L.M_DIVERGED] != L.DIV_NONE

    @property
    def divergence_reason(self) -> str:
        return L.DIV_NAMES[int(self.acc[L.M_DIVERGED])]

    @property
    def t_diverged(self) -> float | None:
        return float(self.acc[L.M_T_DIVERGED]) if self.diverged else None

    @property
    def lost_track(self) -> bool:
        """The windowed RMS of e exceeded the scenario's lost-track bound (see :class:`Scenario`)."""
        return bool(self.acc[L.M_LOST] > 0.0)

    def metrics(self) -> dict:
        """Summary metrics; see :func:`ehss_gym.core.metrics.summarize`."""
        return summarize(self)

    def units(self) -> dict[str, str]:
        """The unit of each of :meth:`arrays` (U = rad/s velocity, rad position; "-" = dimensionless)."""
        U = UNITS[self.scenario.task]
        m = self.scenario.order
        lift = 1 if self.scenario.task == "velocity" else 0  # U = rad/s^lift

        def deriv(i: int) -> str:  # the unit of the i-th time derivative of the output
            p = i + lift
            return "rad" if p == 0 else ("rad/s" if p == 1 else f"rad/s^{p}")

        out = {"t": "s", "y": U, "y_ref": U, "e": U, "u": "mA", "u_applied": "mA", "u_base": "mA",
               "s": deriv(m - 1), "V": "-", "friction": "N*m", "r": U, "u_applied_min": "mA",
               "u_applied_max": "mA", "theta": "rad", "omega": "rad/s", "p_load": "Pa", "valve_area": "m^2"}
        for i in range(1, m + 1):
            out[f"y_ref_d{i}"] = deriv(i)
        for i in range(1, m):
            out[f"y_est_d{i}"] = deriv(i)
        return out

    def arrays(self) -> dict[str, np.ndarray]:
        """Named arrays for saving (npz / csv)."""
        out = {"t": self.t, "y": self.y, "y_ref": self.y_ref, "e": self.e, "u": self.u, "u_applied": self.u_applied,
               "u_base": self.u_base, "s": self.s, "V": self.V, "friction": self.friction, "r": self.r,
               "u_applied_min": self.u_applied_min, "u_applied_max": self.u_applied_max}
        names = ("theta", "omega", "p_load", "valve_area")
        for i, nm in enumerate(names):
            out[nm] = self.x[:, i]
        for i in range(1, self.scenario.order + 1):
            out[f"y_ref_d{i}"] = self.y_ref_derivs[:, i]
        for i in range(1, self.scenario.order):
            out[f"y_est_d{i}"] = self.y_est_derivs[:, i]
        return out


def init_accumulators(acc: np.ndarray, scenarios: Sequence[Scenario]) -> None:
    """Set the parameters of fresh (zeroed) metrics accumulators (rows of layout M_*), one per scenario."""
    for j, s in enumerate(scenarios):
        acc[j, L.M_LOST_BOUND] = s.lost_track_bound
        acc[j, L.M_T_LOST] = -1.0


def simulate_batch(scenarios: Sequence[Scenario]) -> list[Trajectory]:
    """Simulate many scenarios; those sharing a time grid run in one compiled parallel call."""
    scenarios = list(scenarios)
    if not scenarios:
        return []
    for i, s in enumerate(scenarios):
        if not isinstance(s, Scenario):
            raise ValueError(f"scenarios[{i}] must be a Scenario, got {type(s).__name__}")
    groups: dict[tuple, list[int]] = {}
    for i, s in enumerate(scenarios):
        groups.setdefault(s.grid(), []).append(i)
    out: list[Trajectory | None] = [None] * len(scenarios)
    for (h, substeps, n_steps, log_every), idx in groups.items():
        group = [scenarios[i] for i in idx]
        a = LoopArrays.build(group)
        n_rows = (n_steps + log_every - 1) // log_every
        log = np.zeros((len(group), n_rows, L.N_LOG))
        acc = np.zeros((len(group), L.N_METRICS))
        n_log = np.zeros(len(group), dtype=np.int64)
        init_accumulators(acc, group)
        z = a.z0.copy()
        if len(group) == 1:  # skip the thread pool for a single run
            run_lanes(z, h, substeps, n_steps, log_every, a.plant, a.model, a.ctrl, a.ref, a.events, a.filt, log,
                      acc, n_log)
        else:
            threads = max(1, min(nb.get_num_threads(), len(group)))
            chunk = min(MAX_LANES, -(-len(group) // threads))
            run_batch(z, h, substeps, n_steps, log_every, a.plant, a.model, a.ctrl, a.ref, a.events, a.filt, log,
                      acc, n_log, chunk)
        for j, i in enumerate(idx):  # views, not copies: peak memory stays ~1x the trajectory data
            out[i] = Trajectory(group[j], log[j, :n_log[j]], acc[j])
    return out


def simulate(scenario: Scenario | None = None, **changes) -> Trajectory:
    """Simulate one scenario (default: the paper's velocity run, f_r = 100 Hz, n = 2).

    Keyword arguments change fields of ``scenario``; see :class:`Scenario`.
    """
    sc = scenario or Scenario()
    if changes:
        sc = sc.replace(**changes)
    return simulate_batch([sc])[0]
