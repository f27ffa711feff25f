r"""Scripted policies for EHSSTracking-v0 with stable-baselines3's ``predict`` interface.

Every policy here has ``predict(observation, state=None, episode_start=None, deterministic=True) ->
(actions, state)`` and works on one observation (D,) or a batch (n_envs, D), so SB3's
``evaluate_policy`` accepts them. They read the physical values from the observation with
:func:`ehss_gym.envs.observation.decode_observation`.

- :class:`CLFPolicy`: the CLF law of the env it acts in (its ``law`` and ``estimator``; names such as ``clf-n2``,
  ``lin-sontag-n4`` or ``sontag-foh-n2`` map to env settings by :func:`parse_scripted`; ``dob-n2`` adds the
  disturbance observer, ``dob_hz``; ``dcomp-n2`` delays the law's reference, ``reference_delay``; ``vinv-n2``
  inverts the valve's dead band and hysteresis, ``inverse_threshold`` and ``inverse_hysteresis``; ``eso-n2``
  estimates with the extended-state observer, ``estimator`` "eso" at ``observer_hz``) for the env's n.
  Residual mode: a zero residual (the base law alone). Direct mode: the law's current the env reports in the
  observation (``u_base``), over ``residual_scale``, held for the agent period.
- :class:`PIDPolicy`: a PID on the tracking error, u = -(kp e + ki int e dt + kd e') [mA], with the
  integrator clamped (anti-windup) so that |ki int e dt| <= the current limit. Direct mode: u is the
  whole valve current. Residual mode: u is added to the CLF law (CLF + PID).
  Gains come from :func:`tune_pid`, a documented, reproducible procedure:

  1. *Relay experiment* (Astrom-Hagglund): the loop (direct mode: the bare valve; residual mode: the
     CLF loop) under a relay u = -d sign(e) of amplitude d = ``relay_ma`` around r = 0, no friction,
     no noise, for ``relay_seconds``; from the second half, the ultimate period T_u (mean spacing of
     upward zero crossings of e) and the oscillation amplitude a ((max - min) / 2), so the ultimate
     gain is K_u = 4 d / (pi a).
  2. *Candidate rules* from (K_u, T_u), with k_i = K_p / T_i and k_d = K_p T_d:
     Ziegler-Nichols PID (0.6 K_u, T_u/2, T_u/8), ZN PI (0.45 K_u, T_u/1.2, 0),
     Tyreus-Luyben PID (0.45 K_u, 2.2 T_u, T_u/6.3), ZN "some overshoot" (0.33 K_u, T_u/2, T_u/3),
     ZN "no overshoot" (0.2 K_u, T_u/2, T_u/3).
  3. *Selection*: each candidate runs the tuning scenario (the paper's 1 rad/s, 2 rad/s sine -- 1 rad
     for position -- with a 1.8 N*m friction event from 1.5 s to 2.5 s, 3 s, no noise); the lowest
     RMSE wins (a diverged run scores inf).
  4. *Refinement*: coordinate search from the winner -- two rounds; in each, for kp, ki, kd in turn,
     the gain times 0.5, 0.7, 1.4 and 2 is tried on the tuning scenario and kept if it lowers the RMSE.

  :data:`PID_RELAY_GAINS` stores the result of this procedure for the default settings of each task and
  mode; ``tests/test_policies.py`` re-runs the procedure and checks it reproduces them. The direct mode's gains in
  use (:data:`PID_GAINS`, the ``pid`` of ``ehss evaluate``) start from them and are tuned by ``ehss baselines``, the
  coded search that tunes every scripted baseline.
- :class:`FrictionFeedforwardPolicy`: an *oracle* residual that knows the friction events and adds a
  current doublet centred on each friction edge, sized so that G * int int u = Delta T_f / J cancels
  the torque step (G from the model's Lie derivatives at the measured state). It exists to show that
  the residual channel has authority (the env's residual-authority check), not as a controller.
- :class:`ConstantResidualPolicy`: a constant residual current per episode (the headroom study's best-bias oracle).
"""

from .base import ScriptedPolicy
from .clf import (
    COMPENSATOR_ROWS,
    COMPENSATOR_TEXT,
    DOB_HZ,
    DOB_ROWS,
    SCRIPTED_FORMS,
    CLFPolicy,
    compensated_tasks,
    compensator_kind,
    compensator_loops,
    compensator_rows,
    compensator_settings,
    dob_rows,
    parse_scripted,
)
from .feedforward import ConstantResidualPolicy, FrictionFeedforwardPolicy
from .pid import PID_GAINS, PID_RELAY, PID_RELAY_GAINS, RULES, PIDPolicy, default_pid_gains, relay_experiment, tune_pid

__all__ = ["ScriptedPolicy", "CLFPolicy", "parse_scripted", "SCRIPTED_FORMS", "DOB_HZ", "DOB_ROWS", "dob_rows",
           "COMPENSATOR_ROWS", "COMPENSATOR_TEXT", "compensated_tasks", "compensator_kind", "compensator_loops",
           "compensator_rows", "compensator_settings",
           "PIDPolicy",
           "FrictionFeedforwardPolicy", "ConstantResidualPolicy", "tune_pid", "relay_experiment", "PID_GAINS",
           "PID_RELAY_GAINS", "PID_RELAY", "RULES", "default_pid_gains"]
