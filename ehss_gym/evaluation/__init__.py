"""The evaluation harness: scripted and learned policies scored on the same pinned episodes.

Modules, bottom to top:

- :mod:`~ehss_gym.evaluation.suites`: :class:`EvalConfig`, :class:`Episode`, :func:`build_episodes` (the paper
  run, the held-out suite, the robustness sweeps, the step suite, the unmodelled suite).
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

from ehss_gym.infra.lazy import lazy_exports

# the names load on first use: the command line reads the suites' settings without the harness's dependencies
_EXPORTS = {
    **dict.fromkeys(("evaluate", "Results", "rollout"), ".harness"),
    **dict.fromkeys(("EvalConfig", "Episode", "build_episodes", "SUITES", "SWEEP_WINDOW", "TASKS", "UNITS"), ".suites"),
    **dict.fromkeys(("PolicySpec", "PolicyWarning", "saved_env_kwargs", "parse_policy", "parse_policies",
                     "valid_forms", "scripted_spec", "scripted_specs", "learned_spec", "object_spec", "shipped_specs",
                     "default_specs", "check_fit", "REFERENCE_POLICY", "SCRIPTED_DEFAULT"), ".specs"),
    "PolicyError": ".loading",
    **dict.fromkeys(("METRICS", "CLASSES", "summarize"), ".scoring"),
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
__all__ = list(_EXPORTS)
