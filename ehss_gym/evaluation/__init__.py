"""The evaluation harness: scripted and learned policies scored on the same pinned episodes.

Modules, bottom to top:

- :mod:`~ehss_gym.evaluation.suites`: :class:`EvalConfig`, :class:`Episode`, :func:`build_episodes` (the paper
  run, the held-out suite, the robustness sweeps, the step suite).
- :mod:`~ehss_gym.evaluation.loading`: a spec's run (model file, scripted-law description, object) as an object
  with ``predict``; each model loaded once per process.
- :mod:`~ehss_gym.evaluation.specs`: :class:`PolicySpec` and its sources (:func:`parse_policy`,
  :func:`scripted_spec`, :func:`learned_spec`, :func:`object_spec`, :func:`shipped_specs`), :func:`check_fit`.
- :mod:`~ehss_gym.evaluation.stats`: bootstrap CIs, IQM, probability of improvement.
- :mod:`~ehss_gym.evaluation.scoring`: the ruler: per-episode ratios by metric class, figures, gates, ranking,
  summaries and comparisons.
- :mod:`~ehss_gym.evaluation.harness`: jobs, the worker pool, :func:`evaluate` and its :class:`Results`.
- :mod:`~ehss_gym.evaluation.heldout`: the held-out validation used during training.

The report of an evaluation (markdown, CSVs, figures) is :mod:`ehss_gym.reporting.comparison`'s.
"""

from __future__ import annotations

# the harness re-exports the names of the modules below it (its callers use ``harness.<name>``)
from .harness import (
    METRICS,
    REFERENCE_POLICY,
    SCRIPTED_DEFAULT,
    SUITES,
    SWEEP_WINDOW,
    TASKS,
    UNITS,
    Episode,
    EvalConfig,
    PolicyError,
    PolicySpec,
    Results,
    build_episodes,
    check_fit,
    default_specs,
    evaluate,
    learned_spec,
    object_spec,
    parse_policy,
    rollout,
    scripted_spec,
    shipped_specs,
)
from .specs import PolicyWarning, parse_policies, saved_env_kwargs, valid_forms

__all__ = ["EvalConfig", "PolicySpec", "PolicyError", "PolicyWarning", "saved_env_kwargs",
           "Episode", "Results", "evaluate", "parse_policy",
           "parse_policies", "valid_forms", "scripted_spec", "learned_spec", "object_spec", "shipped_specs",
           "default_specs", "build_episodes", "rollout", "check_fit", "REFERENCE_POLICY",
           "SCRIPTED_DEFAULT", "METRICS", "TASKS", "SUITES", "UNITS", "SWEEP_WINDOW"]
