"""The CLF laws as fixed policies (a zero residual, or the law's own current in direct mode), and their names.

Scripted CLF policies are named (:func:`parse_scripted`):

- ``clf-n<k>``: the env's default law and estimator for each task (the noise study's choice, ``ehss noise``), n = k;
- ``<law>-n<k>``: that law (a row of :data:`ehss_gym.core.registry.LAWS`, e.g. ``sontag``, ``lin-sontag``) with the
  env's default estimator and that law's default sigma (:attr:`ehss_gym.envs.config.TaskDefaults.sigma_by_law`);
- ``<law>-<estimator>-n<k>``: that law with that estimator (a row of :data:`ehss_gym.core.registry.ESTIMATORS`, e.g.
  ``foh``, ``eso``), e.g. ``sontag-foh-n2``: Sontag's formula with the paper's state-variable filter;
- ``dob-n<k>``: ``clf-n<k>`` plus the disturbance observer on the combined error (the loop setting ``dob_hz``;
  docs/MODEL.md, "Disturbance observer") at :data:`DOB_HZ`, with a zero residual: the scripted disturbance rejection
  a learned residual must beat. ``ehss evaluate`` and ``ehss headroom`` run ``dob-n2`` at its tuned settings per task,
  :data:`DOB_ROWS`.
- ``dcomp-n<k>``: ``clf-n<k>`` with the law's reference delayed by :data:`DCOMP_SAMPLES` control samples (the loop
  setting ``reference_delay``; docs/MODEL.md, "Compensating the unmodelled valve and sensors"), with a zero residual:
  the scripted compensation of a sensor delay whose size is known only from the distribution it is drawn from.

The start-up settings (bumpless start, reference shaper, the model's pressure domain) are the env's defaults in every
case; pass them as env overrides to change them.
"""

from __future__ import annotations

import re

import numpy as np

from ehss_gym.core.registry import ESTIMATORS, LAWS, names

from .base import ScriptedPolicy

_NAME_RE = re.compile(r"^(clf|" + "|".join(map(re.escape, names(LAWS))) + r")(?:-("
                      + "|".join(map(re.escape, names(ESTIMATORS))) + r"))?-n(\d+)$")
_DOB_RE = re.compile(r"^dob-n(\d+)$")
_DCOMP_RE = re.compile(r"^dcomp-n(\d+)$")
SCRIPTED_FORMS = ("clf-n<k>", "<law>-n<k>", "<law>-<estimator>-n<k>", "dob-n<k>", "dcomp-n<k>")
# ``dob-n2``'s settings per task on Table I: the observer's cutoff f_d [Hz] with the law's smoothing width [unit of s]
# and boundary-layer gain [-] (on clf-n2's sigma and f_r), tuned by ``ehss baselines`` with every other baseline
# (reports/baselines/tuned.json; tests/test_baselines.py checks them). ``ehss evaluate`` and ``ehss headroom`` run
# ``dob-n2`` with the row of each task (a law-settings file's rows instead, where one is given).
DOB_ROWS: dict[str, dict[str, float]] = {
    "velocity": {"dob_hz": 5.59221707326609, "smoothing": 316.22776601683796,
                 "layer_gain": 18.457962304471113},
    "position": {"dob_hz": 12.765592438605339, "smoothing": 119.70850304957303,
                 "layer_gain": 27.91716122789097},
}
# The observer's cutoff f_d [Hz] of a ``dob-n<k>`` name on its own (:func:`parse_scripted` does not know the task): the
# choice of an earlier sweep of 5..160 Hz on 48 training scenarios per task at n = 2 (``python tools/dob_sweep.py``),
# kept for names used outside the evaluation (where the task's row of DOB_ROWS replaces it).
DOB_HZ = 20.0


def dob_rows(tasks, law_table=None) -> dict[str, dict[str, float]]:
    """``dob-n2``'s observer settings per task (``dob_hz`` [Hz], ``smoothing``, ``layer_gain``): a law table's rows
    where one is given (:class:`ehss_gym.envs.law_table.LawTable`: the tasks it tuned an observer for, the others left
    out), else the built-in :data:`DOB_ROWS` (Table I's tuning) for every task of ``tasks``."""
    if law_table is None:
        return {t: dict(DOB_ROWS[t]) for t in tasks}
    return {t: dict(law_table.tasks[t].dob) for t in tasks if t in law_table.tasks and law_table.tasks[t].dob}
# The reference delay [control samples] of ``dcomp-n<k>``, both tasks: the choice of
# ``python tools/compensator_sweep.py`` on 48 training scenarios per task drawn with the unmodelled effects (the env's
# ``unmodelled_effects=True``; their delay is 1 or 2 samples) by its rule, written before it ran (no failure, then the
# lowest geometric mean over the tasks of the ruler's overall figure against clf-n2, a tie to the smaller delay):
# 0.811 at 1 sample (velocity 0.987, position 0.666), 0.821 at 2, 0.835 at 1.5 (the mean delay, which leaves half a
# sample off on every episode), 1.012 at 3. The same sweep's valve inverse (threshold 0-0.5 %, hysteresis 0-3 % of
# rated current) chose none: at the distribution's mean (0.375 %, 2.25 %) it gives 0.883 in velocity but 1.40 in
# position (effort x1.90), 1.11 over both; so there is no scripted valve inverse.
DCOMP_SAMPLES = 1.0


def parse_scripted(name: str) -> dict | None:
    """The env keyword arguments of a scripted CLF policy name, or None if ``name`` is not one.

    Returns:
        {"n": k, "mode": "residual"} plus "law" and "estimator" where the name gives them (``clf`` gives neither: the
        env's defaults), or "dob_hz" (:data:`DOB_HZ` [Hz]) for ``dob-n<k>``, or "reference_delay"
        (:data:`DCOMP_SAMPLES` [control samples]) for ``dcomp-n<k>``. n is validated by the env (an even
        integer >= 2).

    Raises:
        ValueError: ``clf-<estimator>-n<k>`` (the default law has no estimator variant by that name: use the law's).
    """
    m = _DOB_RE.match(name)
    if m:
        return {"n": int(m.group(1)), "mode": "residual", "dob_hz": DOB_HZ}
    m = _DCOMP_RE.match(name)
    if m:
        return {"n": int(m.group(1)), "mode": "residual", "reference_delay": DCOMP_SAMPLES}
    m = _NAME_RE.match(name)
    if not m:
        return None
    law, est, n = m.group(1), m.group(2), int(m.group(3))
    if law == "clf" and est is not None:
        raise ValueError(f"scripted policy {name!r}: an estimator variant names its law, e.g. "
                         f"'sontag-{est}-n{n}' or 'lin-sontag-{est}-n{n}'")
    kw = {"n": n, "mode": "residual"}
    if law != "clf":
        kw["law"] = law
    if est is not None:
        kw["estimator"] = est
    return kw


class CLFPolicy(ScriptedPolicy):
    """The CLF law of the env it acts in: zero residual, or the law's current in direct mode."""

    def act(self, obs, state, episode_start):
        if self.config.mode == "residual":
            return np.zeros((obs.shape[0], 1)), state
        u = self.value(obs, "u_base")
        return (u / self.config.residual_scale).reshape(-1, 1), state
