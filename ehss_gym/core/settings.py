"""The settings of one closed-loop run (:class:`Scenario`), the one list of loop settings, and the controller row.

A :class:`Scenario` is every setting of a run. Its *physical* fields (:data:`PHYSICAL_FIELDS`: the reference, the
friction events, the plants, the sensor noise, the duration, the valve's unmodelled effects and rated current)
describe the episode; the others are the **loop
settings** (:data:`LOOP_SETTINGS`): the controller and its limits. Every other list of settings derives from this one:
the env's settings (:class:`ehss_gym.envs.config.EnvConfig`), what an exported policy pins, what the evaluation
compares, the command line's flags (``ehss simulate``).

The kernels read the loop settings from the *controller row* (``C_*`` below, one row per run, :func:`ctrl_row`).
**Adding a loop setting** is its field in :class:`Scenario` (its default, its docstring with the unit, its check in
``__post_init__``), its slot here and its line in :func:`ctrl_row`; then the kernel that reads it, and its keyword
argument in :class:`ehss_gym.envs.env.EHSSTrackingEnv` (the env's default is the field's unless
:mod:`ehss_gym.envs.config` says otherwise).

Plain data (no numba): the command line reads it without loading the simulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

import numpy as np

from .filters import butterworth_coefficients
from .layout import MAX_DELAY
from .params import PlantParams
from .registry import ESTIMATORS, LAWS, REFERENCE_FAMILIES, code, entry, names
from .signals import Reference, paper_reference
from .unmodelled import HYSTERESIS_MAX, RATED_CURRENT, THRESHOLD_MAX, Unmodelled
from .validate import check_bool, check_choice, check_even_n, check_finite, check_positive

TASKS = {"velocity": 3, "position": 4}  # task -> relative degree m of its output
UNITS = {"velocity": "rad/s", "position": "rad"}  # task -> unit of its output y (and of e, y_d)
PAPER_FRICTION = ((1.8, 8.0, 10.0),)
LAYER_GAIN_MAX = 100.0  # largest adaptive boundary-layer gain accepted (w_eff = gain * noise std of s)
# Scenario fields an episode (not the controller) sets; the rest are the loop settings.
PHYSICAL_FIELDS = ("reference", "friction", "plant", "model", "noise_std", "seed", "t_end", "log_interval",
                   "unmodelled", "rated_current")

# --- The controller row (one per run): the loop settings as the kernels read them -----------------------
C_ORDER = 0  # relative degree m: 3 velocity, 4 position
C_N = 1  # CLF power factor n (even integer >= 2)
C_SIGMA = 2  # CLF scale sigma [unit of s]
C_SMOOTH = 3  # sign(s) smoothing width w [unit of s]; 0 = plain law
C_LAM0 = 4  # combined-error coefficients lambda_0..lambda_2
C_LAM1 = 5
C_LAM2 = 6
C_ULIM = 7  # current limit [mA]; inf = unlimited
C_SEED = 8  # noise seed (integer stored as float)
C_NOISE_THETA = 9  # measurement noise std per plant state, in its unit
C_NOISE_OMEGA = 10
C_NOISE_PL = 11
C_NOISE_AV = 12
C_OMEGA_MAX = 13  # divergence bound on |x2| [rad/s]
C_P_BOUND = 14  # divergence bound on |x3| as a multiple of P_s
C_BASE = 15  # gain on the law's current: 1 = base law + residual, 0 = residual only (pure RL)
C_EST = 16  # output-derivative estimator: its code in ehss_gym.core.registry.ESTIMATORS
C_LAW = 17  # the CLF law: its code in ehss_gym.core.registry.LAWS
C_LAYER_GAIN = 18  # adaptive boundary layer: w_eff = max(w, gain * noise std of s); 0 = the fixed width w
C_BUMPLESS = 19  # 1: the reference model starts at the measured output (bumpless start); 0: at r(0)
C_REF_ACCEL = 20  # acceleration bound of the reference shaper [rad/s^2] (position task); 0 = r drives the model
C_PDOMAIN = 21  # the model is evaluated at |x3| <= C_PDOMAIN * P_s (of the model); inf = at the measured x3 as is
C_ANALOG = 22  # 1: the estimator's filters and the reference model are continuous, integrated with the plant
C_DOB_GAIN = 23  # disturbance observer: its filter gain per period, 1 - exp(-2 pi dob_hz h) [-]; 0 = off
# The effects the law's model leaves out (ehss_gym.core.unmodelled; physical: the episode's, not a loop setting)
C_THRESHOLD = 24  # servo-valve threshold (dead band) th [mA]; 0 = off
C_HYSTERESIS = 25  # servo-valve hysteresis, the play operator's total width h [mA]; 0 = off
C_DELAY = 26  # sensor delay [control samples] (integer stored as float); 0 = off
C_POS_STEP = 27  # encoder count of the measured x1 [rad]; 0 = not quantised
C_VEL_STEP = 28  # quantisation step of the measured x2 [rad/s]; 0 = not quantised
C_LYAP_KAPPA = 29  # Lyapunov-constrained residual: kappa in [0, 1); -1 = off (the residual as commanded)
# The compensators of the unmodelled effects (ehss_gym.core.compensators), loop settings: 0 = off
C_REF_DELAY = 30  # the law's reference delayed by this many control samples (a float: interpolated); 0 = off
C_INV_THRESHOLD = 31  # the valve inverse's threshold (dead band) th_c [mA]; 0 = none
C_INV_HYSTERESIS = 32  # the valve inverse's hysteresis, its play operator's total width h_c [mA]; 0 = none
# The law's reference shift (an input, not a loop setting: the env's "reference" action writes it every agent step;
# ehss_gym.core.controller.reference_shift): 1 = on; the shift delta [output unit] that drives the reference model's
# copy
C_SHIFT_ON = 33
C_SHIFT = 34
N_CTRL = 35


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
    """One closed-loop run. Every field is validated on construction (a bad value raises ValueError naming it)."""

    task: str = "velocity"
    """the tracking task: "velocity" (output x2, relative degree 3) or "position" (x1, 4)"""
    n: int = 2
    """CLF power factor, an even integer >= 2"""
    fr: float = 100.0
    """combined-error cutoff f_r [Hz] (Table I: 100 or 60)"""
    sigma: float = 1.0
    """CLF scale sigma > 0, in the unit of s; 1 = the paper's law"""
    smoothing: float = 0.0
    """sign(s) smoothing width w >= 0 in the unit of s; 0 = plain law"""
    current_limit: float | None = None
    """|u| limit [mA]; None = unlimited (the paper)"""
    control_period: float = 1e-4
    """controller sample time h [s]"""
    substeps: int = 10
    """RK4 plant steps per control period (>= 1)"""
    t_end: float = 20.0
    """simulated duration [s]"""
    log_interval: float = 1e-3
    """trajectory logging interval [s], rounded to a multiple of h"""
    reference: Reference = field(default_factory=paper_reference)
    """the reference signal r(t) (:mod:`ehss_gym.core.signals`)"""
    friction: tuple = PAPER_FRICTION
    """friction events (amplitude [N*m], start [s], end [s]); default the paper's"""
    plant: PlantParams = field(default_factory=PlantParams)
    """true plant parameters"""
    model: PlantParams | None = None
    """the controller's model of the plant; None = the plant (no mismatch)"""
    noise_std: tuple = (0.0, 0.0, 0.0, 0.0)
    """measurement noise std of (x1 [rad], x2 [rad/s], x3 [Pa], x4 [m^2])"""
    unmodelled: Unmodelled = field(default_factory=Unmodelled)
    """the servo valve's threshold and hysteresis, the sensor delay and the encoder quantisation, which the law's
    model leaves out (:class:`ehss_gym.core.unmodelled.Unmodelled`); default all off. See docs/MODEL.md, "Unmodelled
    valve and sensors"."""
    seed: int = 0
    """noise seed (integer >= 0)"""
    ref_model_hz: float = 20.0
    """reference-model cutoff [Hz] (Table I: 20)"""
    estimator_hz: float = 1000.0
    """cutoff of the paper's state-variable filter (SVF) [Hz] (Table I: 1000)"""
    estimator: str = "foh"
    """how the output derivatives are estimated (:data:`ehss_gym.core.registry.ESTIMATORS`): the paper's SVF, its
    reference model run the same way, as "foh" (first-order hold, O(h^2) to the analog filters), "zoh" (zero-order
    hold, the top derivative from the current sample: biased by O(h)) or "analog" (the continuous filters integrated
    with the plant's RK4; the reference); without differentiating the output (reference model "foh"): "state" (the
    model's Lie derivatives of the measured state) or "eso" (an extended-state observer of the velocity and a lumped
    disturbance acceleration, bandwidth ``observer_hz``). See docs/MODEL.md, "Digital filters" and "Estimators"."""
    observer_hz: float = 200.0
    """error bandwidth of the "eso" observer [Hz] (unused by the other estimators)"""
    law: str = "sontag"
    """the CLF law, a row of :data:`ehss_gym.core.registry.LAWS`: "sontag" (Sontag's universal formula, the paper's),
    "lin-sontag" (Lin & Sontag's formula for currents bounded by ``current_limit``, which must then be finite), ...
    See docs/MODEL.md, "Laws"."""
    layer_gain: float = 0.0
    """adaptive boundary layer: the width of the smooth sign is max(smoothing, layer_gain * the running noise std of
    s), in [0, LAYER_GAIN_MAX = 100]; 0 = the fixed width ``smoothing``"""
    bumpless: bool = False
    """the reference model starts at the measured output (and the estimated derivatives) instead of at its steady
    state for r(0): a bumpless start, as servo drives do"""
    ref_accel: float = 0.0
    """position task: acceleration bound a [rad/s^2] of the reference shaper, which turns r into a reference the valve
    can follow (|p''| <= a; r itself wherever |r''| <= a/2) ahead of the reference model; 0 = none (the paper's: r
    drives the reference model). See docs/MODEL.md, "Reference shaper"."""
    pressure_domain: float | None = None
    """the controller evaluates its model (Lie derivatives, F, G) at the measured state with the load pressure
    projected into |x3| <= pressure_domain * P_s of the model, in (0, 1]; None = at the measured x3 as is (the paper's
    loop; the env's default is 0.95). Outside it a model with a lower P_s than the plant's reverses the sign of G. See
    docs/MODEL.md, "The model's pressure domain"."""
    dob_hz: float = 0.0
    """bandwidth f_d [Hz] of the disturbance observer on the combined error: it estimates the lumped disturbance d of
    s' = psi + G u + d (friction, model mismatch) with a first-order filter of cutoff f_d and adds -d_hat/G (clipped
    to +-current_limit) to the law's current; in [0, 1/(2 control_period)) (below the Nyquist frequency of the control
    period); 0 = off (the paper's loop). See docs/MODEL.md, "Disturbance observer"."""
    lyapunov_kappa: float | None = None
    """Lyapunov-constrained residual: the residual current is clipped, each control period, to the nearest value with
    which the model's V' = a + b u of the law's CLF is at most kappa times the law's own decrease (Sontag's
    -sqrt(a^2 + b^4) for the plain law), wherever the law makes V decrease; kappa in [0, 1); None = off (the residual
    as commanded). See docs/MODEL.md, "Lyapunov-constrained residual"."""
    reference_delay: float = 0.0
    """delay compensation: the law tracks the reference model's output y_d and its derivatives of ``reference_delay``
    control samples earlier (interpolated linearly between samples), in [0, MAX_DELAY = 8]; 0 = off. With a sensor
    delay of d samples (``unmodelled.delay``) the law drives the measured output, d samples old, onto today's y_d, so
    the true output leads y_d; against y_d of d samples before, the true output tracks y_d (the metrics still measure
    y - y_d). See docs/MODEL.md, "Compensating the unmodelled valve and sensors"."""
    inverse_threshold: float = 0.0
    """the valve inverse's threshold [percent of ``rated_current``], in [0, THRESHOLD_MAX = 10]: the
    commanded current is pre-compensated by the inverse of a dead band of this width and a play operator of width
    ``inverse_hysteresis`` (the valve model of ``unmodelled``), so that such a valve puts out the command itself;
    0 = none. See docs/MODEL.md, "Compensating the unmodelled valve and sensors"."""
    inverse_hysteresis: float = 0.0
    """the valve inverse's hysteresis [percent of ``rated_current``], in [0, HYSTERESIS_MAX = 30]: the total
    width of the play operator it inverts (``inverse_threshold``); 0 = none"""
    rated_current: float = RATED_CURRENT
    """the servo valve's rated current [mA] (> 0; Table I's valve: 10 mA): the valve inverse's sizes are percent of
    it, and the unmodelled effects drawn for the episode (:func:`ehss_gym.core.scenarios.sample_scenario`) size the
    valve's threshold and hysteresis on it; the env sets it to its rig's"""
    omega_max: float = 1e3
    """divergence bound on |x2| [rad/s]"""
    pressure_bound: float = 1.5
    """divergence bound on |x3| as a multiple of P_s"""
    lost_track: float | None = 1.0
    """lost-track bound as a multiple of the reference's amplitude (> 0; None = never flagged): the run has lost track
    once the RMS of e over a sliding window (exponential, time constant ``LOST_TRACK_WINDOW`` = 0.1 s, from t = 0.2 s
    on) exceeds ``lost_track`` * ``reference.amplitude`` (the amplitude's offset if it is 0; off if both are 0). Only
    reported (``metrics()["lost_track"]``, ``t_lost_track``): the run goes on. See :mod:`ehss_gym.core.metrics`."""

    def __post_init__(self):
        if self.task not in TASKS:
            raise ValueError(f"task must be one of {sorted(TASKS)}, got {self.task!r}")
        check_choice("estimator", self.estimator, names(ESTIMATORS))
        check_choice("law", self.law, names(LAWS))
        object.__setattr__(self, "n", check_even_n(self.n))
        for name in ("fr", "sigma", "control_period", "t_end", "log_interval", "ref_model_hz", "estimator_hz",
                     "observer_hz", "omega_max", "pressure_bound"):
            object.__setattr__(self, name, check_positive(name, getattr(self, name)))
        object.__setattr__(self, "smoothing", check_finite("smoothing", self.smoothing, low=0.0))
        object.__setattr__(self, "layer_gain", check_finite("layer_gain", self.layer_gain, low=0.0,
                                                            high=LAYER_GAIN_MAX))
        object.__setattr__(self, "bumpless", check_bool("bumpless", self.bumpless))
        object.__setattr__(self, "ref_accel", check_finite("ref_accel", self.ref_accel, low=0.0))
        # the observer's filter runs once per period: its cutoff must lie below the period's Nyquist frequency
        nyquist = 0.5 / self.control_period
        try:
            dob = check_finite("dob_hz", self.dob_hz, low=0.0, high=nyquist, high_open=True)
        except ValueError:
            raise ValueError(f"dob_hz must be a finite number in [0, {nyquist:g}) Hz: 0 (off) or a cutoff below the "
                             f"Nyquist frequency 1/(2 control_period) of the control period {self.control_period:g} s, "
                             f"got {self.dob_hz!r}") from None
        object.__setattr__(self, "dob_hz", dob)
        if self.lyapunov_kappa is not None:
            object.__setattr__(self, "lyapunov_kappa", check_finite("lyapunov_kappa", self.lyapunov_kappa, low=0.0,
                                                                    high=1.0, high_open=True))
        self._check_compensators()
        if self.pressure_domain is not None:
            object.__setattr__(self, "pressure_domain", check_finite("pressure_domain", self.pressure_domain, low=0.0,
                                                                     high=1.0, low_open=True))
        if self.ref_accel > 0.0 and (self.task != "position" or entry(ESTIMATORS, self.estimator).analog):
            raise ValueError(f"ref_accel shapes the position task's reference for a digital reference model: it must "
                             f"be 0 for task {self.task!r} with estimator {self.estimator!r}, got {self.ref_accel:g}")
        if self.current_limit is not None:
            object.__setattr__(self, "current_limit", check_positive("current_limit", self.current_limit))
        elif entry(LAWS, self.law).needs_limit:
            raise ValueError(f"law {self.law!r} bounds the current by current_limit, which must then be a finite "
                             "number > 0 (mA), got None")
        if isinstance(self.substeps, bool) or not float(self.substeps).is_integer() or self.substeps < 1:
            raise ValueError(f"substeps must be an integer >= 1, got {self.substeps!r}")
        object.__setattr__(self, "substeps", int(self.substeps))
        if self.t_end < self.control_period:
            raise ValueError(f"t_end must be >= control_period ({self.control_period:g} s), got {self.t_end:g}")
        self._check_episode()

    def _check_compensators(self) -> None:
        """The compensators' checks (reference delay, valve inverse)."""
        object.__setattr__(self, "reference_delay", check_finite("reference_delay (control samples)",
                                                                 self.reference_delay, low=0.0, high=MAX_DELAY))
        object.__setattr__(self, "inverse_threshold", check_finite("inverse_threshold (% of rated current)",
                                                                   self.inverse_threshold, low=0.0, high=THRESHOLD_MAX))
        object.__setattr__(self, "inverse_hysteresis", check_finite(
            "inverse_hysteresis (% of rated current)", self.inverse_hysteresis, low=0.0, high=HYSTERESIS_MAX))
        object.__setattr__(self, "rated_current", check_finite("rated_current (mA)", self.rated_current, low=0.0,
                                                               low_open=True))

    def _check_episode(self) -> None:
        """The physical fields' checks."""
        object.__setattr__(self, "friction", check_friction(self.friction))
        if len(self.noise_std) != 4:
            raise ValueError(f"noise_std must have 4 entries (x1..x4), got {len(self.noise_std)}")
        object.__setattr__(self, "noise_std", tuple(check_finite(f"noise_std[{i}]", v, low=0.0)
                                                    for i, v in enumerate(self.noise_std)))
        if isinstance(self.seed, bool) or not float(self.seed).is_integer() or not 0 <= self.seed < 2**52:
            raise ValueError(f"seed must be an integer in [0, 2^52), got {self.seed!r}")
        if not isinstance(self.reference, Reference):
            raise ValueError(f"reference must be an ehss_gym.core.signals.Reference "
                             f"({', '.join(names(REFERENCE_FAMILIES))}), got {type(self.reference).__name__}")
        for name in ("plant", "model"):
            v = getattr(self, name)
            if v is not None and not isinstance(v, PlantParams):
                raise ValueError(f"{name} must be a PlantParams (use make_plant_params), got {type(v).__name__}")
        if self.lost_track is not None:
            object.__setattr__(self, "lost_track", check_positive("lost_track", self.lost_track))
        if not isinstance(self.unmodelled, Unmodelled):
            raise ValueError(f"unmodelled must be an ehss_gym.core.unmodelled.Unmodelled, got "
                             f"{type(self.unmodelled).__name__}")
        um = self.unmodelled  # one valve: its threshold and hysteresis are percent of the scenario's rated current
        if (um.threshold or um.hysteresis) and um.rated_current != self.rated_current:
            raise ValueError(f"unmodelled.rated_current ({um.rated_current:g} mA) must be the scenario's "
                             f"rated_current ({self.rated_current:g} mA, the rig's): build the valve as "
                             f"Unmodelled(..., rated_current={self.rated_current:g})")

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


# The loop settings: every Scenario field but the physical ones, in field order.
LOOP_SETTINGS = tuple(f.name for f in fields(Scenario) if f.name not in PHYSICAL_FIELDS)


def lambdas(order: int, fr: float) -> np.ndarray:
    """Combined-error coefficients lambda_0..lambda_{m-2}: Butterworth of order m-1 at f_r [Hz]."""
    return butterworth_coefficients(order - 1, fr)


def ctrl_row(sc: Scenario) -> np.ndarray:
    """The controller row (``C_*``) of a scenario."""
    row = np.zeros(N_CTRL)
    row[C_ORDER] = sc.order
    row[C_N] = sc.n
    row[C_SIGMA] = sc.sigma
    row[C_SMOOTH] = sc.smoothing
    lam = lambdas(sc.order, sc.fr)
    row[C_LAM0:C_LAM0 + len(lam)] = lam
    row[C_ULIM] = math.inf if sc.current_limit is None else sc.current_limit
    row[C_SEED] = sc.seed
    row[C_NOISE_THETA:C_NOISE_THETA + 4] = sc.noise_std
    row[C_OMEGA_MAX] = sc.omega_max
    row[C_P_BOUND] = sc.pressure_bound
    row[C_BASE] = 1.0
    row[C_EST] = code(ESTIMATORS, sc.estimator)
    row[C_ANALOG] = 1.0 if entry(ESTIMATORS, sc.estimator).analog else 0.0
    row[C_LAW] = code(LAWS, sc.law)
    row[C_LAYER_GAIN] = sc.layer_gain
    row[C_BUMPLESS] = 1.0 if sc.bumpless else 0.0
    row[C_REF_ACCEL] = sc.ref_accel
    row[C_PDOMAIN] = math.inf if sc.pressure_domain is None else sc.pressure_domain
    row[C_DOB_GAIN] = dob_gain(sc.dob_hz, sc.control_period)
    unmodelled_slots(sc.unmodelled, row)
    row[C_LYAP_KAPPA] = -1.0 if sc.lyapunov_kappa is None else sc.lyapunov_kappa
    row[C_REF_DELAY] = sc.reference_delay
    row[C_INV_THRESHOLD] = sc.inverse_threshold * sc.rated_current / 100.0
    row[C_INV_HYSTERESIS] = sc.inverse_hysteresis * sc.rated_current / 100.0
    return row


def unmodelled_slots(um: Unmodelled, row: np.ndarray) -> None:
    """Write the unmodelled effects ``um`` into their slots of controller row ``row`` (C_THRESHOLD .. C_VEL_STEP)."""
    row[C_THRESHOLD] = um.threshold_current
    row[C_HYSTERESIS] = um.hysteresis_current
    row[C_DELAY] = um.delay
    row[C_POS_STEP] = um.position_step
    row[C_VEL_STEP] = um.velocity_step


def dob_gain(dob_hz: float, control_period: float) -> float:
    """The disturbance observer's filter gain per period, alpha = 1 - exp(-2 pi f_d h) [-] (0 = off).

    Args:
        dob_hz: its cutoff f_d [Hz] (0 = off).
        control_period: the control period h [s].
    """
    return -math.expm1(-2.0 * math.pi * dob_hz * control_period)


__all__ = ["Scenario", "TASKS", "UNITS", "PAPER_FRICTION", "LAYER_GAIN_MAX", "PHYSICAL_FIELDS", "LOOP_SETTINGS",
           "check_friction", "lambdas", "ctrl_row", "unmodelled_slots", "dob_gain", "N_CTRL"]
