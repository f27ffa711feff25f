"""SB3's per-sub-env infos from the native vector env's stacked ones (:func:`ehss_gym.train.vec_env.lane_infos`)
against the rule written lane by lane: sub-env i's dict has key k where k's mask is set for i (every lane when k has
no mask), with k's value for i as a Python value (a nested stacked dict converted the same way), in the stacked dict's
key order."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ehss_gym.train.vec_env import lane_infos


def _reference(stacked: dict, n: int, lanes) -> list[dict]:
    out = []
    for i in range(n):
        d = {}
        if i in lanes:
            for key, val in stacked.items():
                if key.startswith("_"):
                    continue
                mask = stacked.get("_" + key)
                if mask is not None and not mask[i]:
                    continue
                if isinstance(val, dict):
                    d[key] = _reference(val, n, [i])[i]
                else:
                    v = val[i]
                    d[key] = v.item() if isinstance(v, np.generic) else v
        out.append(d)
    return out


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 9), n_keys=st.integers(0, 6), subset=st.booleans())
def test_lane_infos_gives_each_sub_env_its_masked_entries_in_order(seed, n, n_keys, subset):
    rng = np.random.default_rng(seed)
    shared = np.ones(n, dtype=np.bool_)  # the step keys' one mask, as the vector env gives it
    stacked: dict = {}
    for j in range(n_keys):
        kind = rng.integers(4)
        key = ["t", "e", "it's", "u_base", "clipped", "x y"][j]
        val = (rng.normal(size=n) if kind != 1 else rng.random(n) < 0.5)
        stacked[key] = val
        if kind == 2:  # a mask of its own, set for some lanes only
            stacked["_" + key] = rng.random(n) < 0.6
        elif kind == 3:  # no mask at all
            pass
        else:
            stacked["_" + key] = shared
    if rng.random() < 0.5:  # an entry for the lanes that ended: a nested stacked dict, and an object array
        ended = rng.random(n) < 0.4
        stacked["metrics"] = {"rmse": rng.normal(size=n), "_rmse": ended.copy()}
        stacked["_metrics"] = ended
        reason = np.empty(n, dtype=object)
        reason[:] = "nonfinite"
        stacked["divergence_reason"], stacked["_divergence_reason"] = reason, ended.copy()
    lanes = sorted(rng.choice(n, size=rng.integers(0, n + 1), replace=False).tolist()) if subset else None
    got = lane_infos(stacked, n, lanes)
    want = _reference(stacked, n, range(n) if lanes is None else lanes)
    assert len(got) == n
    for g, w in zip(got, want):
        assert list(g) == list(w) and g == w
        assert all(type(g[k]) is type(w[k]) for k in g if not isinstance(w[k], dict))
