"""Scenarios that cycle through every law, estimator and n of a task, for the tests that run many lanes in one block
(each test adds the settings it exercises)."""

from __future__ import annotations

from collections.abc import Callable

from ehss_gym.core.registry import ESTIMATORS, LAWS, names
from ehss_gym.core.scenarios import sample_scenario
from ehss_gym.envs import EnvConfig


def cycled_scenarios(task: str, count: int, t_end: float, seed0: int, extra: Callable[[int, object], dict]) -> list:
    """``count`` randomised scenarios of ``task`` (seeds ``seed0``, ``seed0`` + 1, ...), scenario i with law i mod the
    laws, estimator (i // 3) mod the estimators and n = (2, 4, 6)[i mod 3], and the settings ``extra(i, sc)`` of the
    test on top (``sc`` the drawn scenario)."""
    tmpl = EnvConfig.from_kwargs({"task": task}).template()
    laws, ests = names(LAWS), names(ESTIMATORS)
    out = []
    for i in range(count):
        sc = sample_scenario(seed0 + i, tmpl)
        est = ests[(i // 3) % len(ests)]
        change = {"t_end": t_end, "law": laws[i % len(laws)], "estimator": est, "n": (2, 4, 6)[i % 3],
                  **extra(i, sc)}
        if est == "analog":  # the reference shaper drives a digital reference model only
            change["ref_accel"] = 0.0
        out.append(sc.replace(**change))
    return out
