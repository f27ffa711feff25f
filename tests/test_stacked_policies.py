"""Safe-weights policies side by side in one forward pass (StackedPolicies): the actions of each policy's rows are
the ones it gives alone, bit for bit, or no stack is made."""

from __future__ import annotations

import numpy as np
import pytest

from ehss_gym.agents.safeweights import SafePolicy, StackedPolicies, load_policy, shipped_models
from ehss_gym.core.scenarios import heldout_scenarios
from ehss_gym.envs import EnvConfig
from ehss_gym.envs.rollouts import SideBySide, rollout

SEEDS = 5


def _seeds(spec: str, k: int = SEEDS) -> list[SafePolicy]:
    models = shipped_models()
    return [load_policy(models[f"{spec}-seed{i}"]) for i in range(k)]


def _observations(rng, rows: int, dims: int) -> np.ndarray:
    """Raw observations over six orders of magnitude, so the normalisation's clip is reached too."""
    return (rng.standard_normal((rows, dims)) * rng.choice([0.01, 1.0, 100.0], size=(rows, dims))).astype(np.float32)


# tanh layers and VecNormalize; the pure PPO policy's 17 inputs; SAC's relu layers and squashed head
@pytest.mark.parametrize("spec", ["residual-ppo-position-n2", "ppo-position-n2", "residual-sac-velocity-n2"])
@pytest.mark.parametrize("n", [1, 3, 8, 48])
def test_stacked_seeds_act_as_each_seed_alone_bit_for_bit(spec, n):
    pols = _seeds(spec)
    stacked = SafePolicy.side_by_side(pols, n)
    assert stacked is not None
    assert stacked._rows == (n >= StackedPolicies.MIN_ROWS)  # both forms are exercised over the row counts
    rng = np.random.default_rng(n)
    dims = pols[0].observation_space.shape[0]
    for _ in range(12):
        obs = _observations(rng, SEEDS * n, dims)
        alone = np.concatenate([p.predict(obs[i * n:(i + 1) * n])[0] for i, p in enumerate(pols)])
        together = stacked.predict(obs)
        assert together.shape == alone.shape == (SEEDS * n, *pols[0].action_space.shape)
        assert together.dtype == alone.dtype
        assert np.array_equal(together.view(np.uint32), alone.view(np.uint32))


def test_a_probe_that_rounds_differently_refuses_the_stack(monkeypatch):
    """The probe compares every bit: one action one ulp off anywhere in its batches, and no stack is made."""
    pols = _seeds("residual-ppo-velocity-n2", 2)
    assert StackedPolicies.fit(pols, 8) is not None
    actions = StackedPolicies._actions
    calls = []

    def off_by_one_ulp(self, x):
        out = actions(self, x)
        calls.append(1)
        if len(calls) == StackedPolicies.PROBE_BATCHES:  # the last probe batch only
            out[-1, -1] = np.nextafter(out[-1, -1], np.float32(np.inf))
        return out

    monkeypatch.setattr(StackedPolicies, "_actions", off_by_one_ulp)
    assert StackedPolicies.fit(pols, 8) is None
    assert len(calls) == StackedPolicies.PROBE_BATCHES


def test_policies_that_cannot_share_a_pass_get_no_stack():
    ppo, residual = _seeds("ppo-position-n2", 1)[0], _seeds("residual-ppo-position-n2", 2)
    assert StackedPolicies.fit(residual[:1], 8) is None  # one policy: nothing to share
    assert StackedPolicies.fit([ppo, residual[0]], 8) is None  # 17 against 22 inputs
    sac = _seeds("residual-sac-position-n2", 1)[0]
    assert StackedPolicies.fit([residual[0], sac], 8) is None  # tanh against relu layers, another head
    assert StackedPolicies.fit([residual[0], object()], 8) is None
    with pytest.raises(ValueError, match="observation must have shape"):
        StackedPolicies.fit(residual, 8).predict(np.zeros((8, 22), dtype=np.float32))


def test_side_by_side_seeds_in_one_pass_run_the_episodes_each_runs_alone():
    """A learned policy's seeds side by side in a rollout (the evaluation's jobs) take the one-pass route, and every
    episode's metrics and trace equal those of the seed's rollout alone, bit for bit."""
    pols = _seeds("residual-ppo-position-n2", 2)
    kw = pols[0].env_kwargs
    scs = [sc.replace(t_end=0.04 + 0.01 * (i % 3)) for i, sc in
           enumerate(heldout_scenarios(8, EnvConfig.from_kwargs(kw).template()))]
    both = SideBySide([(pols[0], 8), (pols[1], 8)])
    together = rollout(both, kw, scs + scs, trace=True)
    assert isinstance(both._together, StackedPolicies)
    alone = rollout(pols[0], kw, scs, trace=True) + rollout(pols[1], kw, scs, trace=True)
    assert [repr(r.metrics) for r in together[:8]] != [repr(r.metrics) for r in together[8:]]  # the seeds differ
    for x, y in zip(together, alone):
        assert repr(x.metrics) == repr(y.metrics)
        assert {k: v.tobytes() for k, v in x.trace.items()} == {k: v.tobytes() for k, v in y.trace.items()}
    uneven = SideBySide([(pols[0], 8), (pols[1], 7)])
    uneven.predict(np.zeros((15, 22), dtype=np.float32))
    assert uneven._together is None  # unequal shares: each policy's own pass
