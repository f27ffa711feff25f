"""The headroom table: what a residual on the n = 2 law could gain, on which class of the ruler, and what it must
observe to gain it.

For each task, each suite of ``ehss evaluate`` (:data:`ehss_gym.evaluation.suites.SUITES`, so a suite added there
appears here) and each class of the ruler (:mod:`ehss_gym.evaluation.scoring`: tracking, disturbance, effort,
chatter), the figures against the base law (the env's tuned n = 2 law, zero residual: the ruler's reference law) of:

- ``dob-n2``, the scripted disturbance-observer residual (:func:`ehss_gym.controllers.parse_scripted`);
- the oracles (:data:`VARIANTS`): **true model** (the law's model is the true plant: no parameter mismatch);
  **ff centred** and **ff at edge** (:class:`~ehss_gym.controllers.FrictionFeedforwardPolicy` knowing every friction
  event: its current doublet centred on each edge, or started at the edge, which is what a causal policy told of the
  event could do); **best bias** (per episode, the constant residual current with the best per-episode overall figure
  of the ruler, found by a 1-D bounded search, :class:`Search1D`); **best width** (per episode, the law's smoothing
  width w, the boundary layer, with the best per-episode overall figure, by the same search); on the unmodelled suite
  (:data:`KNOWN_SUITES`), **delay known**, **valve known** and **both known**, which know the episode's own sensor delay
  and valve threshold and hysteresis and compensate them (the law's reference delayed by the delay, the valve's inverse
  on the law's current: :mod:`ehss_gym.core.compensators`), and **delay known, best width** and **both known, best
  width**, which add the best width's search to them (what knowing the effects and the episode in hindsight reach
  together);
- ``dcomp-n2`` and ``vinv-n2``, the causal counterparts of the delay compensation and the valve inverse (fixed sizes
  per task chosen on training episodes, :data:`ehss_gym.envs.law_table.COMPENSATOR_ROWS`), beside ``dob-n2``;
- the sizes of the ideal corrections on the unmodelled suite (:mod:`ehss_gym.study.corrections`).

**The agent period.** The residuals that change their current during an episode (the feed-forward doublets) run at
agent periods 1, 5 and 20 (:data:`AGENT_PERIODS`): a residual holds its current over the agent period. The law and
the disturbance observer act every control period inside the loop, so the agent period must not change the base
law's or ``dob-n2``'s episodes; the other oracles (the true model, a width, a constant current) cannot depend on it
and run at :data:`FREE_PERIOD` (the fewest agent steps). Checked: on :data:`CHECK_SUITE` the base law and ``dob-n2``
run at every agent period, and on every suite the base law runs at :data:`FREE_PERIOD` too; the report says whether
any class metric differed, to the last bit (:func:`period_check`).

**The rule, written before the runs.** The headroom of a class on a (task, suite) is the lowest class figure G_c
among the oracles that pass the ruler's failure gate: the ratio best oracle / base law, with its 95 % bootstrap CI
over episodes (the harness's, :func:`ehss_gym.evaluation.scoring.figure_statistics`); overall, the lowest overall
figure G of one oracle (the geometric mean of its classes). A class **has headroom** when that CI, over at least
:data:`MIN_EPISODES` episodes, lies wholly below 1, and **material headroom** when its upper end is below
1 - :data:`MATERIAL` (a gain of at least 5 % at 95 % confidence). The best oracle names what a residual must
observe to gain it (:attr:`Variant.observes`): the friction events' timing (ahead of the edge, or at it), the
plant-model mismatch, or the whole episode in hindsight (its best constant current or width; the causal counterparts
are integral action and a scheduling action). The best is picked among several oracles on the same episodes, so its
CI is that oracle's own, not adjusted for the pick. The oracles are not bounds on what a residual can reach: each
knows one thing and uses it in one fixed way (the report shows ``dob-n2`` beside the best oracle).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ehss_gym.controllers import (
    CLFPolicy,
    ConstantResidualPolicy,
    FrictionFeedforwardPolicy,
    compensator_kind,
    compensator_loops,
    dob_rows,
    parse_scripted,
)
from ehss_gym.core.rig import Rig
from ehss_gym.envs import EnvConfig
from ehss_gym.envs.config import DEFAULTS
from ehss_gym.envs.law_table import LawTable
from ehss_gym.evaluation.harness import rollout
from ehss_gym.evaluation.scoring import (
    CLASSES,
    PHYSICAL_FLOORS,
    Block,
    Floors,
    episode_log_ratios,
    failure,
    figure_statistics,
    physical_floors,
    ratio_rows,
)
from ehss_gym.evaluation.specs import REFERENCE_POLICY
from ehss_gym.evaluation.suites import SUITE_ENV, SUITES, TASKS, EvalConfig, build_episodes
from ehss_gym.infra.execution import Executor, Job

from .corrections import corrections_job, delay_known, valve_known
from .corrections import summarize as summarize_corrections

PROG = "ehss headroom"
AGENT_PERIODS = (1, 5, 20)  # [control periods] the agent periods of the residuals that change their current
BASE_PERIOD = DEFAULTS.agent_period  # the reference law's agent period (the env's default, as ehss evaluate runs it)
FREE_PERIOD = 200  # [control periods] where the variants the agent period cannot change run (the fewest agent steps)
CHECK_SUITE = "heldout"  # the base law and the observer run at every agent period on this suite (the check)
MATERIAL = 0.05  # [-] material headroom: the CI's upper end below 1 - MATERIAL
MIN_EPISODES = 5  # a cell's CI counts only over at least this many episodes (a single paper run has none)
EPISODES = 32  # episodes per task and suite (a suite with more is subsampled evenly)
QUICK_EPISODES = 2


@dataclass(frozen=True)
class Search1D:
    """A per-episode 1-D bounded search: the grid (the base law's value first), then ``rounds`` refinement rounds, each
    trying every episode's incumbent times 10^(+-step) (the step halved each round; clipped to [lo, hi] in magnitude;
    an incumbent of 0 stays 0); an episode keeps a point only if it lowers its objective.

    Attributes:
        grid: the points every episode tries, after the base law's value (unit of the searched setting).
        lo, hi: the bounds of the magnitude (> 0).
        step: the first refinement step [decades].
        rounds: refinement rounds.
        unit: the setting's unit (for the report).
    """

    grid: tuple
    lo: float
    hi: float
    step: float
    rounds: int
    unit: str = ""

    def around(self, x: float, d: float) -> float:
        """x moved by d decades in magnitude, its sign kept, clipped to [lo, hi]; 0 stays 0."""
        if x == 0.0:
            return 0.0
        return math.copysign(min(max(abs(x) * 10.0 ** d, self.lo), self.hi), x)

    def describe(self) -> str:
        """The search in words."""
        pts = ", ".join(f"{v:.3g}" for v in self.grid)
        return (f"grid {{{pts}}} {self.unit}, then {self.rounds} refinement round(s) from a {self.step:g}-decade step, "
                f"magnitude within [{self.lo:g}, {self.hi:g}] {self.unit}")


_MAGNITUDES = tuple(float(v) for v in np.logspace(-2, 1, 7))  # 0.01 .. 10 mA, half-decade steps
# the constant residual current [mA]: 0 (the base law) first, then +-0.01..10 mA (the residual's whole range)
BIAS = Search1D(grid=tuple(s * m for m in _MAGNITUDES for s in (1.0, -1.0)), lo=0.01, hi=10.0, step=0.25,
                rounds=2, unit="mA")
# the smoothing width w [unit of s]: the env's default first, then 0 (the plain law) and 0.1 .. 1e5 in half decades
WIDTH = Search1D(grid=(0.0,) + tuple(float(v) for v in np.logspace(-1, 5, 13)), lo=0.1, hi=1e6, step=0.25,
                 rounds=1, unit="unit of s")
QUICK_BIAS = Search1D(grid=(0.3, -0.3, 3.0, -3.0), lo=0.01, hi=10.0, step=0.25, rounds=1, unit="mA")
QUICK_WIDTH = Search1D(grid=(0.0, 1.0, 1e3), lo=0.1, hi=1e6, step=0.5, rounds=1, unit="unit of s")


# --- the variants: one row each, and the function that runs it ---------------------------------------------


def _law(task: str, kw: dict, eps: list, search) -> tuple[list, list]:
    """The CLF law of ``kw`` (zero residual), as the harness runs it."""
    return rollout(CLFPolicy(EnvConfig.from_kwargs(kw)), kw, eps)[0], [None] * len(eps)


def _true_model(task: str, kw: dict, eps: list, search) -> tuple[list, list]:
    """The law with the true plant as its model (no parameter mismatch); the plant, events and noise unchanged."""
    same = [replace(ep, physical={**ep.physical, "model": None}) for ep in eps]
    return _law(task, kw, same, search)


class SideBySide:
    """Several policies on consecutive blocks of one batch (block k: the ``sizes[k]`` envs after the blocks before
    it), with SB3's ``predict``: the episodes of several policies in one rollout, which costs one agent step's overhead
    instead of one per policy."""

    def __init__(self, policies: Sequence, sizes: Sequence[int]):
        self.policies, self.cuts = list(policies), np.cumsum([0, *sizes])

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        """Each block's actions from its policy (its own state kept apart), concatenated."""
        acts, states = [], []
        for k, p in enumerate(self.policies):
            a, b = self.cuts[k], self.cuts[k + 1]
            act, st = p.predict(observation[a:b], state=None if state is None else state[k],
                                episode_start=None if episode_start is None else episode_start[a:b],
                                deterministic=deterministic)
            acts.append(np.asarray(act).reshape(b - a, -1))
            states.append(st)
        return np.concatenate(acts), states


def _grouped(kw: dict, eps: list, settings_of: Callable) -> list[dict]:
    """The law of ``kw`` on each episode with loop settings of its own (``settings_of(episode)`` -> dict), one rollout
    per distinct setting (a setting is the env's, the same for every episode of a rollout)."""
    groups: dict = {}
    for i, ep in enumerate(eps):
        groups.setdefault(tuple(sorted(settings_of(ep).items())), []).append(i)
    out: list = [None] * len(eps)
    for key, idx in groups.items():
        skw = {**kw, **dict(key)}
        for i, m in zip(idx, rollout(CLFPolicy(EnvConfig.from_kwargs(skw)), skw, [eps[i] for i in idx])[0]):
            out[i] = m
    return out


def _delay_of(ep) -> dict:
    """The loop settings that compensate an episode's own sensor delay."""
    return delay_known(ep.physical)


def _valve_of(ep) -> dict:
    """The loop settings that invert an episode's own valve."""
    return valve_known(ep.physical)


def _both_of(ep) -> dict:
    """Both compensations of an episode's own effects."""
    return {**_delay_of(ep), **_valve_of(ep)}


def _known(task: str, kw: dict, eps: list, search) -> dict:
    """The oracles that know the episode's unmodelled effects: its delay, its valve, and both."""
    delays = [_delay_of(ep)["reference_delay"] for ep in eps]
    return {"delay known": (_grouped(kw, eps, _delay_of), delays),
            "valve known": (_grouped(kw, eps, _valve_of), [None] * len(eps)),
            "both known": (_grouped(kw, eps, _both_of), delays)}


def _feedforward(task: str, kw: dict, eps: list, search) -> dict:
    """Both feed-forward oracles, centred on each edge and started at it, side by side in one rollout."""
    cfg, events, n = EnvConfig.from_kwargs(kw), [ep.physical["friction"] for ep in eps], len(eps)
    pol = SideBySide([FrictionFeedforwardPolicy(cfg, start_at_edge=edge, friction_by_lane=events)
                      for edge in (False, True)], (n, n))
    res = rollout(pol, kw, list(eps) * 2)[0]
    return {"ff centred": (res[:n], [None] * n), "ff at edge": (res[n:], [None] * n)}


def _objective(m: dict, ref: dict, noisy: bool, task: str, floors: Floors = PHYSICAL_FLOORS) -> float:
    """The ruler's per-episode overall log ratio of ``m`` against ``ref`` (an episode of ``task``, under the rig's
    ``floors``); inf for a failed episode or no class."""
    if m["diverged"] or m["lost_track"]:
        return math.inf
    logs = episode_log_ratios(m, ref, noisy, task, floors)
    return float(np.mean(list(logs.values()))) if logs else math.inf


def search_episodes(search: Search1D, first: float, run_values: Callable, noisy: Sequence[bool],
                    task: str, floors: Floors = PHYSICAL_FLOORS) -> tuple[list, list]:
    """:class:`Search1D` on every episode at once, minimising each episode's :func:`_objective` against its run at
    ``first`` (the base law's value, kept on ties).

    Args:
        search: the grid and refinement.
        first: the base law's value of the setting.
        run_values: (values, episode indices) -> the episodes' metrics with those values (one value per index).
        noisy: per episode, whether it has sensor noise (its effort class is chatter).
        task: the episodes' task (the ruler's floors).
        floors: the ruler's floors on the rig the episodes run on.

    Returns:
        (per episode the metrics at its best value, the best values).
    """
    N = len(noisy)
    tried: list[dict] = [{} for _ in range(N)]

    def metrics_at(values: list) -> list:
        need = [i for i in range(N) if values[i] not in tried[i]]
        if need:
            for i, m in zip(need, run_values([values[i] for i in need], need)):
                tried[i][values[i]] = m
        return [tried[i][values[i]] for i in range(N)]

    ref = metrics_at([first] * N)
    best = [first] * N
    obj = [0.0 if not (m["diverged"] or m["lost_track"]) else math.inf for m in ref]

    def consider(values: list) -> None:
        for i, m in enumerate(metrics_at(values)):
            o = _objective(m, ref[i], noisy[i], task, floors)
            if o < obj[i]:
                best[i], obj[i] = values[i], o

    for g in search.grid:
        consider([float(g)] * N)
    for r in range(search.rounds):
        d = search.step / 2.0 ** r
        for sgn in (-1.0, 1.0):
            consider([search.around(best[i], sgn * d) for i in range(N)])
    return [tried[i][best[i]] for i in range(N)], best


def _noisy(eps: list) -> list[bool]:
    return [any(v > 0.0 for v in ep.physical["noise_std"]) for ep in eps]


def _best_bias(task: str, kw: dict, eps: list, search: Search1D) -> tuple[list, list]:
    """Per episode the best constant residual current [mA] (:func:`search_episodes`); one rollout per point, each
    episode with its own current."""
    cfg = EnvConfig.from_kwargs(kw)

    def run_values(values, idx):
        return rollout(ConstantResidualPolicy(cfg, currents=values), kw, [eps[i] for i in idx])[0]

    return search_episodes(search, 0.0, run_values, _noisy(eps), task, physical_floors(cfg.plant))


def _best_width(task: str, kw: dict, eps: list, search: Search1D,
                settings_of: Callable = lambda ep: {}) -> tuple[list, list]:
    """Per episode the best smoothing width w [unit of s] of the law (:func:`search_episodes`), each episode with the
    loop settings ``settings_of(episode)`` besides (default none: the law as the env has it); one rollout per
    distinct width and setting (both are env settings, the same for every episode of a rollout)."""

    def run_values(values, idx):
        out: list = [None] * len(idx)
        for w in dict.fromkeys(values):
            at = [j for j, v in enumerate(values) if v == w]
            for j, m in zip(at, _grouped({**kw, "smoothing": w}, [eps[idx[j]] for j in at], settings_of)):
                out[j] = m
        return out

    cfg = EnvConfig.from_kwargs(kw)
    return search_episodes(search, float(cfg.loop.smoothing), run_values, _noisy(eps), task, physical_floors(cfg.plant))


def _delay_width(task: str, kw: dict, eps: list, search: Search1D) -> tuple[list, list]:
    """The episode's sensor delay known (:func:`_known`) and its best width in hindsight (:func:`_best_width`)."""
    return _best_width(task, kw, eps, search, _delay_of)


def _both_width(task: str, kw: dict, eps: list, search: Search1D) -> tuple[list, list]:
    """The episode's sensor delay and valve known (:func:`_known`) and its best width in hindsight."""
    return _best_width(task, kw, eps, search, _both_of)


@dataclass(frozen=True)
class Variant:
    """One row of :data:`VARIANTS`.

    Attributes:
        name: its label in the tables.
        kind: "base" (the reference law), "scripted" (a causal residual) or "oracle".
        policy: the scripted policy name whose env settings it acts in (:func:`ehss_gym.controllers.parse_scripted`).
        periods: the agent periods it runs at: "all" = :data:`AGENT_PERIODS`; "free" = :data:`FREE_PERIOD` only;
            "check" = the env's default (:data:`BASE_PERIOD`), and every agent period on :data:`CHECK_SUITE`, plus
            :data:`FREE_PERIOD` for the base law (:meth:`HeadroomConfig.periods_of`).
        period_free: the agent period cannot change its episodes (checked where it runs at several).
        observes: what a residual must observe to gain what it gains.
        run: (task, env kwargs, episodes, search) -> (per-episode metrics, per-episode chosen values or None), or a
            dict of those by variant name when it runs several variants at once.
        search: "bias" or "width": the :class:`Search1D` of :class:`HeadroomConfig` it takes; "" none.
        made_by: the variant whose run gives this one's episodes too (it has no job of its own).
        suites: the suites it runs on (empty: every suite).
    """

    name: str
    kind: str
    policy: str
    periods: str
    period_free: bool
    observes: str
    run: Callable | None = field(repr=False, compare=False)
    search: str = ""
    made_by: str = ""
    suites: tuple = ()


KNOWN_SUITES = ("unmodelled",)  # where the oracles that know the unmodelled effects run (elsewhere there are none)
CORRECTIONS_SUITE = "unmodelled"  # where the ideal corrections are measured
VARIANTS: tuple[Variant, ...] = (
    Variant("base law", "base", "clf-n2", "check", True, "(the reference: the env's tuned n = 2 law)", _law),
    Variant("dob-n2", "scripted", "dob-n2", "check", True,
            "nothing beyond the loop: the combined error s and the applied current (causal, every control period)",
            _law),
    Variant("dcomp-n2", "scripted", "dcomp-n2", "check", True,
            "the delay distribution's best single compensation per task, chosen on training episodes (causal: the "
            "law's reference delayed by a fixed number of samples; in velocity the rule chose none)", _law),
    Variant("vinv-n2", "scripted", "vinv-n2", "check", True,
            "the valve distribution's best single inverse per task, chosen on training episodes (causal: a fixed "
            "dead band and hysteresis inverted on the law's current; in position the rule chose none)", _law),
    Variant("eso-n2", "scripted", "eso-n2", "check", True,
            "the sensors' quantisation known only by its distribution (causal: the law's estimator the extended-state "
            "observer at a bandwidth chosen per task on training episodes; where the rule chose none, the base law)",
            _law),
    Variant("true model", "oracle", "clf-n2", "free", True,
            "the plant-model mismatch (the true plant's parameters)", _true_model),
    Variant("ff centred", "oracle", "clf-n2", "all", False,
            "each friction event's timing ahead of its edge, and its amplitude (not causal)", _feedforward),
    Variant("ff at edge", "oracle", "clf-n2", "all", False,
            "each friction event's timing at its edge, and its amplitude (causal once the event is known)",
            None, made_by="ff centred"),
    Variant("best bias", "oracle", "clf-n2", "free", True,
            "the whole episode in hindsight: its best constant current (causal counterpart: integral action)",
            _best_bias, "bias"),
    Variant("best width", "oracle", "clf-n2", "free", True,
            "the whole episode in hindsight: its best boundary-layer width (causal counterpart: a scheduling action "
            "on the width)", _best_width, "width"),
    Variant("delay known", "oracle", "clf-n2", "free", True,
            "the episode's sensor delay (the law's reference delayed by as many samples; causal counterpart: dcomp-n2, "
            "or a reference action)", _known, suites=KNOWN_SUITES),
    Variant("valve known", "oracle", "clf-n2", "free", True,
            "the episode's valve threshold and hysteresis (their inverse on the law's current; causal counterpart: "
            "vinv-n2)", None, made_by="delay known", suites=KNOWN_SUITES),
    Variant("both known", "oracle", "clf-n2", "free", True,
            "the episode's sensor delay and valve (both compensations)", None, made_by="delay known",
            suites=KNOWN_SUITES),
    Variant("delay known, best width", "oracle", "clf-n2", "free", True,
            "the episode's sensor delay, and in hindsight its best boundary-layer width with the delay compensated",
            _delay_width, "width", suites=KNOWN_SUITES),
    Variant("both known, best width", "oracle", "clf-n2", "free", True,
            "the episode's sensor delay and valve, and in hindsight its best boundary-layer width with both "
            "compensated", _both_width, "width", suites=KNOWN_SUITES),
)
VARIANT_BY_NAME = {v.name: v for v in VARIANTS}


# --- sizes, episodes and jobs --------------------------------------------------------------------------------


@dataclass(frozen=True)
class HeadroomConfig:
    """Sizes of the study.

    Attributes:
        episodes: episodes per task and suite (a suite with more is subsampled evenly, a smaller one kept whole).
        tasks: the tasks.
        agent_periods: the agent periods of the variants that run at several [control periods].
        bias, width: the per-episode searches of the best-bias and best-width oracles.
        quick: the CI form (:meth:`quick_config`).
        n_boot: bootstrap replicates.
        seed: bootstrap seed.
        plant: the rig the suites run on and the laws act on (``ehss evaluate``'s ``EvalConfig.plant``); None =
            Table I.
        law_settings: the laws' settings tuned for it (``EvalConfig.law_settings``); None = the built-in ones.
        base: the loop every variant runs on: ``clf-n2`` (the env's tuned n = 2 law, the default) or a scripted
            compensator's (``dcomp-n2``, ``vinv-n2``, ``eso-n2``: its row of each task added to every variant's
            settings, under the variant's own), so that the oracles measure what is left over that law. The base
            law's rows keep the label clf-n2.
    """

    episodes: int = EPISODES
    tasks: tuple = TASKS
    agent_periods: tuple = AGENT_PERIODS
    bias: Search1D = BIAS
    width: Search1D = WIDTH
    quick: bool = False
    n_boot: int = 2000
    seed: int = 0
    plant: Rig | None = None
    law_settings: LawTable | None = None
    base: str = REFERENCE_POLICY

    @classmethod
    def quick_config(cls, **changes) -> HeadroomConfig:
        """The CI form: 2 episodes per suite, the short suites of ``ehss evaluate --quick`` with one robustness level
        per sweep and a 2 s paper run (before its friction: no disturbance class there), agent periods 5 and 20, small
        searches, 500 bootstrap replicates; numbers not meaningful."""
        return replace(cls(episodes=QUICK_EPISODES, agent_periods=(5, 20), bias=QUICK_BIAS, width=QUICK_WIDTH,
                           quick=True, n_boot=500), **changes)

    def __post_init__(self):
        """Raises ValueError naming the first setting out of range."""
        if isinstance(self.episodes, bool) or not isinstance(self.episodes, int) or self.episodes < 1:
            raise ValueError(f"episodes must be an integer >= 1 (per task and suite), got {self.episodes!r}")
        if not self.tasks or any(t not in TASKS for t in self.tasks):
            raise ValueError(f"tasks must be a non-empty subset of {list(TASKS)}, got {list(self.tasks)}")
        if self.base != REFERENCE_POLICY and (compensator_kind(self.base) is None or not self.base.endswith("-n2")):
            raise ValueError(f"base must be {REFERENCE_POLICY} or a scripted compensator's n = 2 name (dcomp-n2, "
                             f"vinv-n2, eso-n2), got {self.base!r}")
        if BASE_PERIOD not in self.agent_periods or any(not isinstance(p, int) or p < 1 for p in self.agent_periods):
            raise ValueError(f"agent_periods must be integers >= 1 including the env's default {BASE_PERIOD}, got "
                             f"{list(self.agent_periods)}")

    def eval_config(self) -> EvalConfig:
        """The suites' sizes (``ehss evaluate``'s, or its quick form's)."""
        if self.quick:
            return EvalConfig.quick(tasks=self.tasks, heldout_episodes=self.episodes, paper_seconds=2.0,
                                    friction_levels=(1.8,), mismatch_levels=(0.2,), step_amplitudes=(0.5,),
                                    plant=self.plant, law_settings=self.law_settings)
        return EvalConfig(tasks=self.tasks, heldout_episodes=self.episodes, plant=self.plant,
                          law_settings=self.law_settings)

    def base_settings(self, task: str) -> dict:
        """The loop settings :attr:`base` adds on ``task`` ({} for clf-n2, or where its rule chose none)."""
        kind = compensator_kind(self.base)
        return {} if kind is None else compensator_loops(kind, (task,), self.law_settings).get(task, {})

    def periods_of(self, v: Variant, suite: str = CHECK_SUITE) -> tuple:
        """The agent periods variant ``v`` runs at on ``suite`` (:attr:`Variant.periods`)."""
        if v.periods == "all":
            return tuple(self.agent_periods)
        if v.periods == "free":
            return (FREE_PERIOD,)
        own = tuple(self.agent_periods) if suite == CHECK_SUITE else (BASE_PERIOD,)
        return own + ((FREE_PERIOD,) if v.kind == "base" else ())


def suite_episodes(cfg: HeadroomConfig, task: str) -> dict[str, list]:
    """Suite -> its episodes of ``task`` (every suite of :data:`SUITES` that has some), at most ``cfg.episodes`` each,
    taken evenly over the suite's order (so a sweep keeps its levels)."""
    eps = build_episodes(replace(cfg.eval_config(), tasks=(task,)))
    out = {}
    for suite in SUITES:
        sel = [ep for ep in eps if ep.suite == suite]
        if len(sel) > cfg.episodes:
            sel = [sel[int(i)] for i in np.unique(np.linspace(0, len(sel) - 1, cfg.episodes).round().astype(int))]
        if sel:
            out[suite] = sel
    return out


def variant_job(config: dict, seed: int, context) -> dict:
    """An executor job: one variant on one (task, suite) at one agent period; plain data back."""
    v = VARIANT_BY_NAME[config["variant"]]
    out = v.run(config["task"], config["env_kwargs"], config["episodes"], config["search"])
    first = None  # the base law's value of a searched setting
    if v.search == "bias":
        first = 0.0
    elif v.search == "width":
        first = float(EnvConfig.from_kwargs(config["env_kwargs"]).loop.smoothing)
    elif v.suites == KNOWN_SUITES:
        first = 0.0  # the base law's reference delay
    made = out if isinstance(out, dict) else {v.name: out}
    return {name: {"metrics": m, "values": vals, "first": first} for name, (m, vals) in made.items()}


def variant_config(cfg: HeadroomConfig, v: Variant, task: str, suite: str, eps: list, ap: int,
                   env_suite: str | None = None) -> dict:
    """The job config of variant ``v`` on ``eps`` of (task, suite) at agent period ``ap`` (:func:`variant_job`); the
    env settings are those of suite ``env_suite`` (default: ``suite``)."""
    ev = cfg.eval_config()  # its law table's compensator rows replace Table I's, where one is given
    kw = {"task": task, **cfg.base_settings(task), **parse_scripted(v.policy, task, ev.law_settings),
          **SUITE_ENV.get(env_suite or suite, {}), "agent_period": ap, **ev.env_kwargs(), **_dob_row(v, task, cfg)}
    return {"variant": v.name, "task": task, "suite": suite, "agent_period": ap, "env_kwargs": kw, "episodes": eps,
            "search": getattr(cfg, v.search) if v.search else None}


def plan(cfg: HeadroomConfig) -> list[Job]:
    """Every job of the study: per task, suite, variant and agent period."""
    jobs = []
    for task in cfg.tasks:
        for suite, eps in suite_episodes(cfg, task).items():
            for v in (v for v in VARIANTS if not v.made_by and (not v.suites or suite in v.suites)):
                for ap in cfg.periods_of(v, suite):
                    jobs.append(Job(variant_job, variant_config(cfg, v, task, suite, eps, ap), seed=0,
                                    label=f"{task}/{suite}/{v.name}@{ap}"))
        eps = suite_episodes(cfg, task).get(CORRECTIONS_SUITE)
        if eps:  # the ideal corrections' sizes (ehss_gym.study.corrections)
            kw = {"task": task, **cfg.base_settings(task), **parse_scripted(REFERENCE_POLICY, task),
                  **cfg.eval_config().env_kwargs()}
            jobs.append(Job(corrections_job, {"corrections": True, "task": task, "suite": CORRECTIONS_SUITE,
                                              "env_kwargs": kw, "episodes": eps, "agent_period": FREE_PERIOD,
                                              "search": None, "variant": "corrections"}, seed=0,
                            label=f"{task}/{CORRECTIONS_SUITE}/corrections"))
    # the longest first keeps both workers busy to the end: agent steps x searched points, roughly
    return sorted(jobs, key=lambda j: -_cost(j.config))


def _dob_row(v: Variant, task: str, cfg: HeadroomConfig) -> dict:
    """The observer's settings tuned for the plant (:func:`ehss_gym.controllers.dob_rows`: the law table's row of
    ``task``, without a table the built-in tuning) for ``dob-n2``; {} else."""
    return dob_rows((task,), cfg.law_settings).get(task, {}) if v.policy == "dob-n2" else {}


def _cost(c: dict) -> float:
    seconds = sum(ep.t_end for ep in c["episodes"])
    points = {"ff centred": 2, "delay known": 3, "corrections": 6}.get(c["variant"], 1) if c["search"] is None else \
        len(c["search"].grid) + 2 * c["search"].rounds + 1
    return seconds * points * (1.0 + 4.0 / c["agent_period"])  # the per-agent-step Python cost grows as 1/period


# --- statistics ----------------------------------------------------------------------------------------------


def label(v: Variant, ap: int, cfg: HeadroomConfig) -> str:
    """A variant's row label: the reference law is :data:`REFERENCE_POLICY` at :data:`BASE_PERIOD`; a variant that
    runs at several agent periods carries its period."""
    if v.kind == "base" and ap == BASE_PERIOD:
        return REFERENCE_POLICY
    return v.name if v.periods == "free" else f"{v.name} @{ap}"


def row_meta(cfg: HeadroomConfig) -> dict:
    """Row label -> its variant's name, kind, agent period, what it observes and whether the period cannot matter."""
    return {label(v, ap, cfg): {"variant": v.name, "kind": v.kind, "agent_period": ap, "observes": v.observes,
                                "period_free": v.period_free}
            for v in VARIANTS for ap in dict.fromkeys(cfg.periods_of(v, CHECK_SUITE) + cfg.periods_of(v, ""))}


def episode_rows(done: list[tuple[Job, dict]], cfg: HeadroomConfig) -> list[dict]:
    """Harness-like per-episode rows (suite, task, policy, run, episode, noisy, metrics; a searched oracle's chosen
    value and the base law's value of its setting) of finished jobs."""
    rows = []
    for job, made in done:
        c = job.config
        for variant, res in made.items():
            name = label(VARIANT_BY_NAME[variant], c["agent_period"], cfg)
            for ep, m, val in zip(c["episodes"], res["metrics"], res["values"]):
                rows.append({**m, "suite": c["suite"], "task": c["task"], "policy": name, "run": 0,
                             "episode": ep.episode_id, "noisy": any(v > 0.0 for v in ep.physical["noise_std"]),
                             "value": val, "first": res["first"]})
    return rows


def period_check(rows: list, v: Variant, cfg: HeadroomConfig, suite: str, task: str) -> dict | None:
    """Whether the agent period changed the class metrics of a variant that runs at several periods: the largest
    relative difference of any class metric between its periods (0 = the same to the last bit), None if it runs at
    one."""
    periods = cfg.periods_of(v, suite)
    if len(periods) < 2:
        return None
    by = {ap: {r["episode"]: r for r in rows if r["policy"] == label(v, ap, cfg) and r["suite"] == suite
               and r["task"] == task} for ap in periods}
    keys = ("trk_rmse", "trk_iae", "dst_peak", "dst_iae", "tv_u_rate", "rms_u")
    worst = 0.0
    for e, r0 in by[periods[0]].items():
        for ap in periods[1:]:
            r1 = by[ap][e]
            for k in keys:
                a, b = float(r0[k]), float(r1[k])
                if a != b and not (math.isnan(a) and math.isnan(b)):
                    worst = max(worst, abs(a - b) / max(abs(a), abs(b), 1e-300))
    return {"variant": v.name, "suite": suite, "task": task, "periods": periods, "max_rel_diff": worst}


def block_stats(rows: list, suite: str, task: str, names: list, meta: dict, cfg: HeadroomConfig) -> list[dict]:
    """Per policy of one (task, suite): class and overall figures against the base law with CIs, and the gate."""
    blk = Block(rows, names, suite, task)
    ecfg = EvalConfig(n_boot=cfg.n_boot, seed=cfg.seed)
    out = []
    for name in names:
        sel = [r for r in rows if r["policy"] == name and r["suite"] == suite and r["task"] == task]
        failed, n_failed = failure(sel)
        d = {"task": task, "suite": suite, "policy": name, **meta[name], "failed": failed, "n_failed": n_failed}
        d.update(figure_statistics(blk, name, ecfg))
        vals = [r["value"] for r in sel if r["value"] is not None]
        d["value_median"] = float(np.median(vals)) if vals else math.nan
        d["value_moved"] = sum(1 for r in sel if r["value"] is not None and r["value"] != r["first"])
        out.append(d)
    return out


def headroom(stats: list[dict], classes: Sequence[str]) -> dict:
    """The rule of the module docstring on one (task, suite): per class and overall the best passing oracle."""
    oracles = [d for d in stats if d["kind"] == "oracle" and not d["failed"]]
    out = {}
    for key in tuple(classes) + ("figure",):
        cands = [d for d in oracles if math.isfinite(d.get(key, math.nan))]
        if not cands:
            continue
        b = min(cands, key=lambda d: d[key])
        hi, n = b[f"{key}_hi"], b["n_used"] if key == "figure" else b[f"{key}_n"]
        few = n < MIN_EPISODES
        out["overall" if key == "figure" else key] = {
            "oracle": b["policy"], "ratio": b[key], "lo": b[f"{key}_lo"], "hi": hi, "observes": b["observes"],
            "n": n, "few": few, "has": hi < 1.0 and not few, "material": hi < 1.0 - MATERIAL and not few}
    return out


def run(cfg: HeadroomConfig | None = None, executor: Executor | None = None, progress: bool = False) -> dict:
    """Run every job (on ``executor``, default in this process) and tabulate.

    Returns:
        {"cfg", "blocks" (per task and suite: "task", "suite", "episodes", "classes", "stats" (one row per policy:
        :func:`block_stats`), "headroom" (:func:`headroom`), "checks" (:func:`period_check`)), "corrections" (per
        task the ideal corrections' sizes on the unmodelled suite: :func:`ehss_gym.study.corrections.summarize`),
        "jobs", "computed", "skipped", "wall_s"}.
    """
    t0 = time.perf_counter()
    cfg = cfg or HeadroomConfig()
    executor = executor or Executor(progress=progress)
    jobs = plan(cfg)
    done = list(zip(jobs, executor.map(jobs, desc=PROG)))
    corrections = {j.config["task"]: summarize_corrections(r, j.config["task"]) for j, r in done
                   if j.config.get("corrections")}
    rows = episode_rows([(j, r) for j, r in done if not j.config.get("corrections")], cfg)
    ratio_rows(rows, physical_floors(cfg.eval_config().rig))
    meta = row_meta(cfg)
    blocks = []
    for task in cfg.tasks:
        for suite in SUITES:
            present = [n for n in meta if any(r["policy"] == n and r["suite"] == suite and r["task"] == task
                                              for r in rows)]
            if not present:
                continue
            stats = block_stats(rows, suite, task, present, meta, cfg)
            classes = [c for c in CLASSES if any(math.isfinite(d.get(c, math.nan)) for d in stats)]
            checks = [c for v in VARIANTS if (c := period_check(rows, v, cfg, suite, task)) is not None]
            n_eps = len({r["episode"] for r in rows if r["suite"] == suite and r["task"] == task})
            blocks.append({"task": task, "suite": suite, "episodes": n_eps, "classes": classes, "stats": stats,
                           "headroom": headroom(stats, classes), "checks": checks})
    return {"cfg": cfg, "blocks": blocks, "corrections": corrections, "jobs": len(jobs), "computed": executor.computed,
            "skipped": executor.skipped, "wall_s": time.perf_counter() - t0}


__all__ = ["PROG", "AGENT_PERIODS", "BASE_PERIOD", "FREE_PERIOD", "MATERIAL", "MIN_EPISODES", "EPISODES", "CHECK_SUITE",
           "Search1D", "BIAS", "WIDTH", "Variant", "VARIANTS", "VARIANT_BY_NAME", "SideBySide", "HeadroomConfig",
           "suite_episodes", "search_episodes", "plan", "variant_config", "variant_job", "label", "row_meta",
           "episode_rows", "block_stats", "period_check", "headroom", "run"]
