"""One tuning procedure for every scripted baseline, and the rule that turns its results into the env's defaults.

**The baselines** (:data:`BASELINES`, one row each): per task the CLF law for n = 2, 4, 6 (sigma, f_r, the smoothing
width w with 0 allowed, the boundary-layer gain with 0 = the fixed layer and > 0 the adaptive one) and the PID (its
gains kp, ki, kd, +-2 decades around the relay procedure's gains, :data:`PID_START`). A row names its task, its
parameter space (log grids with ranges, :class:`Axis`), its fixed settings, the settings it takes from another
row's result (``inherit``: a residual on the n = 2 law takes that law's tuned sigma and f_r) and how a candidate
becomes episodes (:data:`RUNNERS`: the CLF laws through :func:`ehss_gym.core.sim.simulate_batch`, the PID through the
env's rollout loop, as ``ehss evaluate`` runs it). Adding a baseline is one row (the disturbance-observer residual's:
``*[dob_row(t) for t in TASKS]``, :func:`dob_row`).

**The objective**: the evaluation ruler's overall figure G (:mod:`ehss_gym.evaluation.scoring`: per-episode class log
ratios, class figures, their geometric mean) of the candidate against a fixed anchor, the env's default law as it
was before this tuning (:data:`ANCHOR`), on the same episodes of the training distribution only
(``sample_scenario(seed, template)`` for seeds 0..K-1, 2 s; the held-out seeds are >= 2^62 and never drawn). The
failure gate: any diverged or lost-track episode, or a mean saturation share above 0.10, makes a candidate
infeasible; candidates are ordered as the ruler ranks policies (:func:`~ehss_gym.evaluation.scoring.rank_key`:
feasible first by G, then the infeasible by failed episodes, then G), so the search can climb out of an infeasible
start.

**The search** (:func:`search`, the same for every row, deterministic, budget B evaluations): start at the row's
start point; for each axis in the row's order evaluate its grid points (the others fixed) and keep the best; then
refinement rounds, each halving the log step, try the incumbent times 10^(+-step) on each axis (within its range;
an axis whose incumbent is its 0 point is left there) and keep any improvement, until B distinct points are spent.

**The defaults rule** (written before the held-out suite was run; :func:`default_n`): per task, the env's default
law is the tuned CLF baseline with the lowest objective; a smaller n is kept unless a larger one is lower by more
than 2 %. The env's per-n defaults are each n's tuned values (``ehss_gym.envs.config``, checked against tuned.json).

**The compensators** (:func:`compensators`, the last stage): the scripted compensations of the unmodelled valve and
sensors, ``dcomp-n2`` (the law's reference delayed) and ``vinv-n2`` (the valve's dead band and hysteresis inverted),
are sized per task on the tuned n = 2 law by their own rule (:mod:`ehss_gym.study.compensators`: every point of a
small grid whose 0 is "off", on 48 training seeds drawn with the unmodelled effects (in the quick form too), against
that law; the grid is searched whole because its rule sends a tie to the smaller compensation, which a search from a
start cannot promise).

**Another plant** (``TuneSettings.plant``, ``ehss baselines --plant FILE``): the same rows, search, objective and
rule, on training scenarios drawn around that plant (:func:`ehss_gym.core.scenarios.sample_scenario` on a template
carrying it), with its rated current as the limit; the PID starts at the relay procedure's gains on that plant
(:func:`ehss_gym.controllers.tune_pid`). The result is also written as a law table
(:mod:`ehss_gym.envs.law_table`, ``law_settings.json``), which ``--law-settings FILE`` and the env's
``law_settings`` take. After the search, the tuned n = 2 law and the untuned one are checked on held-out episodes
(:mod:`ehss_gym.study.friction_windows`: saturation, limit cycles through the friction events); the check does not
feed back into the search.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ehss_gym.controllers import PIDPolicy, tune_pid
from ehss_gym.controllers.pid import PID_RELAY_GAINS
from ehss_gym.core.rig import Rig, as_rig
from ehss_gym.core.scenarios import sample_scenario
from ehss_gym.core.sim import simulate_batch
from ehss_gym.envs import EnvConfig
from ehss_gym.envs.config import PlantWarning
from ehss_gym.envs.law_table import table_from_dict
from ehss_gym.envs.rollouts import rollout
from ehss_gym.evaluation.scoring import gated_figure as objective  # the ruler's figure with the gate
from ehss_gym.evaluation.scoring import physical_floors
from ehss_gym.evaluation.suites import TASKS

from .compensators import tune_compensators
from .friction_windows import check as friction_check

PROG = "ehss baselines"
BUDGET = 64  # evaluations per baseline
EPISODES = 48  # training scenario seeds 0..EPISODES-1
QUICK_BUDGET = 32  # the quick form's evaluations per baseline: one pass over every grid (25 points for a law) and more
QUICK_EPISODES = 12  # the quick form's training scenarios
CHECK_EPISODES = 48  # held-out episodes of the check after the search (the held-out suite's size)
COMPENSATOR_EPISODES = 48  # training scenarios of the compensators' sweep, in both forms (TuneSettings)
EPISODE_SECONDS = 2.0  # [s]
KEEP_MARGIN = 0.02  # the defaults rule: a larger n replaces a smaller one only if its objective is lower by more
LAW_NS = (2, 4, 6)
# The anchor of the objective: the env's default law (n = 2) as it was before this tuning, per task (sigma [unit of
# s], f_r [Hz], smoothing w [unit of s], layer_gain [-]); frozen here so that a rerun after the defaults changed
# measures against the same law.
ANCHOR = {"velocity": {"n": 2, "sigma": 1e5, "fr": 60.0, "smoothing": 1e3, "layer_gain": 3.0},
          "position": {"n": 2, "sigma": 1e6, "fr": 20.0, "smoothing": 100.0, "layer_gain": 3.0}}
# The PID's start (kp [mA/U], ki [mA/(U s)], kd [mA s/U], U the output unit): the relay procedure's gains
# (ehss_gym.controllers.tune_pid, stored as PID_RELAY_GAINS) for the direct mode, which is how `ehss evaluate` runs
# the PID.
PID_START = {t: dict(zip(("kp", "ki", "kd"), PID_RELAY_GAINS[(t, "direct")])) for t in TASKS}


@dataclass(frozen=True)
class Axis:
    """One searched parameter: a log grid on [lo, hi] with a step of ``step`` decades (rounded so that both ends
    are on it), plus the value 0 when ``zero`` (the setting switched off).

    Attributes:
        name: the env setting (or the PID gain) it sets.
        lo, hi: the range, both > 0, in the setting's unit.
        step: the grid's log step [decades].
        zero: 0 is a point of the grid too.
        unit: the setting's unit (for the report).
    """

    name: str
    lo: float
    hi: float
    step: float
    zero: bool = False
    unit: str = ""

    @property
    def points(self) -> int:
        """Grid points on [lo, hi]."""
        return max(2, round(math.log10(self.hi / self.lo) / self.step) + 1)

    @property
    def log_step(self) -> float:
        """The grid's actual log step [decades]."""
        return math.log10(self.hi / self.lo) / (self.points - 1)

    def grid(self) -> list[float]:
        """The grid: 0 first (if allowed), then lo .. hi."""
        g = [float(v) for v in np.logspace(math.log10(self.lo), math.log10(self.hi), self.points)]
        return ([0.0] if self.zero else []) + g

    def around(self, x: float, step: float) -> list[float]:
        """x * 10^(-step) and x * 10^(+step), clipped to [lo, hi]; none if x is the 0 point."""
        if x == 0.0:
            return []
        return [min(max(x * 10.0 ** (sgn * step), self.lo), self.hi) for sgn in (-1.0, 1.0)]

    def describe(self) -> str:
        """The grid in words."""
        return (f"log {self.lo:g}..{self.hi:g}{' ' + self.unit if self.unit else ''}, {self.points} points "
                f"({self.log_step:.3g} decade step){' plus 0' if self.zero else ''}")


@dataclass(frozen=True)
class Baseline:
    """One row of :data:`BASELINES`.

    Attributes:
        name: "<task>/<policy>" (the policy's ``ehss evaluate`` name).
        task: "velocity" or "position".
        runner: a key of :data:`RUNNERS` (how a candidate becomes episodes).
        axes: the searched parameters, in the search's order.
        start: the start point (every axis' name -> value).
        fixed: env settings held fixed (n, for a law).
        inherit: (row name, settings) pairs taken from that row's tuned result (it must come earlier in the
            table): a searched setting starts there, any other is held there.
    """

    name: str
    task: str
    runner: str
    axes: tuple
    start: dict
    fixed: dict = field(default_factory=dict)
    inherit: tuple = ()

    @property
    def policy(self) -> str:
        """The policy's name in ``ehss evaluate``."""
        return self.name.split("/", 1)[1]


def law_axes(task: str) -> tuple[Axis, ...]:
    """The CLF law's space on ``task``: sigma, f_r, the smoothing width and the boundary-layer gain."""
    sig = (1e2, 1e9) if task == "velocity" else (1e3, 1e10)
    fr = (20.0, 200.0) if task == "velocity" else (5.0, 60.0)
    return (Axis("sigma", *sig, 1.0, unit="unit of s"), Axis("fr", *fr, 0.25, unit="Hz"),
            Axis("smoothing", 1e-1, 1e6, 1.0, zero=True, unit="unit of s"),
            Axis("layer_gain", 0.3, 30.0, 0.5, zero=True))


def pid_axes(task: str) -> tuple[Axis, ...]:
    """The PID's space: each gain +-2 decades around :data:`PID_START`, half-decade grid."""
    units = {"kp": "mA/U", "ki": "mA/(U s)", "kd": "mA s/U"}
    return tuple(Axis(k, v / 100.0, v * 100.0, 0.5, unit=units[k]) for k, v in PID_START[task].items())


def _law_row(task: str, n: int) -> Baseline:
    start = {k: v for k, v in ANCHOR[task].items() if k != "n"}
    return Baseline(f"{task}/clf-n{n}", task, "law", law_axes(task), start, {"n": n})


def _pid_row(task: str) -> Baseline:
    return Baseline(f"{task}/pid", task, "pid", pid_axes(task), dict(PID_START[task]))


def dob_row(task: str) -> Baseline:
    """The disturbance-observer residual on the n = 2 law (loop setting ``dob_hz``, its cutoff f_d [Hz]): f_d on a
    log grid 1..500 Hz, then the smoothing width and the boundary layer (starting at the n = 2 law's tuned values),
    with that law's tuned sigma and f_r. Its row in :data:`BASELINES` goes after the n = 2 law's, where the loop has
    the setting."""
    axes = (Axis("dob_hz", 1.0, 500.0, 0.25, unit="Hz"), *law_axes(task)[2:])
    inherit = ((f"{task}/clf-n2", ("sigma", "fr", "smoothing", "layer_gain")),)
    return Baseline(f"{task}/dob-n2", task, "law", axes, {"dob_hz": 20.0}, {"n": 2}, inherit=inherit)


BASELINES: tuple[Baseline, ...] = tuple(
    [_law_row(t, n) for t in TASKS for n in LAW_NS] + [_pid_row(t) for t in TASKS] + [dob_row(t) for t in TASKS])


def pid_start(task: str, plant: Rig | None) -> dict:
    """The PID row's start (kp, ki, kd): the relay procedure's gains in direct mode, on ``plant`` (Table I's stored
    gains without one)."""
    if plant is None:
        return dict(PID_START[task])
    gains = tune_pid(EnvConfig.from_kwargs({"task": task, "mode": "direct", "plant": plant}), progress=False)["gains"]
    return dict(zip(("kp", "ki", "kd"), gains))


def baselines_for(plant: Rig | None) -> tuple[Baseline, ...]:
    """:data:`BASELINES` for ``plant``: the PID rows' start and gain ranges around the relay gains on it."""
    if plant is None:
        return BASELINES
    out = []
    for row in BASELINES:
        if row.runner == "pid":
            start = pid_start(row.task, plant)
            units = {ax.name: ax.unit for ax in row.axes}
            axes = tuple(Axis(k, v / 100.0, v * 100.0, 0.5, unit=units[k]) for k, v in start.items())
            row = replace(row, axes=axes, start=start)
        out.append(row)
    return tuple(out)


# --- how a candidate becomes episodes ------------------------------------------------------------------------


def scenario_seeds(episodes: int = EPISODES) -> range:
    """The training scenario seeds of the objective."""
    return range(episodes)


def _scenarios(env_kwargs: dict, episodes: int, seconds: float) -> list:
    """The training scenarios (seeds 0..episodes-1) on the template of ``env_kwargs`` (its plant's)."""
    template = EnvConfig.from_kwargs(env_kwargs).template()
    return [sample_scenario(s, template, seconds) for s in scenario_seeds(episodes)]


def law_metrics(task: str, settings: dict, episodes: int, seconds: float) -> list[dict]:
    """Per-episode metrics of the CLF law (zero residual) at env settings ``settings`` (simulate_batch)."""
    return [t.metrics() for t in simulate_batch(_scenarios({"task": task, **settings}, episodes, seconds))]


def pid_metrics(task: str, settings: dict, episodes: int, seconds: float) -> list[dict]:
    """Per-episode metrics of the PID (direct mode, as ``ehss evaluate`` runs it) with gains kp, ki, kd."""
    kw = {"task": task, "mode": "direct", **({"plant": settings["plant"]} if "plant" in settings else {})}
    cfg = EnvConfig.from_kwargs(kw)
    pol = PIDPolicy(cfg, gains=(settings["kp"], settings["ki"], settings["kd"]))
    return [r.metrics for r in rollout(pol, kw, _scenarios(kw, episodes, seconds), name="pid")]


RUNNERS: dict[str, Callable[[str, dict, int, float], list[dict]]] = {"law": law_metrics, "pid": pid_metrics}


# --- the objective -------------------------------------------------------------------------------------------


# --- the search ----------------------------------------------------------------------------------------------


def _point_key(point: dict) -> tuple:
    return tuple((k, float(f"{v:.12g}")) for k, v in sorted(point.items()))


class Search:
    """The coordinate search of the module docstring on ``axes`` with budget ``budget``, minimising ``evaluate``
    (point -> a dict with "key", the order; lower is better). Evaluations are remembered: a point seen before costs
    nothing."""

    MAX_ROUNDS = 200  # refinement rounds at most (a round always offers a new point unless every axis is at 0)

    def __init__(self, axes: Sequence[Axis], start: dict, evaluate: Callable[[dict], dict], budget: int,
                 progress: Callable[[], None] | None = None):
        self.axes, self.evaluate, self.budget, self.progress = tuple(axes), evaluate, int(budget), progress
        self.seen: dict[tuple, dict] = {}
        self.history: list[dict] = []
        self.best, self.best_out = dict(start), None
        self._phase = "start"

    @property
    def used(self) -> int:
        """Evaluations spent."""
        return len(self.history)

    def _try(self, point: dict) -> bool:
        """Evaluate ``point`` (unless seen or the budget is spent); True if it became the incumbent."""
        key = _point_key(point)
        if key in self.seen or self.used >= self.budget:
            return False
        out = self.evaluate(dict(point))
        self.seen[key] = out
        self.history.append({"point": dict(point), **{k: v for k, v in out.items() if k != "key"},
                             "phase": self._phase})
        if self.progress:
            self.progress()
        if self.best_out is None or out["key"] < self.best_out["key"]:
            self.best, self.best_out = dict(point), out
            return True
        return False

    def run(self) -> dict:
        """Search until the budget is spent; returns {"best", "best_out", "used", "history"}."""
        self._phase = "start"
        self._try(self.best)
        self._phase = "grid"
        for ax in self.axes:
            anchor = dict(self.best)  # the axis' points, the other axes at the incumbent of the pass's start
            for v in ax.grid():
                self._try({**anchor, ax.name: v})
        steps = {ax.name: ax.log_step for ax in self.axes}
        for r in range(self.MAX_ROUNDS):
            if self.used >= self.budget:
                break
            self._phase = f"refine {r + 1}"
            for ax in self.axes:
                steps[ax.name] /= 2.0
                anchor = dict(self.best)
                for v in ax.around(anchor[ax.name], steps[ax.name]):
                    self._try({**anchor, ax.name: v})
        return {"best": self.best, "best_out": self.best_out, "used": self.used, "history": self.history}


def search(axes: Sequence[Axis], start: dict, evaluate: Callable[[dict], dict], budget: int = BUDGET,
           progress: Callable[[], None] | None = None) -> dict:
    """:class:`Search` of ``axes`` from ``start`` within ``budget`` evaluations of ``evaluate``."""
    return Search(axes, start, evaluate, budget, progress).run()


# --- tuning every row ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TuneSettings:
    """What :func:`tune` measures on.

    Attributes:
        budget: evaluations per baseline.
        episodes: training scenarios (seeds 0..episodes-1).
        seconds: their duration [s].
        rows: the baselines' names (default all of :data:`BASELINES`).
        plant: the rig the training scenarios are drawn around (None: Table I).
        check_episodes: held-out episodes of the check after the search (:mod:`ehss_gym.study.friction_windows`;
            0: no check).
        compensator_episodes: training scenarios with the unmodelled effects (seeds 0..N-1) of the last stage, the
            compensators' sweep (:func:`compensators`; 0: not run). The quick form keeps the full run's 48: on the
            compact 140 bar rig 12 episodes chose a valve inverse in velocity (0.865 there) that 48 do not (none
            within 1 % of the best) and that the unmodelled suite scores at 1.05, worse than the law alone.
    """

    budget: int = BUDGET
    episodes: int = EPISODES
    seconds: float = EPISODE_SECONDS
    rows: tuple = ()
    plant: Rig | None = None
    check_episodes: int = CHECK_EPISODES
    compensator_episodes: int = COMPENSATOR_EPISODES

    @classmethod
    def quick(cls, **changes) -> TuneSettings:
        """The quick form, a few minutes on two cores: 12 training episodes of 2 s, 32 evaluations per baseline
        (one pass over every grid and a refinement round; coarser than the full run)."""
        return replace(cls(budget=QUICK_BUDGET, episodes=QUICK_EPISODES), **changes)

    def env_kwargs(self) -> dict:
        """The env settings every candidate gets from the settings: the plant, when one was given."""
        return {} if self.plant is None else {"plant": self.plant}


def _noisy(task: str, episodes: int, seconds: float, env: dict) -> list[bool]:
    return [any(v > 0.0 for v in sc.noise_std) for sc in _scenarios({"task": task, **env}, episodes, seconds)]


def tune_row(row: Baseline, tuned: dict, cfg: TuneSettings, anchors: dict, progress=None) -> dict:
    """Tune one row (its inherited settings taken from ``tuned``, the rows tuned before it)."""
    fixed, start = dict(row.fixed), dict(row.start)
    names = {ax.name for ax in row.axes}
    for src, keys in row.inherit:  # an inherited searched setting is the start there, any other one is fixed
        for k in keys:
            (start if k in names else fixed)[k] = tuned[src]["settings"][k]
    anchor, noisy = anchors[row.task]
    run = RUNNERS[row.runner]
    floors = physical_floors(as_rig(cfg.plant))

    def evaluate(point: dict) -> dict:
        return objective(run(row.task, {**fixed, **point, **cfg.env_kwargs()}, cfg.episodes, cfg.seconds), anchor,
                         noisy, row.task, floors)

    res = search(row.axes, start, evaluate, cfg.budget, progress)
    out = res["best_out"]
    return {"name": row.name, "policy": row.policy, "task": row.task, "runner": row.runner, "fixed": fixed,
            "settings": {**fixed, **res["best"]}, "tuned": res["best"], "start": start,
            "objective": out["figure"], "classes": out["classes"], "failed": out["failed"],
            "n_failed": out["n_failed"], "saturation": out["saturation"], "evaluations_used": res["used"],
            "space": {ax.name: ax.describe() for ax in row.axes},
            "evaluations": [_json_eval(h) for h in res["history"]]}


def _json_eval(h: dict) -> dict:
    return {"point": h["point"], "objective": h["figure"], "classes": h["classes"], "failed": h["failed"],
            "n_failed": h["n_failed"], "saturation": h["saturation"], "phase": h["phase"]}


def anchors_of(cfg: TuneSettings, tasks: Sequence[str]) -> dict:
    """Per task (the anchor law's per-episode metrics, the episodes' noise flags)."""
    env = cfg.env_kwargs()
    return {t: (law_metrics(t, {**ANCHOR[t], **env}, cfg.episodes, cfg.seconds),
                _noisy(t, cfg.episodes, cfg.seconds, env)) for t in tasks}


def default_n(tuned: dict, task: str, ns: Sequence[int] = LAW_NS, margin: float = KEEP_MARGIN) -> dict:
    """The defaults rule: the task's default n and why (module docstring).

    Args:
        tuned: row name -> tuned result (``objective``, ``failed``, ``n_failed``).
        task: the task.
        ns: the law's n, ascending.
        margin: a larger n replaces a smaller one only if its objective is lower by more than this share.

    Returns:
        {"n", "best_n" (the lowest objective), "objectives" ({n: G}), "feasible" ({n: bool})}.

    Raises:
        RuntimeError: no n passed the failure gate.
    """
    res = {n: tuned[f"{task}/clf-n{n}"] for n in ns}
    ok = [n for n in ns if not res[n]["failed"]]
    if not ok:
        raise RuntimeError(f"{task}: no tuned CLF law passed the failure gate; the defaults rule has no candidate")
    best = min(ok, key=lambda n: (res[n]["objective"], n))
    chosen = next(n for n in ok if not res[best]["objective"] < (1.0 - margin) * res[n]["objective"])
    return {"n": chosen, "best_n": best, "objectives": {n: res[n]["objective"] for n in ns},
            "feasible": {n: not res[n]["failed"] for n in ns}}


def tune(cfg: TuneSettings = TuneSettings(), progress=None) -> dict:
    """Tune every row of :data:`BASELINES` (or ``cfg.rows``) in table order, apply the defaults rule, then size the
    compensators on the tuned n = 2 law (:func:`compensators`).

    Returns:
        {"settings" (budget, episodes, seconds, seeds), "anchor", "baselines" ({name: tune_row's result}),
        "defaults" ({task: default_n's result and the per-n settings}), "compensators" ({task: {kind: the sweep's
        result}}), "law_settings" (the law table), "check" (the held-out check)}.
    """
    rows = [r for r in baselines_for(cfg.plant) if not cfg.rows or r.name in cfg.rows]
    tasks = [t for t in TASKS if any(r.task == t for r in rows)]
    anchors = anchors_of(cfg, tasks)
    tuned: dict = {}
    for row in rows:
        tuned[row.name] = tune_row(row, tuned, cfg, anchors, progress)
    defaults = {}
    for t in tasks:
        if all(f"{t}/clf-n{n}" in tuned for n in LAW_NS):
            rule = default_n(tuned, t)
            per_n = {str(n): {k: tuned[f"{t}/clf-n{n}"]["tuned"][k] for k in ("sigma", "fr", "smoothing", "layer_gain")}
                     for n in LAW_NS}
            defaults[t] = {**rule, "per_n": per_n}
    rig = as_rig(cfg.plant)
    table = law_table(tuned, defaults, rig)
    comp = compensators(table, cfg, progress)
    return {"settings": {"budget": cfg.budget, "episodes": cfg.episodes, "seconds": cfg.seconds,
                         "seeds": [0, cfg.episodes - 1], "margin": KEEP_MARGIN,
                         "compensator_episodes": cfg.compensator_episodes if comp else 0},
            "plant": rig.describe(), "anchor": ANCHOR, "baselines": tuned, "defaults": defaults,
            "compensators": comp, "law_settings": table, "check": held_out_check(table, rig, cfg)}


def compensators(table: dict, cfg: TuneSettings, progress=None) -> dict:
    """The last stage: per task of the law table ``table`` (its tuned n = 2 law), the compensators' sweep
    (:mod:`ehss_gym.study.compensators`) on ``cfg.compensator_episodes`` training seeds with the unmodelled effects
    drawn; their chosen rows are added to ``table`` (``dcomp-n2``, ``vinv-n2``). Returns the sweep's results (task ->
    kind -> ...)."""
    tasks = [t for t in TASKS if t in table]
    if not tasks or not cfg.compensator_episodes:
        return {}
    env = {**cfg.env_kwargs(), "law_settings": table_from_dict(table)}
    res = tune_compensators(tasks, cfg.compensator_episodes, cfg.seconds, env, progress)
    for t, kinds in res.items():
        table[t].update({f"{kind}-n2": dict(r["chosen"]) for kind, r in kinds.items()})
    return res


def law_table(tuned: dict, defaults: dict, rig: Rig) -> dict:
    """The law-settings file's content (:mod:`ehss_gym.envs.law_table`) of the tuned rows: per task with all three
    CLF laws tuned, their settings, the rule's n, and the observer's and the PID's rows where tuned."""
    out: dict = {"plant": {"label": rig.label, "hash": rig.hash}}
    for t, d in defaults.items():
        row: dict = {"default_n": d["n"], **{f"clf-n{n}": dict(v) for n, v in d["per_n"].items()}}
        if f"{t}/dob-n2" in tuned:
            row["dob-n2"] = {k: tuned[f"{t}/dob-n2"]["settings"][k] for k in ("dob_hz", "smoothing", "layer_gain")}
        if f"{t}/pid" in tuned:
            row["pid"] = {k: tuned[f"{t}/pid"]["settings"][k] for k in ("kp", "ki", "kd")}
        out[t] = row
    return out


def held_out_check(table: dict, rig: Rig, cfg: TuneSettings) -> dict:
    """Per task of the law table: the held-out check (:func:`ehss_gym.study.friction_windows.check`) of the tuned
    n = 2 law and of the untuned one (the built-in settings, tuned for Table I), on the same episodes."""
    if cfg.check_episodes < 1 or not any(t in table for t in TASKS):
        return {}
    env = cfg.env_kwargs()
    laws = table_from_dict(table)
    out = {}
    for t in laws.tasks:
        tuned = {k: v for k, v in friction_check({"task": t, "n": 2, "law_settings": laws, **env},
                                                 cfg.check_episodes).items() if k != "rows"}
        with warnings.catch_warnings():  # the untuned law on another plant: the warning is the point here
            warnings.simplefilter("ignore", PlantWarning)
            untuned = {k: v for k, v in friction_check({"task": t, "n": 2, **env}, cfg.check_episodes).items()
                       if k != "rows"}
        out[t] = {"tuned": tuned, "untuned": untuned}
    return out


__all__ = ["QUICK_BUDGET", "QUICK_EPISODES", "CHECK_EPISODES", "COMPENSATOR_EPISODES", "baselines_for", "pid_start",
           "law_table", "held_out_check", "compensators", "PROG", "BUDGET", "EPISODES", "EPISODE_SECONDS",
           "KEEP_MARGIN", "LAW_NS", "ANCHOR", "PID_START", "Axis",
           "Baseline", "BASELINES", "dob_row", "RUNNERS",
           "law_axes", "pid_axes", "law_metrics", "pid_metrics", "objective",
           "Search", "search", "TuneSettings", "tune_row", "anchors_of", "default_n", "tune", "scenario_seeds"]
