"""The study's runs, stage by stage; later stages use the settings chosen from earlier ones.

:func:`run_study` calls the stages in order. Each stage adds its runs to ``Study.records`` (by group name)
and its choices to ``Study.rec``; the rules that choose are the pure functions of :mod:`.rules`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from ehss_gym.core.scenarios import DEFAULT_DISTRIBUTION, heldout_scenarios, paper_scenario, sample_scenario
from ehss_gym.core.signals import sine
from ehss_gym.core.sim import Scenario
from ehss_gym.envs import EnvConfig
from ehss_gym.infra.execution import Executor

from .config import CLAIM_CONFIGS, CLAIM_LOGGED, CLAIM_PERIOD, CONFIGS, NS, StudyConfig
from .records import RecordStore, Runner, probe_summary
from .rules import (
    admissible_sigmas,
    choose_limit,
    choose_period_sigma,
    choose_robust,
    choose_robust_cell,
    choose_sigma,
    choose_smoothing,
    choose_substeps,
    least_saturating_sigma,
)


@dataclass
class Study(RecordStore):
    """The study's runs (group -> records), its choices and its timings (:class:`~.records.RecordStore`)."""

    cfg: StudyConfig = field(kw_only=True)


def sweep_base(cfg: StudyConfig, **kw) -> Scenario:
    """A sweep run: the shortened, phase-matched paper run with the study's limit and filter scheme."""
    kw = {"t_end": cfg.sweep_t_end, "friction": cfg.sweep_friction, "current_limit": cfg.limit,
          "estimator": cfg.estimator, **kw}
    return Scenario(**kw)


def paper_set(cfg: StudyConfig, name: str, sigma: dict, h: float, ss: int, limit, w: float = 0.0,
              log_interval: float = 1e-3, estimator: str | None = None) -> list:
    """(group, Scenario) pairs: the paper's nine 20 s runs (three configurations x n) at these settings."""
    items = []
    for task, fr in CONFIGS:
        for n in NS:
            items.append((name, Scenario(task=task, fr=fr, n=n, sigma=sigma[task], smoothing=w, current_limit=limit,
                                         control_period=h, substeps=ss, t_end=cfg.paper_t_end,
                                         friction=cfg.paper_friction, log_interval=log_interval,
                                         estimator=estimator or cfg.estimator)))
    return items


def distribution_items(group: str, cfg: StudyConfig, task: str = "velocity", heldout: bool = False,
                       **settings) -> list:
    """(group, Scenario) pairs: the env's randomised training scenarios (seeds 0 .. dist_episodes - 1), or the
    held-out ones (``heldout_episodes``, seeds disjoint from training), for the n = 2 law with ``settings``."""
    settings.setdefault("estimator", cfg.estimator)
    settings.setdefault("current_limit", cfg.limit)
    tmpl = paper_scenario(Scenario(task=task, n=2, **settings))
    if heldout:
        return [(group, sc) for sc in heldout_scenarios(cfg.heldout_episodes, tmpl)]
    return [(group, sample_scenario(seed, tmpl, None, DEFAULT_DISTRIBUTION)) for seed in range(cfg.dist_episodes)]


def stage_paper_sweep(st: Study, run: Runner) -> None:
    """Sigma x period sweep, the unlimited law's divergence, the paper runs P0-P2 at sigma = 1, probes;
    then the paper rule's period and sigma (velocity, n = 2)."""
    cfg = st.cfg
    items = [("sigma_period", sweep_base(cfg, n=n, sigma=sg, control_period=h, substeps=cfg.substeps_for(h)))
             for h in cfg.periods for sg in cfg.sigmas for n in NS]
    items += [("sigma_period", sweep_base(cfg, n=n, sigma=sg, control_period=h, substeps=cfg.substeps_for(h),
                                          t_end=cfg.tiny_t_end, friction=cfg.tiny_friction))
              for h in cfg.tiny_periods for sg in cfg.tiny_sigmas for n in NS]
    for h, te in zip(cfg.div_periods, cfg.div_t_end):
        items += [("divergence", Scenario(task=task, fr=fr, n=n, control_period=h, substeps=cfg.substeps_for(h),
                                          t_end=min(te, cfg.paper_t_end), friction=cfg.paper_friction,
                                          log_interval=max(h, 1e-3), estimator=cfg.estimator))
                  for task, fr in CONFIGS for n in NS]
    one = {"velocity": 1.0, "position": 1.0}
    base_ss, fine_ss = cfg.substeps_for(cfg.base_period), cfg.substeps_for(cfg.fine_period)
    paper = paper_set(cfg, "P0", one, cfg.base_period, base_ss, None, log_interval=cfg.base_period)
    paper += paper_set(cfg, "P1", one, cfg.base_period, base_ss, cfg.limit)
    paper += paper_set(cfg, "P2", one, cfg.fine_period, fine_ss, cfg.limit)
    probes = [("probe", Scenario(n=2, sigma=1.0, current_limit=cfg.limit, control_period=h,
                                 substeps=cfg.substeps_for(h), t_end=cfg.probe_t_end, estimator_hz=est, friction=(),
                                 log_interval=max(h, 1e-5), estimator=cfg.estimator))
              for h in cfg.probe_periods for est in (1000.0, 3000.0)]
    # the position task's own sigma x period sweep (f_r 60 Hz): the env has one control period for both tasks
    items += [("position_sigma_period", sweep_base(cfg, task="position", fr=60.0, n=2, sigma=sg, control_period=h,
                                                   substeps=cfg.substeps_for(h)))
              for h in cfg.periods for sg in cfg.sigmas]
    st.add(run.run(items))
    st.add(run.run(paper, keep=True))
    st.records["probe"] = [probe_summary(r) for r in run.run(probes, keep=True)]
    h_vel, _, table = choose_period_sigma(st.group("sigma_period"), n=2)
    h_pos, _, pos_table = choose_period_sigma(st.group("position_sigma_period"), n=2)
    h_paper = min(h_vel, h_pos)  # the longest period that both tasks' rules allow
    at_h = [r for r in st.group("sigma_period") if r.params["h"] == h_paper]
    st.rec.update(period_table=table, pos_period_table=pos_table, h_velocity_rule=h_vel, h_position_rule=h_pos,
                  h_paper=h_paper, sigma_paper=choose_sigma(at_h, 2))
    st.rec["sigma_by_n_velocity"] = {n: choose_sigma(at_h, n) for n in NS}


def _robust_search(st: Study, run: Runner, group: str, task: str, frs, sigmas, start: float,
                   periods=None) -> tuple:
    """The randomised-scenario check over (h >= start) x f_r x sigma, period by period until one passes."""
    cfg = st.cfg
    for h in sorted({h for h in (cfg.dist_periods if periods is None else periods) if h >= start} | {start}):
        items = []
        for fr in frs:
            for sg in sigmas:
                items += distribution_items(group, cfg, task, fr=fr, sigma=sg, control_period=h,
                                            substeps=cfg.substeps_for(h))
        st.add(run.run(items))
        h_rec, fr, sg, met, table = choose_robust_cell(st.group(group), start, cfg.lost_rms, cfg.max_lost)
        if met:
            break
    return h_rec, fr, sg, met, table


def stage_robust_velocity(st: Study, run: Runner) -> None:
    """The paper rule's law on the env's randomised scenarios; the robust period, f_r and sigma (velocity)."""
    cfg = st.cfg
    at_h = [r for r in st.group("sigma_period") if r.params["h"] == st.rec["h_paper"]]
    sigmas = admissible_sigmas(at_h)  # every sigma the paper rule admits at its period
    st.rec["sigmas_admissible_velocity"] = sigmas
    h, fr, sg, met, table = _robust_search(st, run, "distribution", "velocity", cfg.dist_frs, sigmas,
                                           st.rec["h_paper"])
    st.rec.update(h=h, fr_velocity=fr, sigma_velocity=sg, dist_rule_met=met, dist_table=table)


def stage_substeps_position(st: Study, run: Runner) -> None:
    """Substeps at the chosen period; the position task's sigma sweep (f_r 60 Hz) and its robust cell."""
    cfg = st.cfg
    h, fr = st.rec["h"], st.rec["fr_velocity"]
    items = [("substeps", sweep_base(cfg, n=n, sigma=st.rec["sigma_by_n_velocity"][n] or st.rec["sigma_velocity"],
                                     fr=fr, control_period=h, substeps=ss))
             for ss in cfg.substeps_list for n in NS]
    items += [("position_sigma", sweep_base(cfg, task="position", fr=60.0, n=n, sigma=sg, control_period=h,
                                            substeps=cfg.substeps_for(h)))
              for sg in cfg.sigmas for n in NS]
    st.add(run.run(items))
    st.rec["substeps"] = choose_substeps(st.group("substeps"))
    sp = choose_sigma(st.group("position_sigma"), 2)
    st.rec["position_saturating"] = sp is None
    # no non-saturating sigma: fall back to the least-saturating one and say so in the report
    sp = sp if sp is not None else least_saturating_sigma(st.group("position_sigma"), 2)
    st.rec["sigma_position_paper"] = sp
    st.rec["sigma_by_n_position"] = {n: choose_sigma(st.group("position_sigma"), n) for n in NS}
    sigmas = admissible_sigmas(st.group("position_sigma")) or [sp]
    st.rec["sigmas_admissible_position"] = sigmas
    # at the env's one control period, chosen above: only f_r and sigma are the position task's own
    _, fr_p, sg_p, met, table = _robust_search(st, run, "distribution_position", "position", cfg.pos_dist_frs,
                                               sigmas, h, periods=(h,))
    st.rec.update(fr_position=fr_p, sigma_position=sg_p, pos_dist_rule_met=met, pos_dist_table=table)


def stage_limit_fr_smoothing(st: Study, run: Runner) -> None:
    """Current limit, f_r and smoothing around the chosen point; the limit rules."""
    cfg = st.cfg
    h, ss, fr, sg = st.rec["h"], st.rec["substeps"], st.rec["fr_velocity"], st.rec["sigma_velocity"]
    items = [("sigma_limit", sweep_base(cfg, n=n, sigma=s, fr=fr, control_period=h, substeps=ss,
                                        current_limit=lim))
             for s in sorted(set(cfg.limit_sigmas) | {sg}) for lim in cfg.limits for n in NS]
    items += [("sigma_fr", sweep_base(cfg, n=n, sigma=s, fr=f, control_period=h, substeps=ss))
              for s in sorted(set(cfg.fr_sigmas) | {sg}) for f in cfg.frs for n in NS]
    items += [("smoothing_position", sweep_base(cfg, task="position", n=n, sigma=st.rec["sigma_position"],
                                                fr=st.rec["fr_position"], smoothing=w, control_period=h, substeps=ss))
              for w in cfg.pos_widths for n in NS]
    for w in cfg.widths:
        for n in NS:
            items.append(("smoothing", sweep_base(cfg, n=n, sigma=sg, fr=fr, smoothing=w, control_period=h,
                                                  substeps=ss)))
            items += [("smoothing_coarse", sweep_base(cfg, n=n, sigma=sg, fr=fr, smoothing=w, control_period=hc,
                                                      substeps=cfg.substeps_for(hc)))
                      for hc in cfg.smoothing_periods if hc != h]
    st.add(run.run(items))
    lim_runs = [r for r in st.group("sigma_limit") if r.params["sigma"] == sg and r.params["n"] == 2]
    lim = choose_limit(lim_runs)
    st.rec["limit_paper"] = lim_paper = lim if lim is not None else cfg.limit
    st.rec["limit_rule_met"] = lim is not None
    items = []
    for lim in sorted(k for k in cfg.limits if k is not None and lim_paper <= k <= cfg.limit):
        items += distribution_items("distribution_limit", cfg, fr=fr, sigma=sg, current_limit=lim, control_period=h,
                                    substeps=ss)
    st.add(run.run(items))
    lim, met, ltab = choose_robust(st.group("distribution_limit"), "limit", lim_paper, cfg.lost_rms, cfg.max_lost)
    st.rec.update(limit=lim, dist_limit_rule_met=met, dist_limit_table=ltab)
    st.rec["smoothing"] = choose_smoothing([r for r in st.group("smoothing") if r.params["n"] == 2])
    st.rec["smoothing_position"] = choose_smoothing([r for r in st.group("smoothing_position")
                                                     if r.params["n"] == 2])


def stage_position_probe(st: Study, run: Runner) -> None:
    """The position law at the paper's gains (f_r 60 Hz, 1 kHz estimator) by period, limited and not, and
    at the chosen cell; both filter schemes."""
    cfg = st.cfg
    rec = st.rec
    variants = [(h, 60.0, 1000.0, rec["sigma_position_paper"]) for h in cfg.pos_probe_periods]
    variants.append((rec["h"], rec["fr_position"], 1000.0, rec["sigma_position"]))
    variants = list(dict.fromkeys(variants))  # the env's cell may coincide with a paper-gain probe
    items = [("position_probe", Scenario(task="position", fr=fr, n=2, sigma=sg, current_limit=lim, control_period=h,
                                         estimator_hz=est, substeps=cfg.substeps_for(h), t_end=cfg.pos_probe_t_end,
                                         friction=(), estimator=scheme))
             for h, fr, est, sg in variants for lim in (cfg.limit, None) for scheme in (cfg.estimator,
                                                                                       cfg.old_estimator)]
    st.add(run.run(items))


def stage_lost_track_maps(st: Study, run: Runner) -> None:
    """Where the corrected loop loses track: smoothing and limit maps on the randomised scenarios, the old
    loop's f_r x sigma map, and the start-up probe (the largest initial error recovered from rest)."""
    cfg = st.cfg
    rec = st.rec
    h, ss = rec["h"], rec["substeps"]
    items = []
    for fr in sorted({rec["fr_velocity"], cfg.dist_frs[0]}):
        for w in cfg.map_widths:
            items += distribution_items("map_smoothing", cfg, fr=fr, sigma=rec["sigma_velocity"], smoothing=w,
                                        control_period=h, substeps=ss)
        for lim in cfg.map_limits:
            items += distribution_items("map_limit", cfg, fr=fr, sigma=rec["sigma_velocity"], current_limit=lim,
                                        control_period=h, substeps=ss)
    old = cfg.old("velocity")
    for fr in cfg.dist_frs:
        for f in cfg.dist_sigma_factors:
            items += distribution_items("map_old", cfg, **{**old, "fr": fr, "sigma": old["sigma"] * f,
                                                            "smoothing": 0.0})
    for scheme in (cfg.estimator, cfg.old_estimator):
        for fr in cfg.roa_frs:
            for sg in cfg.roa_sigmas:
                for e0 in cfg.roa_errors:
                    items.append(("roa", Scenario(n=2, fr=fr, sigma=sg, current_limit=cfg.limit, control_period=h,
                                                  substeps=ss, t_end=cfg.roa_t_end, friction=(),
                                                  reference=sine(0.0, 2.0, offset=e0), estimator=scheme)))
    st.add(run.run(items))


def stage_final(st: Study, run: Runner) -> None:
    """The paper runs at the recommended settings (P3 plain, P4 smoothed), the old loop's P1/P3 for the claims
    side by side, full-rate snippets, and the recommended and the old defaults on the randomised and held-out
    scenarios of both tasks."""
    cfg = st.cfg
    rec = st.rec
    h, ss, lim = rec["h"], rec["substeps"], rec["limit"]
    sig = {"velocity": rec["sigma_velocity"], "position": rec["sigma_position"]}
    items = paper_set(cfg, "P3", sig, h, ss, lim)
    items += paper_set(cfg, "P4", sig, h, ss, lim, w=rec["smoothing"])
    one = {"velocity": 1.0, "position": 1.0}
    items += paper_set(cfg, "P1_old", one, cfg.base_period, cfg.substeps_for(cfg.base_period), cfg.limit,
                       estimator=cfg.old_estimator)
    items += paper_set(cfg, "P3_old", dict(cfg.old_paper_sigma), 3e-5, 1, cfg.limit, estimator=cfg.old_estimator)
    on = cfg.sweep_friction[0][1]
    snip = [("snippet", sweep_base(cfg, n=2, sigma=rec["sigma_velocity"], fr=rec["fr_velocity"], smoothing=w,
                                   control_period=h, substeps=ss, t_end=min(cfg.sweep_t_end, on + 0.3),
                                   log_interval=h))
            for w in (0.0, rec["smoothing"])]
    st.add(run.run(items, keep=True) + run.run(snip, keep=True))
    new = {"velocity": dict(fr=rec["fr_velocity"], sigma=rec["sigma_velocity"], smoothing=rec["smoothing"]),
           "position": dict(fr=rec["fr_position"], sigma=rec["sigma_position"], smoothing=rec["smoothing_position"])}
    items = []
    for task in ("velocity", "position"):
        for heldout in (False, True):
            suite = "heldout" if heldout else "random"
            items += distribution_items(f"final_{task}_{suite}_new", cfg, task, heldout, control_period=h,
                                        substeps=ss, current_limit=lim, **new[task])
            items += distribution_items(f"final_{task}_{suite}_old", cfg, task, heldout, **cfg.old(task))
            # the old defaults with the corrected filters: what the fix alone does to them
            items += distribution_items(f"final_{task}_{suite}_fixed", cfg, task, heldout,
                                        **{**cfg.old(task), "estimator": cfg.estimator})
    st.add(run.run(items))


def env_template(task: str, n: int) -> Scenario:
    """The env's default loop for ``task`` and power factor ``n`` (its tuned law for that n where the env has one),
    as a Scenario of the paper's run."""
    return EnvConfig.from_kwargs({"task": task, "n": n}).template()


def claim_scenario(cfg: StudyConfig, name: str, n: int, logged: bool = False) -> Scenario:
    """The designated run of claim configuration ``name`` (:data:`~.config.CLAIM_CONFIGS`) for power factor ``n``:
    the paper's run (its start, the study's duration and friction) with the env's defaults for ``n``, at the
    configuration's f_r (None: the env's) and current limit, h = CLAIM_PERIOD; ``logged``: every control period."""
    task, fr, limit = CLAIM_CONFIGS[name]
    tmpl = env_template(task, n)
    return paper_scenario(tmpl, cfg.paper_t_end).replace(
        fr=tmpl.fr if fr is None else fr, current_limit=limit, control_period=CLAIM_PERIOD, bumpless=False,
        friction=cfg.paper_friction, log_interval=CLAIM_PERIOD if logged else 1e-3)


def stage_claims(st: Study, run: Runner) -> None:
    """The claims' designated runs (group "claims"; the configurations of CLAIM_LOGGED once more at every control
    period for the chatter index, which is copied onto their "claims" record) and the held-out suite of each task
    for n = 2, 4, 6 at the env's defaults for each n (group "claims_heldout", the evaluation's held-out episodes)."""
    cfg = st.cfg
    items = [("claims", claim_scenario(cfg, name, n)) for name in CLAIM_CONFIGS for n in NS]
    logged = [("claims_logged", claim_scenario(cfg, name, n, logged=True)) for name in CLAIM_LOGGED for n in NS]
    held = [("claims_heldout", sc) for task in ("velocity", "position") for n in NS
            for sc in heldout_scenarios(cfg.heldout_episodes, env_template(task, n))]
    recs = run.run(items, keep=True)
    full = run.run(logged)
    by_key = {(name, n): r for (name, n), r in zip([(c, n) for c in CLAIM_CONFIGS for n in NS], recs)}
    for (name, n), r in zip([(c, n) for c in CLAIM_LOGGED for n in NS], full):
        by_key[(name, n)].features["chatter_index"] = r.features["chatter_index"]
    st.add(recs)
    st.add(run.run(held))


STAGES = (stage_paper_sweep, stage_robust_velocity, stage_substeps_position, stage_limit_fr_smoothing,
          stage_position_probe, stage_lost_track_maps, stage_final, stage_claims)


def run_study(cfg: StudyConfig, progress: bool = True, executor: Executor | None = None) -> Study:
    """Run every stage in order; later stages use the settings chosen from earlier ones.

    Args:
        cfg: the study's settings.
        progress: show a progress bar.
        executor: where the simulation batches run (:mod:`ehss_gym.infra.execution`; default in this process).
    """
    st = Study(cfg=cfg)
    runner = Runner(progress=progress, executor=executor)
    t_start = time.perf_counter()
    try:
        for stage in STAGES:
            stage(st, runner)
    finally:
        runner.close()
    st.timings["simulate_s"] = runner.sim_seconds
    st.timings["by_group"] = dict(runner.by_group)
    st.timings["runs"] = runner.n_runs
    st.timings["study_s"] = time.perf_counter() - t_start
    return st
