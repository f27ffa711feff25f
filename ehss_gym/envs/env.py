"""Gymnasium environment ``EHSSTracking-v0``: the EHSS servo loop with a residual (or direct) RL action.

The env is a thin adapter over the compiled core (:func:`ehss_gym.core.loop.lanes_period`): it holds the
state and the RNG, and one compiled call (:func:`ehss_gym.envs.kernels.advance`) advances ``agent_period``
control periods for B lanes. The single env uses B = 1, the vector env (:mod:`ehss_gym.envs.vector`) B = N,
so both run the same code and give identical results for the same seeds.

All defaults live in :data:`ehss_gym.envs.config.DEFAULTS`; see :class:`EHSSTrackingEnv` for the specification.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ehss_gym.core.layout import I_E, I_R, I_T, I_TF, I_UAPP, I_UBASE, I_URES, I_YD, I_YE, M_LOST
from ehss_gym.core.settings import Scenario

from .buffers import F_REW, F_STATS, S_N, S_UMAX, S_UMIN
from .config import DEFAULTS, NONE_IS_A_VALUE, RATED, EnvConfig, warn_untuned
from .lanes import Lanes, step_info
from .observation import OBS_BOUND

# what the dashboard records per agent step (at its last control sample; u_min/u_max over its control periods)
HIST_COLUMNS = ("t", "y", "y_ref", "e", "u_applied", "u_base", "u_residual", "friction", "r", "u_min", "u_max")


def parse_action_scalar(action) -> float:
    """A single action value from an array-like of one element; NaN raises ValueError."""
    if type(action) is np.ndarray and action.shape == (1,):
        v = float(action[0])
    else:
        a = np.asarray(action, dtype=np.float64)
        if a.size != 1:
            raise ValueError(f"action must have shape (1,), got shape {a.shape}")
        v = float(a.reshape(-1)[0])
    if v != v:
        raise ValueError("action is NaN; actions must be numbers in [-1, 1] (out-of-range values are clipped)")
    return v


def parse_action_vector(action, k: int) -> tuple[np.ndarray, bool]:
    """An action of ``k`` values from an array-like of that size, clipped to [-1, 1]: (values (1, k) float64, any
    was out of range); NaN or a wrong size raises ValueError."""
    a = np.asarray(action, dtype=np.float64)
    if a.size != k:
        raise ValueError(f"action must have shape ({k},), got shape {a.shape}")
    a = a.reshape(1, k)
    if np.isnan(a).any():
        raise ValueError("action is NaN; actions must be numbers in [-1, 1] (out-of-range values are clipped)")
    clipped = bool((np.abs(a) > 1.0).any())
    return np.clip(a, -1.0, 1.0), clipped


class EHSSTrackingEnv(gym.Env):
    r"""EHSS servo tracking with a Sontag/CLF base law and a residual (or direct) RL action.

    **Plant and loop** (Mintsa et al., Eq. 1; see :mod:`ehss_gym.core.physics`)::

        x1' = x2                                    angular position [rad]
        x2' = (d_m x3 - B x2 - T_f) / J             angular velocity [rad/s]
        x3' = (4 beta / V_m)(Q(x3, x4) - d_m x2 - c_sm x3)   load pressure [Pa]
        x4' = (K u - x4) / tau                      valve opening area [m^2]

    with Coulomb friction events T_f (never observed). The output y is x2 (task "velocity", relative
    degree m = 3) or x1 ("position", m = 4). Every control period h (``control_period``) the digital
    controller samples (with sensor noise), forms the tracking errors e = y - y_d and their estimates
    (``estimator``: per task, the defaults table below; the paper's state-variable filter is "foh"),
    the combined error s = e^(m-1) + lambda_{m-2} e^(m-2) + ... and the CLF current on
    V = (s/sigma)^n / n (:mod:`ehss_gym.core.laws`; ``law``: Sontag's formula by default)::

        u_base = -psi/G - sgn_w(s) sign(G) hypot(psi/G, |s/sigma|^(n-1) |G| / sigma)

    (y_d: the reference model's output, started at the measured output or at its steady state for r(0),
    ``bumpless``; position: driven by the reference shaper's feasible version of r when ``ref_accel`` > 0.)

    and applies, held over the period (ZOH, ``substeps`` RK4 steps)::

        residual mode:  u = clip(u_base + residual_scale * a, -current_limit, current_limit)
        direct mode:    u = clip(residual_scale * a, -current_limit, current_limit)

    The agent acts every ``agent_period`` control periods; its action a is held in between.

    **Action** ``Box(-1, 1, (k,), float32)``, with the ``action`` setting (:mod:`ehss_gym.envs.actions`; the
    bounds' defaults and their measurement: docs/ENV.md, "Action modes"):

    ===========  ===  ==========================================================================================
    action       k    what a does (R, D = ``action_bound``; h the control period)
    ===========  ===  ==========================================================================================
    current      1    the residual current ``residual_scale * a`` [mA], held over the agent step (the default;
                      direct mode: the whole current; ``residual_scale`` defaults to ``current_limit``)
    rate         1    the residual's rate of change a R / 10 ms [mA/s]; the residual r is integrated every control
                      period and clipped to +-R [mA]: continuous, at most R / 10 ms
    filtered     1    the residual is a first-order filter (time constant 10 ms) of R a [mA]: |r| <= R
    reference    1    the law's reference shifted by delta = D a [output unit] through a copy of the reference model,
                      so its output and derivatives stay consistent: the law tracks y_d + Delta (the reward and the
                      metrics still measure against y_d); delta ~ -d h y_d' compensates a sensor delay of d samples
    schedule     2-3  gain scheduling at the agent rate: a_0 scales the boundary layer's width (``smoothing`` and
                      ``layer_gain``) within [0.1, 1000], a_1 sigma within [0.1, 10], a_2 (``dob_hz`` > 0 only) the
                      observer's bandwidth within [0.1, 10]; factor hi^a for a >= 0, lo^(-a) for a < 0
    ===========  ===  ==========================================================================================

    In every mode a = 0 throughout is the base law, bit for bit. Out-of-range values are clipped to [-1, 1] and
    counted (``info["clipped"]`` this step, ``info["n_clipped"]`` in the episode). A NaN action raises ValueError.

    **Observation** ``Box(-10, 10, (D,), float32)``, D = 15 (velocity) or 17 (position). Each entry
    is ``clip(sign(v) log(1 + |v|), -10, 10)`` with ``v = x / scale`` (only ``last_action`` is linear):
    about unit size in normal tracking, compressed in transients, never NaN. Values are what the
    controller sees at its next sample, at the end of the step (t = info["t"] + control_period, with
    that sample's sensor noise), so the agent acts on the freshest measurement; ``u_applied`` and
    ``last_action`` are those of the last period run (0 after reset). e^(i) are the estimator's
    values. Decode with :func:`decode_observation`. Output unit U = rad/s (velocity) or rad
    (position); w_r = 2 pi f_r; P_s and K are the controller's model's (of the env's ``plant``).

    =============================  ============================  ===============================
    entries                        quantity                      scale
    =============================  ============================  ===============================
    e, e_d1, .., e_d(m-1)          e^(i) [U/s^i]                 error_scale * w_r^i
    s                              combined error [U/s^(m-1)]    error_scale * w_r^(m-1)
    y_ref, y_ref_d1, .., y_ref_dm  y_d^(i) [U/s^i]               1 * (10 rad/s)^i
    x1, x2                         measured x1 [rad], x2 [rad/s] 1
    x3                             measured x3 [Pa]              P_s (Table I: 9e6 Pa)
    x4                             measured x4 [m^2]             K * 0.1 mA (Table I: 8e-8 m^2)
    u_applied                      applied current [mA]          0.1 mA
    u_base                         Sontag current [mA] (also     0.1 mA
                                   computed, not applied, in
                                   direct mode)
    last_action                    previous a [-] (linear; in    1
                                   the rate and filtered modes
                                   the residual over
                                   residual_scale)
    =============================  ============================  ===============================

    An action mode but "current" appends its last action (``action``, or ``action_width``, ``action_sigma``,
    ``action_observer`` for the schedule; [-], linear) and what it moves: ``ref_shift`` (the reference shift Delta at
    the next sample over D, linear) or ``width`` (the boundary-layer width in use, scaled as s).

    **Reward**, per agent step over its control periods k (e_k the sampled error)::

        r = w_track / (1 + mean_k(e_k^2) / error_scale^2) - w_effort a^2 - w_rate ((a - a_prev)/2)^2
            - w_tv |a - a_prev|/2 - w_tv_u mean_k(|u_k - u_(k-1)|) / residual_scale
            - w_divergence [diverged this step]   (the tracking term is dropped on divergence)

    with a the clipped action and u_k the applied current [mA]. w_tv is an L1 rate penalty on the
    residual's own steps (the quadratic rate term hardly sees small jitter); w_tv_u charges the whole
    control total variation (the evaluation's TV, base-law switching included: a residual that tracks
    more tightly can make the base law switch more often without any step of its own). Range:
    [-(w_effort + w_rate + w_tv + 2 w_tv_u current_limit/residual_scale + w_divergence), w_track]; with
    the default weights (1, 0.05, 0.05, 0, 0, 10): [-10.1, 1].

    The **class reward** (weights ``class`` and ``saturation``, 0 by default) is the evaluation's ruler spread over
    the steps: each step pays w_class times the step's change of the episode's running log figure against the base
    law (the tracking window's sum e^2 and IAE, the disturbance windows' IAE and peak |e|, the control TV and sum u^2,
    on the true error as the ruler has them, each against the base law's total on the same episode pro rata,
    offset by 1 % of it; weighted as in the overall log figure), and w_saturation times the step's share of periods
    at the limit. Over an episode it sums to minus w_class times the episode's overall log figure (0 for the base
    law; :func:`ehss_gym.envs.kernels.class_reward`). The base law's totals come from its run of the episode at reset
    (one simulation more per episode).

    The **physical reward** (weight ``physical``, 0 by default) is the ruler per agent step, with no history: each step
    pays, for each class c of the episode (tracking and disturbance where their windows have samples, effort always; C
    of them), its metric pair over the step's own control samples, each over its scale s = its physical floor
    (:mod:`ehss_gym.core.resolution`: e_f = 1e-4 rad/s or 2 pi / 2^20 rad for an error, tv_f = 1.59 mA/s, u_f = 0.05 mA)
    plus the base law's level over the episode (from its run at reset, as the class reward's)::

        r = -w_physical K / C sum_c (n_c / N_c) phi_c
        phi_tracking    = 1/4 log(1 + mean e_t^2 / s) + 1/2 log(1 + mean |e_t| / s)      s = e_f^2 + B, e_f + B
        phi_disturbance = 1/2 log(1 + max |e_t| / s) + 1/2 log(1 + mean |e_t| / s)       s = e_f + B
        phi_effort      = 1/2 log(1 + TV / (n h) / s) + 1/4 log(1 + mean u^2 / s)        s = tv_f + B, u_f^2 + B

    with e_t the true error over the step's n_c samples in class c's window (the effort class: all n), B the base
    law's value of the same metric over the episode's window, N_c the episode's samples in the window, K its agent
    steps, TV the applied current's total variation over the step [mA]. Below its scale a metric costs about its ratio
    to it (so the episode's sum follows the metric's mean, as the ruler's RMSE, IAE and TV do), far above it
    logarithmically (bounded, as the ruler is); a difference below a floor costs next to nothing. Over an episode it
    ranks fixed policies as the ruler's overall figure does (docs/RL.md, "Physical reward", with the measured agreement;
    :func:`ehss_gym.envs.kernels.physical_reward`).

    **Termination and truncation.** Divergence (non-finite value, |x2| > omega_max, |x3| > 1.5 P_s;
    see :mod:`ehss_gym.core.sim`) ends the episode with ``terminated=True``, ``info["diverged"]=True`` and
    ``info["divergence_reason"]``; the observation and info show the last finite state. With
    ``terminate_on_lost_track=True`` an episode that has lost track (``lost_track``) ends too, with
    ``terminated=True``, ``info["lost_track"]=True`` and ``info["diverged"]=False``. The episode
    ends after floor(t_end / (agent_period h)) agent steps with ``truncated=True``. At either end,
    ``info["metrics"]`` holds the core metrics summary (:func:`ehss_gym.core.metrics.summarize_acc`, at the
    full control rate; recovery times from the agent-rate error log).

    **info** each step (values at the last control sample of the step): t [s], e, s, V, u_base,
    u_residual, u_applied [mA], saturated (limit active at that sample), sat_fraction (share of this
    step's control periods at the limit), friction_torque [N*m], clipped, n_clipped, diverged, lost_track
    (the episode has lost track at or before this step; see ``lost_track``).
    ``reset`` returns the drawn scenario (``info["scenario"]``, ``info["scenario_name"]``, and
    ``info["scenario_seed"]`` for random draws).

    **Defaults** per task (generated from :data:`DEFAULTS` by ``python -m ehss_gym.envs.defaults --write``, the
    same table as README.md and docs/ENV.md; U = the output unit):

    <!-- env-defaults:start -->

    | setting | velocity | position | unit |
    |---|---|---|---|
    | `n` | 2 | 2 | - |
    | `fr` | 99.1614 | 54.4497 | Hz |
    | `sigma` | 8.058422e4 | 1.333521e5 | unit of s |
    | `smoothing` | 107.461 | 39.2419 | unit of s |
    | `current_limit` | 10 | 10 | mA (None: unlimited; default: the plant's rated current) |
    | `control_period` | 5e-5 | 5e-5 | s |
    | `substeps` | 1 | 1 | RK4 steps per period |
    | `estimator_hz` | 1000 | 1000 | Hz |
    | `estimator` | `"foh"` | `"eso"` |  |
    | `observer_hz` | 200 | 1000 | Hz |
    | `law` | `"sontag"` | `"sontag"` |  |
    | `layer_gain` | 11.7726 | 7.37473 | - |
    | `bumpless` | True | True |  |
    | `ref_accel` | 0 | 100 | rad/s^2 (0: none) |
    | `pressure_domain` | 0.95 | 0.95 | x P_s |
    | `dob_hz` | 0 | 0 | Hz (0: off) |
    | `lyapunov_kappa` | None | None | - (None: off) |
    | `reference_delay` | 0 | 0 | control samples (0: off) |
    | `inverse_threshold` | 0 | 0 | % of rated current (0: none) |
    | `inverse_hysteresis` | 0 | 0 | % of rated current (0: none) |
    | `lost_track` | 1 | 1 | x reference amplitude |
    | `plant` | Table I | Table I | TOML file, dict, PlantParams or Rig |
    | `law_settings` | None | None | JSON file or dict (None: Table I's tuning) |
    | `mode` | `"residual"` | `"residual"` |  |
    | `residual_scale` | 10 | 10 | mA |
    | `agent_period` | 5 | 5 | control periods |
    | `scenario` | `"random"` | `"random"` |  |
    | `reward_weights["track"]` | 1 | 1 | - |
    | `reward_weights["effort"]` | 0.05 | 0.05 | - |
    | `reward_weights["rate"]` | 0.05 | 0.05 | - |
    | `reward_weights["tv"]` | 0 | 0 | - |
    | `reward_weights["tv_u"]` | 0 | 0 | - |
    | `reward_weights["divergence"]` | 10 | 10 | - |
    | `reward_weights["class"]` | 0 | 0 | - |
    | `reward_weights["saturation"]` | 0 | 0 | - |
    | `reward_weights["physical"]` | 0 | 0 | - |
    | `error_scale` | 0.01 | 0.01 | U |
    | `episode_seconds` | None | None | s (None: 2 s random, 20 s paper) |
    | `terminate_on_lost_track` | False | False |  |
    | `unmodelled_effects` | False | False |  |
    | `unmodelled_share` | 1 | 1 | - (share of episodes) |
    | `memory_tau` | None | None | s (None: no memory features) |
    | `action` | `"current"` | `"current"` |  |
    | `action_bound` | None | None | the action's unit (None: none) |
    | `sigma` with `law="lin-sontag"` | 3e6 | 1e7 | unit of s |
    | `action_bound` with `action="rate"` | 0.4 | 4 | mA |
    | `action_bound` with `action="filtered"` | 0.4 | 4 | mA |
    | `action_bound` with `action="reference"` | 8e-4 | 3e-4 | U |
    | `action_bound` with `action="reference-schedule"` | 8e-4 | 3e-4 | U |
    | `fr` with `n=4` | 127.561 | 60 | Hz |
    | `sigma` with `n=4` | 1.654817e5 | 1.433013e4 | unit of s |
    | `smoothing` with `n=4` | 220.673 | 165.482 | unit of s |
    | `layer_gain` with `n=4` | 4.96445 | 3.59126 | - |
    | `fr` with `n=6` | 129.876 | 53.4029 | Hz |
    | `sigma` with `n=6` | 1.654817e5 | 1.074608e4 | unit of s |
    | `smoothing` with `n=6` | 220.673 | 42.1697 | unit of s |
    | `layer_gain` with `n=6` | 4.96445 | 4.96445 | - |

    <!-- env-defaults:end -->

    Args (keyword only; unknown names or bad values raise ValueError listing what is valid; defaults in the
    table above):
        task: "velocity" (the default) or "position" (see docs/ENV.md for what each task's base law achieves).
        plant: the rig (:func:`ehss_gym.core.rig.as_rig`): a TOML plant file's path (a [plant] table of the model's
            parameters or a [datasheet] table; docs "Your own servo"), a shipped plant's name ("table1",
            "compact140"), a dict of the same content, a :class:`~ehss_gym.core.params.PlantParams` or a
            :class:`~ehss_gym.core.rig.Rig`; None = Table I. "paper" episodes run on it, "random" episodes draw their
            mismatch around it, and the controller's model is the file's (its [model] table, else the plant's
            nominal parameters); its rated current is the default current limit. A bad file or value raises
            ValueError naming the key, its unit and range.
        law_settings: the CLF law's settings tuned for the plant (:mod:`ehss_gym.envs.law_table`): the
            ``law_settings.json`` that ``ehss baselines --plant FILE`` writes (a path, its content as a dict, or a
            :class:`~ehss_gym.envs.law_table.LawTable`); the env takes its row for n for every law setting (sigma,
            fr, smoothing, layer_gain) not given. None: the built-in rows, tuned for Table I (a
            :class:`~ehss_gym.envs.config.PlantWarning` says so on another plant).
        n: CLF power factor, even >= 2.
        fr: combined-error cutoff f_r [Hz].
        sigma: CLF scale [unit of s] (1 = the paper's law).
        smoothing: sign(s) smoothing width [unit of s], >= 0.
        mode: "residual" or "direct" (pure RL: no base current applied).
        residual_scale: current of a unit action [mA] (None: current_limit, or 10 if unlimited).
        agent_period: control periods per agent step, >= 1.
        control_period: h [s], in [1e-7, 1e-2].
        substeps: RK4 plant steps per control period, >= 1.
        current_limit: |u| limit [mA] or None = unlimited; "rated" (the default): the plant's rated current (Table I's
            loop: 10 mA).
        estimator_hz: cutoff of the paper's state-variable filter (SVF) [Hz] (the paper's: 1000).
        estimator: how the output derivatives are estimated, a row of :data:`ehss_gym.core.registry.ESTIMATORS`:
            "foh" (the paper's SVF, first-order-hold discretisation,
            O(h^2) to its continuous filters), "zoh" (the first implementation's zero-order hold, biased by O(h)),
            "analog" (continuous filters integrated with the plant), "state" (the model's Lie derivatives of the
            measured state) or "eso" (an extended-state observer of the velocity and a lumped disturbance
            acceleration). See docs/MODEL.md, "Digital filters" and "Estimators".
        observer_hz: error bandwidth of the "eso" observer [Hz] (unused by the other estimators).
        law: the CLF law, a row of :data:`ehss_gym.core.registry.LAWS` ("sontag": Sontag's universal formula,
            the paper's; "lin-sontag": Lin & Sontag's formula for controls bounded by current_limit). Without
            ``sigma`` each law gets its own default sigma, where the env has one (:attr:`TaskDefaults.sigma_by_law`;
            else the task's). See docs/MODEL.md, "Laws".
        layer_gain: adaptive boundary layer: width max(smoothing, layer_gain * running noise std of s), in
            [0, 100] (0: the fixed width ``smoothing``).
        bumpless: the reference model starts at the measured output (and the estimated derivatives) instead of at
            its steady state for r(0).
        ref_accel: position task: the reference shaper's acceleration bound [rad/s^2], 0 = none (velocity: 0).
            See docs/MODEL.md, "Reference shaper".
        pressure_domain: the controller evaluates its model at |x3| <= pressure_domain * P_s (None = at the
            measured pressure as is, as in the legacy loop).
        dob_hz: cutoff f_d [Hz] of the disturbance observer on the combined error, in [0, 1/(2 control_period)):
            it estimates the lumped disturbance d of s' = psi + G u + d (friction, model mismatch) and adds
            -d_hat/G, clipped to the current limit, to the base current (0: off; the scripted policy ``dob-n<k>``
            turns it on). See docs/MODEL.md, "Disturbance observer".
        lyapunov_kappa: the Lyapunov-constrained residual: each control period the residual is clipped to the
            nearest current with which the model's V' of the law's CLF is at most kappa times the law's own decrease
            (Sontag's -sqrt(a^2 + b^4) for the plain law), wherever the law makes V decrease; kappa in [0, 1), None
            = off. ``info["metrics"]["v_model_decrease"]`` is the episode's share of control periods with the model's
            V' < 0 (or s = 0, V at its minimum). See docs/MODEL.md, "Lyapunov-constrained residual".
        reference_delay: delay compensation [control samples], in [0, 8]: the law tracks the reference model's output
            and its derivatives of that many samples earlier (interpolated between samples), so that with a sensor
            delay of as many samples the true output tracks y_d instead of leading it; 0 = off. See docs/MODEL.md,
            "Compensating the unmodelled valve and sensors".
        inverse_threshold: the valve inverse's dead band [% of the rig's rated current], in [0, 10]: the
            commanded current (law plus residual) passes through the inverse of a valve dead band of this width and
            a play operator of width ``inverse_hysteresis`` before the current limit, so that such a valve puts out
            the command; 0 = none (both 0: off).
        inverse_hysteresis: the valve inverse's play operator's total width [% of rated current], in [0, 30]; 0 = none.
        scenario: "random" (the training distribution of :mod:`ehss_gym.core.scenarios`), "paper",
            or a pinned :class:`ehss_gym.Scenario` whose controller fields equal this env's
            (``env.unwrapped.scenario_template.replace(...)``). ``reset(options={"scenario": ...})``
            overrides it for one episode (also accepting a dict of physical fields).
        reward_weights: dict overriding any of track, effort, rate, tv, tv_u, divergence, class, saturation, physical
            (the class and the physical rewards: see the reward above and docs/RL.md, "Class reward" and "Physical
            reward").
        error_scale: error scale of reward and observation [output unit].
        episode_seconds: episode duration [s] for "random" and "paper" (None: 2 s random, 20 s paper; a pinned
            Scenario keeps its t_end).
        lost_track: lost-track bound as a multiple of the reference's amplitude (None = never flagged): an
            episode has lost track once, past 0.2 s, the RMS of e over a 0.1 s sliding window exceeds it
            (``Scenario.lost_track``; a saturated oscillation within the state bounds, which is not a divergence).
            Reported every step as ``info["lost_track"]``.
        terminate_on_lost_track: end the episode (``terminated=True``, ``info["lost_track"]=True``,
            ``info["diverged"]=False``, no divergence penalty) at the end of the step in which it lost track.
        unmodelled_effects: with "random", each episode also draws the servo valve's threshold and hysteresis, a
            sensor delay and the encoder quantisation that the law's model leaves out, at datasheet sizes
            (:data:`ehss_gym.core.unmodelled.DATASHEET_RANGES`; docs/MODEL.md, "Unmodelled valve and sensors");
            False (the default): none.
        unmodelled_share: with ``unmodelled_effects``, the share of the episodes that have the effects, in (0, 1]
            (default 1: every episode); the others have none (a mixture of the realistic and the model's plant).
        memory_tau: the memory features, for rejecting what one observation cannot show (a friction step, a dead
            band): two entries appended to the observation, the filtered error integral ``e_int`` (x' = e - x/tau
            at the agent step with the step's last measured error held, |x| clipped to 10 error_scale tau against
            windup; scale error_scale tau) and the action of the step before last ``prev_action`` [-]; tau [s] >=
            one agent step; None = none (the observation as without them). See docs/RL.md, "Memory".
        action: what the agent's action does, a row of :data:`ehss_gym.envs.actions.ACTIONS`: "current" (the
            default: a residual current), "rate", "filtered", "reference", "schedule", "reference-schedule" or
            "compensation" (the action table above; the last four act through the law and need ``mode="residual"``,
            those that shift the reference a digital estimator, the compensation mode a compensator on).
        action_bound: the bound of the rate and filtered modes' residual R [mA] and of the reference and
            reference-schedule modes' shift D [output unit], > 0; None = the mode's default per task (the defaults
            table); the other modes have none.
        render_mode: None or "rgb_array" (a dashboard: raw reference r, filtered y_d and output y; error; the
            applied current on a linear axis with its limit and its min/max envelope over each agent step;
            friction).

    Version history:
        v0 (ehss-gym 0.1): first release. Within 0.1 the defaults changed four times; the settings that
        reproduce each earlier loop are given.

        1. The reproduction study's recommendation (``ehss reproduce``): h = 30 us and smoothing 100 for
           velocity (they were 50 us and 0).
        2. The derivative estimator's O(h) bias fixed (``estimator="foh"``; ``estimator="zoh"`` is the
           earlier scheme), with the study's recommendation on the corrected loop: h = 50 us, f_r = 60 Hz and
           smoothing 1e3 (velocity), f_r = 20 Hz, sigma = 1e6, smoothing 100 and a 1 kHz estimator (position).
           Policies record every setting they were trained with, the estimator included; those trained before
           (without it) were retrained.
        3. The settings estimator "state"/"eso", observer_hz, law, layer_gain, bumpless, ref_accel and
           pressure_domain, with the noise study's choices as the defaults (``ehss noise``; docs/ENV.md).
           :data:`ehss_gym.envs.config.LEGACY_LOOP` holds the values that reproduce the loop before them; a
           policy recorded without them acts in it (:func:`ehss_gym.envs.config.in_legacy_loop`).
        4. The CLF law's sigma, f_r, smoothing and layer_gain tuned per task and n by one coded search on training
           scenarios (``ehss baselines``, reports/baselines); before, every n had n = 2's: sigma 1e5, f_r 60 Hz,
           smoothing 1e3, layer_gain 3 (velocity) and sigma 1e6, f_r 20 Hz, smoothing 100, layer_gain 3 (position).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, *, task: str = "velocity", plant=None, law_settings=None, mode: str = DEFAULTS.mode,
                 n: int = DEFAULTS.n,
                 fr: float | None = None, sigma: float | None = None, smoothing: float | None = None,
                 current_limit: float | str | None = RATED, control_period: float = DEFAULTS.control_period,
                 substeps: int = DEFAULTS.substeps, estimator: str | None = None,
                 estimator_hz: float | None = None, observer_hz: float | None = None, law: str | None = None,
                 layer_gain: float | None = None, bumpless: bool | None = None, ref_accel: float | None = None,
                 pressure_domain: float | None = DEFAULTS.pressure_domain, dob_hz: float = DEFAULTS.dob_hz,
                 lyapunov_kappa: float | None = None, reference_delay: float = 0.0, inverse_threshold: float = 0.0,
                 inverse_hysteresis: float = 0.0, agent_period: int = DEFAULTS.agent_period,
                 residual_scale: float | None = None, scenario: str | Scenario = DEFAULTS.scenario,
                 reward_weights: dict | None = None, error_scale: float | None = None,
                 episode_seconds: float | None = None, lost_track: float | None = DEFAULTS.lost_track,
                 terminate_on_lost_track: bool = DEFAULTS.terminate_on_lost_track,
                 unmodelled_effects: bool = DEFAULTS.unmodelled_effects,
                 unmodelled_share: float = DEFAULTS.unmodelled_share,
                 memory_tau: float | None = DEFAULTS.memory_tau, action: str = DEFAULTS.action,
                 action_bound: float | None = None, render_mode: str | None = None, **unknown):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got "
                             f"{render_mode!r}")
        self.render_mode = render_mode
        given = {k: v for k, v in locals().items() if k in EnvConfig.KEYS}  # the arguments above, by name
        # None selects the default, except where None is a value (current_limit=None means unlimited)
        given = {k: v for k, v in given.items() if v is not None or k in NONE_IS_A_VALUE}
        self.config = cfg = EnvConfig.from_kwargs({**given, **unknown})
        warn_untuned(cfg, given)
        self._lanes = Lanes(cfg, 1)
        self.observation_layout = self._lanes.layout
        D = len(self.observation_layout)
        self.observation_space = spaces.Box(-OBS_BOUND, OBS_BOUND, shape=(D,), dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self._lanes.action_dims,), dtype=np.float32)
        self._current = cfg.action == "current"  # today's action: the fast path of step()
        self._scale = cfg.residual_scale
        self._steps = 0
        self._T = 0
        self._n_clipped = 0
        self._ready = False
        self._hist: list | None = None
        self.scenario: Scenario | None = None

    @property
    def scenario_template(self) -> Scenario:
        """A Scenario with this env's controller settings; ``.replace(...)`` it to pin an episode."""
        return self._lanes.template

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        lanes = self._lanes
        sc, info = lanes.draw(0, self.config, self.np_random, options)
        lanes.load(0, sc)
        lanes.observe([0])
        self.scenario = sc
        self._T = int(lanes.T[0])
        self._steps = 0
        self._n_clipped = 0
        self._ready = True
        if self.render_mode == "rgb_array":
            self._hist = []
            self._record()
        return lanes.obs[0].copy(), info

    def step(self, action):
        if not self._ready:
            raise RuntimeError("call reset() before step()")
        lanes = self._lanes
        if self._current:
            if type(action) is np.ndarray and action.shape == (1,):  # fast path
                v = float(action[0])
                if v != v:
                    raise ValueError("action is NaN; actions must be numbers in [-1, 1] (out-of-range values are "
                                     "clipped)")
            else:
                v = parse_action_scalar(action)
            clipped = v > 1.0 or v < -1.0
            if clipped:
                v = 1.0 if v > 1.0 else -1.0
            lanes.u_res[0] = v * self._scale
        else:
            a, clipped = parse_action_vector(action, lanes.action_dims)
            lanes.set_actions(slice(0, 1), a)
        self._n_clipped += clipped
        lanes.step()
        self._steps += 1
        lost = lanes.acc0.item(M_LOST) > 0.0
        diverged = not lanes.run[0]
        terminated = diverged or (lost and self.config.terminate_on_lost_track)
        truncated = not terminated and self._steps >= self._T
        # Python floats in two list conversions of pre-made row views (numpy scalar reads cost ~0.1 us each)
        st = lanes.tail0.tolist()
        info = step_info(lanes.info_ok0.tolist(), st, clipped, self._n_clipped, diverged, lost)
        if terminated or truncated:
            self._ready = False
            m = lanes.metrics(0)
            info["metrics"] = m
            if diverged:
                info["divergence_reason"] = m["divergence_reason"]
                info["t_diverged"] = m["t_diverged"]
        if self._hist is not None:
            self._record()
        return lanes.obs0.copy(), st[F_REW - F_STATS], terminated, truncated, info

    # --- rendering ---------------------------------------------------------------------------------

    def _record(self):
        i = self._lanes.info_ok[0]
        st = self._lanes.stats[0]
        lo, hi = (st[S_UMIN], st[S_UMAX]) if st[S_N] > 0 else (i[I_UAPP], i[I_UAPP])
        self._hist.append((i[I_T], i[I_YE], i[I_YD], i[I_E], i[I_UAPP], i[I_UBASE], i[I_URES], i[I_TF], i[I_R], lo,
                           hi))

    def render(self):
        """An RGB dashboard (H, W, 3) uint8 of the episode so far, or None without render_mode."""
        if self.render_mode is None:
            gym.logger.warn("render() called without render_mode; create the env with render_mode='rgb_array'")
            return None
        from .render import render_dashboard  # matplotlib (~0.3 s to import) only for envs that render

        rows = np.array(self._hist or [(0.0,) * len(HIST_COLUMNS)])
        return render_dashboard(dict(zip(HIST_COLUMNS, rows.T)), self.config, self.scenario)

    def close(self):
        self._hist = None
