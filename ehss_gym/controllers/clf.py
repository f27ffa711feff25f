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
- ``dcomp-n<k>``: ``clf-n<k>`` with the law's reference delayed by the task's row of :data:`COMPENSATOR_ROWS`
  (``reference_delay`` [control samples]; docs/MODEL.md, "Compensating the unmodelled valve and sensors"), with a zero
  residual: the scripted compensation of a sensor delay whose size is known only from the distribution it is drawn
  from.
- ``vinv-n<k>``: ``clf-n<k>`` with the valve's dead band and hysteresis inverted on the law's current at the task's
  row of :data:`COMPENSATOR_ROWS` (``inverse_threshold``, ``inverse_hysteresis`` [% of rated current]), with a zero
  residual: the scripted valve compensation of a valve whose sizes are known only from their distribution.
- ``eso-n<k>``: ``clf-n<k>`` with the extended-state observer as its estimator (``estimator`` "eso", no output
  differentiated: it reads the measured velocity and the model, so the sensors' quantisation steps are not
  differentiated into the current) at the task's row of :data:`COMPENSATOR_ROWS` (``observer_hz`` [Hz]), with a zero
  residual: the scripted estimator for quantised sensors, its bandwidth chosen on the distribution of the effects.

The start-up settings (bumpless start, reference shaper, the model's pressure domain) are the env's defaults in every
case; pass them as env overrides to change them.
"""

from __future__ import annotations

import re

import numpy as np

from ehss_gym.core.registry import ESTIMATORS, LAWS, names
from ehss_gym.envs.law_table import COMPENSATOR_ROWS, compensator_settings

from .base import ScriptedPolicy

_NAME_RE = re.compile(r"^(clf|" + "|".join(map(re.escape, names(LAWS))) + r")(?:-("
                      + "|".join(map(re.escape, names(ESTIMATORS))) + r"))?-n(\d+)$")
_DOB_RE = re.compile(r"^dob-n(\d+)$")
_COMPENSATOR_RE = re.compile(r"^(dcomp|vinv|eso)-n(\d+)$")
SCRIPTED_FORMS = ("clf-n<k>", "<law>-n<k>", "<law>-<estimator>-n<k>", "dob-n<k>", "dcomp-n<k>", "vinv-n<k>",
                  "eso-n<k>")
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
COMPENSATOR_TEXT = {"dcomp": "its reference delayed by {reference_delay:g} control sample(s)",
                    "vinv": "the valve's dead band and hysteresis inverted at {inverse_threshold:g} % and "
                            "{inverse_hysteresis:g} % of rated current",
                    "eso": "the extended-state observer at {observer_hz:g} Hz as its estimator"}  # (str.format)


DEFAULT_TASK = "velocity"  # the env's default task: the row a compensator name takes where no task is given


def compensator_kind(name: str) -> str | None:
    """``"dcomp"``, ``"vinv"`` or ``"eso"`` for a scripted compensator's name (``dcomp-n<k>``, ``vinv-n<k>``,
    ``eso-n<k>``), else None."""
    m = _COMPENSATOR_RE.match(name)
    return m.group(1) if m else None


def compensator_rows(kind: str, tasks, law_table=None) -> dict[str, dict[str, float]]:
    """The settings of the scripted compensator ``kind`` (``"dcomp"`` or ``"vinv"``) for each task of ``tasks``: a law
    table's rows where one is given (:class:`ehss_gym.envs.law_table.LawTable`: the tasks it chose a size for, the
    others left out), else the built-in :data:`COMPENSATOR_ROWS` (Table I's training distribution of the unmodelled
    effects)."""
    rows = COMPENSATOR_ROWS[kind]
    bad = [t for t in tasks if t not in rows]
    if bad:
        raise ValueError(f"task must be one of {sorted(rows)}, got {bad[0]!r}")
    if law_table is None:
        return {t: dict(rows[t]) for t in tasks}
    return {t: dict(law_table.tasks[t].compensators[kind]) for t in tasks
            if t in law_table.tasks and kind in law_table.tasks[t].compensators}


def compensator_loops(kind: str, tasks, law_table=None) -> dict[str, dict]:
    """The loop settings of the scripted compensator ``kind`` on each task of ``tasks`` that has a row
    (:func:`compensator_rows` through :func:`compensator_settings`)."""
    return {t: compensator_settings(kind, row) for t, row in compensator_rows(kind, tasks, law_table).items()}


def compensated_tasks(kind: str, tasks, law_table=None) -> tuple[str, ...]:
    """The tasks of ``tasks`` on which the scripted compensator ``kind`` compensates anything (a nonzero setting of
    :func:`compensator_rows`): on the others its rule chose none, so it is ``clf-n<k>`` there and is not run twice."""
    return tuple(t for t, row in compensator_rows(kind, tasks, law_table).items()
                 if any(v != 0.0 for v in row.values()))


def parse_scripted(name: str, task: str | None = None, law_table=None) -> dict | None:
    """The env keyword arguments of a scripted CLF policy name, or None if ``name`` is not one.

    Args:
        name: the policy name (:data:`SCRIPTED_FORMS`).
        task: the task the policy acts on, for the names whose settings depend on it (``dcomp-n<k>``,
            ``vinv-n<k>``, ``eso-n<k>``: the task's row of :data:`COMPENSATOR_ROWS`); default the env's default
            task.
        law_table: the law table whose compensator rows replace :data:`COMPENSATOR_ROWS` (None: Table I's).

    Returns:
        {"n": k, "mode": "residual"} plus "law" and "estimator" where the name gives them (``clf`` gives neither: the
        env's defaults), or "dob_hz" (:data:`DOB_HZ` [Hz]) for ``dob-n<k>``, or the compensator's settings for
        ``dcomp-n<k>`` ("reference_delay" [control samples]), ``vinv-n<k>`` ("inverse_threshold",
        "inverse_hysteresis" [% of rated current]) and ``eso-n<k>`` ("estimator" "eso" and "observer_hz" [Hz]; none
        where the task's row is 0: :func:`compensator_settings`). n is validated by the env (an even integer >= 2).

    Raises:
        ValueError: ``clf-<estimator>-n<k>`` (the default law has no estimator variant by that name: use the law's), or
            a compensator whose ``law_table`` has no row for the task.
    """
    m = _DOB_RE.match(name)
    if m:
        return {"n": int(m.group(1)), "mode": "residual", "dob_hz": DOB_HZ}
    m = _COMPENSATOR_RE.match(name)
    if m:
        task = task or DEFAULT_TASK
        rows = compensator_rows(m.group(1), (task,), law_table)
        if task not in rows:
            raise ValueError(f"scripted policy {name!r}: {law_table.describe()} have no {m.group(1)}-n2 row for "
                             f"task {task!r}; ehss baselines writes it")
        return {"n": int(m.group(2)), "mode": "residual", **compensator_settings(m.group(1), rows[task])}
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

    @property
    def observes(self) -> bool:
        """In residual mode the action is the zero residual (the law acts alone); in direct mode it is the law's
        current, read from the observation."""
        return self.config.mode != "residual"

    def act(self, obs, state, episode_start):
        if self.config.mode == "residual":
            return np.zeros((obs.shape[0], 1)), state
        u = self.value(obs, "u_base")
        return (u / self.config.residual_scale).reshape(-1, 1), state
