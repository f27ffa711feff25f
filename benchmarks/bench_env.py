"""Environment throughput: EHSSTracking-v0 against Gymnasium's Pendulum-v1 and gym-electric-motor.

Every env is built with its standard maker (``gym.make`` / ``gem.make``, default
wrappers included) and stepped with the same loop: pre-sampled random actions
from the env's own action space, reset on termination or truncation (resets are
counted in the time, as a training loop sees them). Cases are interleaved and
repeated; the median steps/s is quoted.

The native vector env (``ehss_gym.envs.vector``) is stepped the same way at 1, 16,
256 and 1024 sub-envs; its rate counts sub-env steps (num_envs x vector steps).
"""

from __future__ import annotations

import time
from importlib.metadata import version

import gymnasium as gym
import numba
import numpy as np

import ehss_gym  # noqa: F401  (registers EHSSTracking-v0 with gymnasium)
from ehss_gym.core.loop import MAX_LANES
from ehss_gym.envs.kernels import advance

from . import kernel_profile, lane_stages
from .common import Section, Table, Target, interleave, log, median, profile, repo_root, spread, top_own_time

ENV_ID = "EHSSTracking-v0"
GEM_ID = "Cont-SC-PermExDc-v0"
OURS, PENDULUM = "EHSSTracking-v0 (ours)", "Pendulum-v1"  # their rows in the single env table
VEC_SIZES = (1, 16, 256, 1024)
VEC_TARGET = 20.0  # sub-env steps/s of the vector env at VEC_TARGET_SIZE sub-envs over the single env's steps/s
VEC_TARGET_SIZE = 256
COMPILED_NS_TARGET = 150.0  # ns of the vector env's compiled call per lane and control period at VEC_TARGET_SIZE
BLOCK = MAX_LANES  # lanes of the vectorised plant and core-loop blocks timed for the vector env
PHASE_LANES = 64  # sub-envs of the out-of-phase measurement (lanes restarted at up to this many different steps)
STRIP = ("site-packages/", repo_root() + "/")  # profile file names are shown relative to these


def env_status() -> str:
    """'' if our env is registered, else why not."""
    try:
        gym.spec(ENV_ID)
    except Exception as exc:  # say why it is missing rather than fail the whole run
        return f"env not available: {ENV_ID} is not registered ({type(exc).__name__}: {exc})"
    return ""


def make_ours():
    return gym.make(ENV_ID)


def make_pendulum():
    return gym.make("Pendulum-v1")


def _gem():
    """The gym-electric-motor module; raises ImportError (or what its import raises) where it is not installed."""
    import gym_electric_motor  # optional peer: not a dependency of ehss-gym, compared only where installed

    return gym_electric_motor


def gem_status() -> str:
    """'' if gym-electric-motor imports, else why it is left out."""
    try:
        _gem()
    except Exception as exc:
        return (f"gym-electric-motor not installed here ({type(exc).__name__}); install it with "
                f"`pip install gym-electric-motor` to include it")
    return ""


def make_gem():
    return _gem().make(GEM_ID)


def make_vector(n: int, threads: int = 1):
    """The native vector env with n sub-envs, through its registered vector entry point; ``threads``: its setting of
    that name (parallel chunks of lanes; 1, the default, is one compiled call on one thread)."""
    return gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="vector_entry_point", threads=threads)


def vector_status() -> str:
    """'' if the vector env builds, else why not."""
    if env_status():
        return "vector env not available: the single env is not available"
    try:
        v = make_vector(2)
        v.close()
    except Exception as exc:
        return f"vector env not available ({type(exc).__name__}: {exc})"
    return ""


class Stepper:
    """Steps one env with pre-sampled actions; ``run(n)`` returns the wall time of n steps [s]."""

    def __init__(self, env, seed: int = 0, n_actions: int = 1024):
        self.env = env
        env.action_space.seed(seed)
        self.actions = [env.action_space.sample() for _ in range(n_actions)]
        env.reset(seed=seed)
        self.episodes = 0
        self.steps = 0

    def run(self, n: int) -> float:
        env, acts, na = self.env, self.actions, len(self.actions)
        t0 = time.perf_counter()
        for i in range(n):
            _, _, term, trunc, _ = env.step(acts[i % na])
            if term or trunc:
                env.reset()
                self.episodes += 1
        dt = time.perf_counter() - t0
        self.steps += n
        return dt


class VecStepper(Stepper):
    """Steps a vector env with pre-sampled batched actions (autoreset is the env's own)."""

    def __init__(self, venv, seed: int = 0, n_actions: int = 64):
        super().__init__(venv, seed, n_actions)

    def run(self, n: int) -> float:
        env, acts, na = self.env, self.actions, len(self.actions)
        t0 = time.perf_counter()
        for i in range(n):
            env.step(acts[i % na])
        return time.perf_counter() - t0


def profile_steps(env, n: int, top: int = 8) -> tuple[float, list]:
    """cProfile of n env steps: total time and the top functions by own time (share, name)."""
    s = Stepper(env, seed=1)
    s.run(5)  # Gymnasium's passive checker inspects the first step only; keep that one-off out of the profile
    return top_own_time(profile(s.run, n), top, STRIP)


def _describe(env) -> str:
    u = env.unwrapped
    shape = getattr(env.observation_space, "shape", None)
    parts = [f"action {env.action_space}", f"obs {shape if shape is not None else env.observation_space}"]
    cfg = getattr(u, "config", None)
    for attr in ("dt", "tau", "control_period", "substeps", "agent_period"):
        v = getattr(u, attr, getattr(cfg, attr, None))
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            parts.append(f"{attr}={v:g}")
    spec = getattr(env, "spec", None)
    if spec is not None and spec.max_episode_steps:
        parts.append(f"episode limit {spec.max_episode_steps} steps")
    return ", ".join(parts)


def run(quick: bool) -> Section:
    """Section 2: single env steps/s against the peers, what one step costs, and the native vector env."""
    sec = Section("env", "2. Environment steps per second", template="env.md.j2")
    status = env_status()
    if status:
        sec.skipped = status
        log(f"env: {status}")
        return sec
    n_steps = 300 if quick else 5000
    reps = 2 if quick else 5
    makers, gem = _makers()
    tb, rates, described = single_env_rates(makers, n_steps, reps)
    sec.tables.append(tb)
    sec.targets.append(Target("env steps/s vs Pendulum-v1", rates[OURS] / rates[PENDULUM], 1.0))
    profiles = step_profiles(200 if quick else 2000)
    kc = step_breakdown(quick)
    if kc is not None:
        sec.tables.append(step_cost_table(kc, rates[OURS], rates[PENDULUM]))
    v_status, vec, v_profile = vector_status(), None, None
    vector_target = f"vector env ({VEC_TARGET_SIZE} sub-envs) vs single env"
    if v_status:
        sec.targets.append(Target(vector_target, None, VEC_TARGET, note=v_status))
    else:
        vtab, vec = vector_rates(quick, n_steps, reps if quick else 3)
        sec.tables.append(vtab)
        sec.targets.append(Target(vector_target, vec["ratio"], VEC_TARGET, note="default settings (threads=1)"))
        if vec["ratio_par"] is not None:
            name = f"vector env ({VEC_TARGET_SIZE} sub-envs, threads={vec['threads']}) vs single env"
            sec.targets.append(Target(name, vec["ratio_par"], VEC_TARGET, note="parallel chunks of lanes"))
        vec["compiled_ns"] = compiled_ns_per_period(quick)
        sec.targets.append(Target(f"compiled step per lane and control period, {VEC_TARGET_SIZE} sub-envs",
                                  vec["compiled_ns"], COMPILED_NS_TARGET, unit="ns", lower_is_better=True,
                                  note="one thread, the vector env's compiled call alone"))
        log(f"env: the compiled step's stages at {VEC_TARGET_SIZE} sub-envs")
        vec["stages"] = lane_stages.stage_costs(VEC_TARGET_SIZE, repeats=5 if quick else 40)
        log(f"env: the compiled step with {PHASE_LANES} sub-envs out of phase")
        vec["stages"]["phases"] = lane_stages.phase_costs(PHASE_LANES, repeats=5 if quick else 30)
        sec.tables.append(stage_table(vec["stages"]))
        if vec["ratio"] < VEC_TARGET:
            v_profile = vector_profile(vec["steps"])
    sec.context = report_context(n_steps, reps, (gem, described, profiles), kc, rates, v_status, vec, v_profile)
    log("env: machine code of the control period's stages")
    sec.context["control_mix"] = kernel_profile.control_period_mix()
    return sec


def report_context(n_steps: int, reps: int, peers: tuple[dict, list, dict], kc: dict | None,
                   rates: dict[str, float], v_status: str, vec: dict | None, v_profile: list | None) -> dict:
    """What ``env.md.j2`` is rendered with: the run's sizes, the measurements and the explanations of misses.

    Args:
        n_steps: single env steps per repeat.
        reps: interleaved repeats.
        peers: :func:`_makers`'s gym-electric-motor status, :func:`single_env_rates`'s descriptions of the envs and
            :func:`step_profiles`'s profiles.
        kc: :func:`step_breakdown` (None if the env's internals are not as expected).
        rates: single env steps/s per env.
        v_status: why the vector env is left out, or ''.
        vec: :func:`vector_rates`'s measurements (None when left out).
        v_profile: :func:`vector_profile` when the vector env misses its target, else None.
    """
    gem, described, profiles = peers
    ours, pend = rates[OURS], rates[PENDULUM]
    return {"n_steps": n_steps, "reps": reps, "gem_id": GEM_ID, "block": BLOCK, "vector_size": VEC_TARGET_SIZE,
            "gem": gem, "described": described, "profiles": profiles,
            "pendulum_miss": None if kc is None else pendulum_miss(kc, ours, pend, profiles["ours"]["rows"]),
            "vector_status": v_status, "vector_profile": v_profile, "control_mix": None,  # run() measures it
            "vector_miss": None if kc is None or v_profile is None else vector_miss(kc, vec, v_profile)}


def _makers() -> tuple[dict, dict]:
    """The envs to compare (name -> maker), and gym-electric-motor's ``status`` (why it is left out, or '') and
    ``version``."""
    makers = {OURS: make_ours, PENDULUM: make_pendulum}
    gs = gem_status()
    if gs:
        return makers, {"status": gs, "version": ""}
    makers[f"{GEM_ID} (gym-electric-motor)"] = make_gem
    return makers, {"status": "", "version": version("gym-electric-motor")}


def single_env_rates(makers: dict, n_steps: int, reps: int) -> tuple[Table, dict[str, float], list]:
    """Each env stepped ``n_steps`` times per repeat, interleaved.

    Returns:
        the table, steps/s per env (median), and (name, description) of each env.
    """
    steppers, described = {}, []
    for name, mk in makers.items():
        env = mk()
        steppers[name] = Stepper(env)
        steppers[name].run(min(50, n_steps))  # first steps (JIT load, caches) outside the timing
        described.append((name, _describe(env)))
    log(f"env: {', '.join(makers)}: {reps} x {n_steps} steps interleaved")
    times = interleave({k: (lambda s=s: s.run(n_steps)) for k, s in steppers.items()}, reps)
    tb = Table("env_steps", columns=["env", "median_steps_per_s", "min..max_s_per_run", "vs_Pendulum-v1",
                                     "episodes_ended"])
    pend = n_steps / median(times[PENDULUM])
    rates = {}
    for name, ts in times.items():
        rates[name] = n_steps / median(ts)
        tb.add(name, rates[name], spread(ts), rates[name] / pend, steppers[name].episodes)
    for s in steppers.values():
        s.env.close()
    return tb, rates, described


def step_profiles(n: int) -> dict[str, dict]:
    """cProfile of n steps of ours and of Pendulum-v1: ``us_per_step`` under the profiler and the top ``rows``."""
    out = {}
    for key, mk in (("ours", make_ours), ("pendulum", make_pendulum)):
        total, rows = profile_steps(mk(), n)
        out[key] = {"us_per_step": total / n * 1e6, "rows": rows}
    return out


def step_breakdown(quick: bool) -> dict | None:
    """Time the pieces of one EHSSTracking-v0 step [us]; None if the env's internals are not as expected.

    The core's kernels through :mod:`benchmarks.kernel_profile`, at the env's own control period and substeps
    (``ctrl``, ``plant1``, ``plantB``, ``loopB`` per control period, ``floor1`` their sum over one agent step),
    and the env's compiled step (``advance`` on ``env.unwrapped._lanes._args``) as called and as dispatched.
    """
    env = make_ours()
    u = env.unwrapped
    template = getattr(u, "scenario_template", None)
    ap = getattr(getattr(u, "config", None), "agent_period", None)
    if template is None or not ap:
        return None
    sc = template.replace(t_end=max(template.control_period, 0.05 if quick else 0.5))
    n = sc.n_steps
    out = {"agent_period": ap, "h": sc.control_period, "substeps": sc.substeps,
           "ctrl": kernel_profile.controller_us(sc, n), "plant1": kernel_profile.plant_us_per_lane(sc, 1, n),
           "plantB": kernel_profile.plant_us_per_lane(sc, BLOCK, n),
           "loopB": kernel_profile.loop_us_per_lane(sc, BLOCK)}
    out["floor1"] = ap * (out["ctrl"] + out["plant1"])
    args = getattr(getattr(u, "_lanes", None), "_args", None)
    if args is None:
        return out
    calls = 100 if quick else 1000
    best = _best_calls(advance, args, calls, before=lambda: env.reset(seed=3))  # every call advances a live lane
    env.close()
    dbest = _best_calls(_noop_like(args), args, calls)
    out.update({"advance": best / calls * 1e6, "dispatch": dbest / calls * 1e6, "n_args": len(args)})
    return out


def _noop_like(args: tuple):
    """A compiled function that does nothing with as many arguments as ``args``, compiled for their types."""
    ns: dict = {}
    exec("def noop(" + ", ".join(f"a{i}" for i in range(len(args))) + "):\n    return 0\n", ns)
    noop = numba.njit(ns["noop"])
    noop(*args)
    return noop


def _best_calls(fn, args: tuple, calls: int, before=None, repeats: int = 3) -> float:
    """Best of ``repeats`` wall times [s] of ``calls`` calls ``fn(*args)``; ``before()`` runs untimed first."""
    best = float("inf")
    for _ in range(repeats):
        if before is not None:
            before()
        t0 = time.perf_counter()
        for _ in range(calls):
            fn(*args)
        best = min(best, time.perf_counter() - t0)
    return best


def step_cost_table(kc: dict, ours: float, pend: float) -> Table:
    """What one env step costs [us], from :func:`step_breakdown` and the measured steps/s of ours and Pendulum."""
    t_ours, t_pend = 1e6 / ours, 1e6 / pend
    ap = kc["agent_period"]
    kt = Table("env_profile", columns=["piece", "us", "note"])
    kt.add("EHSSTracking-v0 step", t_ours, f"{ap} control periods of {kc['h']:g} s, {kc['substeps']} RK4 "
           "substep(s) each")
    if "advance" in kc:
        kt.add("  Python step + Gymnasium wrappers", t_ours - kc["advance"], "step minus the compiled call")
        kt.add("  compiled call advance(...), as called", kc["advance"], "")
        kt.add(f"    numba dispatch of its {kc['n_args']} arguments", kc["dispatch"],
               "a no-op compiled function with the same arguments")
        kt.add(f"    controller, {ap} x controller_update", ap * kc["ctrl"], f"{kc['ctrl']:.3g} us per period")
        kt.add(f"    plant, {ap} x integrate_lanes on 1 lane", ap * kc["plant1"], f"{kc['plant1']:.3g} us per period")
        kt.add("    other compiled work", kc["advance"] - kc["dispatch"] - kc["floor1"],
               "lane grouping, copies, checks, metrics, observation, reward")
    kt.add(f"plant per control period per lane, {BLOCK}-lane block", kc["plantB"], "vectorised (vector env)")
    kt.add(f"core loop loop.run_lanes per control period per lane, {BLOCK}-lane block", kc["loopB"],
           "controller + plant + checks + metrics, one thread, no env")
    kt.add("Pendulum-v1 step", t_pend, "")
    return kt


def pendulum_miss(kc: dict, ours: float, pend: float, rows: list) -> dict | None:
    """The numbers that explain ours missing 1x Pendulum-v1's steps/s; None when it does not (or is not timed)."""
    if not (ours < pend and "advance" in kc):
        return None
    t_ours, t_pend = 1e6 / ours, 1e6 / pend
    return {"kc": kc, "rate_khz": 1 / kc["h"] / 1e3, "t_ours": t_ours, "t_pend": t_pend,
            "kernel_share": sum(share for share, name in rows if name.endswith("(advance)")),
            "other": kc["advance"] - kc["dispatch"] - kc["floor1"], "python": t_ours - kc["advance"],
            "floor_vs_pend": kc["floor1"] / t_pend, "advance_vs_pend": kc["advance"] / t_pend}


def vector_rates(quick: bool, n_steps: int, reps: int) -> tuple[Table, dict]:
    """Sub-env steps/s of the native vector env at VEC_SIZES sub-envs with its default settings (``threads=1``: one
    compiled call on one thread) and at VEC_TARGET_SIZE with ``threads`` = numba's threads (parallel chunks of lanes;
    where numba has more than one), interleaved with the single env.

    Returns:
        the table and the measurements: ``single`` (the single env's steps/s), ``rate`` (sub-env steps/s per
        size), ``rate_par`` (VEC_TARGET_SIZE sub-envs in ``threads`` parallel chunks; None with one thread),
        ``ratio`` and ``ratio_par`` (VEC_TARGET_SIZE sub-envs vs the single env), ``steps`` (vector steps per run,
        per size) and ``threads``.
    """
    threads = numba.get_num_threads()
    budget = 2048 if quick else 20_000  # sub-env steps per measurement
    vsteppers = {}
    for n in VEC_SIZES:
        vsteppers[n] = VecStepper(make_vector(n))
        vsteppers[n].run(3)
    vsteps = {n: max(5 if quick else 20, min(budget // n, 2000)) for n in VEC_SIZES}
    single = Stepper(make_ours(), seed=2)
    single.run(min(50, n_steps))
    cases = {"single env (gym.make)": lambda: single.run(n_steps)}
    for n in VEC_SIZES:
        cases[n] = lambda n=n: vsteppers[n].run(vsteps[n])
    par = None
    if threads > 1:
        par = VecStepper(make_vector(VEC_TARGET_SIZE, threads))
        par.run(3)
        cases["parallel"] = lambda: par.run(vsteps[VEC_TARGET_SIZE])
    log(f"env: vector env at {VEC_SIZES} sub-envs (+ {VEC_TARGET_SIZE} in {threads} parallel chunks), {reps} "
        f"interleaved repeats")
    vt = interleave(cases, reps)
    for s in [*vsteppers.values(), *([par] if par else [])]:
        s.env.close()
    return _vector_table(vt, vsteps, n_steps, threads)


def _vector_table(vt: dict, vsteps: dict, n_steps: int, threads: int) -> tuple[Table, dict]:
    single_rate = n_steps / median(vt["single env (gym.make)"])
    vtab = Table("vector_env", columns=["sub_envs", "env_threads", "vector_steps_per_run", "median_s",
                                        "sub_env_steps_per_s", "vs_single_env"])
    vtab.add("single env (gym.make)", "-", n_steps, median(vt["single env (gym.make)"]), single_rate, 1.0)
    vrate = {}
    for n in VEC_SIZES:
        vrate[n] = n * vsteps[n] / median(vt[n])
        vtab.add(n, 1, vsteps[n], median(vt[n]), vrate[n], vrate[n] / single_rate)
    n, rate_par = VEC_TARGET_SIZE, None
    if "parallel" in vt:
        rate_par = n * vsteps[n] / median(vt["parallel"])
        vtab.add(n, threads, vsteps[n], median(vt["parallel"]), rate_par, rate_par / single_rate)
    return vtab, {"single": single_rate, "rate": vrate, "rate_par": rate_par, "steps": vsteps, "threads": threads,
                  "ratio": vrate[n] / single_rate, "ratio_par": None if rate_par is None else rate_par / single_rate}


def compiled_ns_per_period(quick: bool) -> float:
    """The vector env's compiled call alone (``Lanes.step``, one thread) at VEC_TARGET_SIZE sub-envs [ns per lane and
    control period]: the best of many short bursts of a few calls (on shared cores a long run is mostly time spent
    waiting for the core; the best short burst is the call's own cost). The lanes are stepped with seeded random
    residuals first, so they run mid-episode with their noise and friction as a training loop sees them."""
    from ehss_gym.envs.vector import EHSSTrackingVectorEnv

    v = EHSSTrackingVectorEnv(VEC_TARGET_SIZE)
    v.reset(seed=0)
    acts = np.random.default_rng(0).uniform(-1.0, 1.0, (64, VEC_TARGET_SIZE, 1))
    for a in acts:
        v.step(a)
    lanes = v._lanes
    calls, bursts = 4, (10 if quick else 60)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        best = _best_calls(lambda: lanes.step(), (), calls, repeats=bursts)
    finally:
        numba.set_num_threads(threads)
        v.close()
    return best / calls / (VEC_TARGET_SIZE * v.config.agent_period) * 1e9


def stage_table(st: dict) -> Table:
    """The table of :func:`benchmarks.lane_stages.stage_costs`: each part's ns per lane and control period."""
    tb = Table("lane_stages", columns=["part", "ns_per_lane_and_period", "kind"])
    for kind in ("stages", "step", "layout"):
        for name, ns in st[kind].items():
            tb.add(name, ns, {"stages": "control period stage", "step": "env step", "layout": "layout"}[kind])
    for n, ns in st.get("phases", {}).items():
        tb.add(f"the whole compiled step, {PHASE_LANES} sub-envs in {n} phase(s)", ns, "lanes out of phase")
    return tb


def vector_profile(vsteps: dict) -> list:
    """cProfile of the VEC_TARGET_SIZE-sub-env vector step: the top functions by own time (share, name)."""
    v = make_vector(VEC_TARGET_SIZE)
    vst = VecStepper(v)
    st = profile(vst.run, max(5, vsteps[VEC_TARGET_SIZE] // 2))
    v.close()
    return top_own_time(st, 8, STRIP)[1]


def vector_miss(kc: dict, vec: dict, rows: list) -> dict:
    """The numbers that explain the vector env missing VEC_TARGET x the single env at VEC_TARGET_SIZE sub-envs: the
    measured rates, the stage table's sums (:func:`benchmarks.lane_stages.stage_costs`) and the budget per lane and
    control period that VEC_TARGET leaves."""
    ap, st = kc["agent_period"], vec["stages"]
    stages, step, layout = st["stages"], st["step"], st["layout"]

    def part(*words):
        return sum(ns for name, ns in stages.items() if not name.startswith(" ") and any(w in name for w in words))

    t_single = 1e6 / vec["single"]
    needed = t_single / VEC_TARGET / ap * 1e3
    law = part("law_lanes")
    return {"kc": kc, "target": VEC_TARGET, "size": VEC_TARGET_SIZE, "threads": vec["threads"], "ap": ap,
            "ratio": vec["ratio"], "ratio_par": vec["ratio_par"], "compiled_ns": vec["compiled_ns"],
            "compiled_share": sum(sh for sh, nm in rows if "advance" in nm),
            "ctrl_ns": part("sense_lanes", "law_lanes", "controller_apply"), "sense_ns": part("sense_lanes"),
            "law_ns": law, "ref_ns": next(ns for name, ns in stages.items() if "reference_value" in name),
            "plant_ns": part("integrate_lanes"), "book_ns": part("friction", "divergence", "metrics", "copy"),
            "obs_ns": next(ns for name, ns in step.items() if name.startswith("observation")),
            "peek_ns": next(ns for name, ns in step.items() if name.startswith("look-ahead")),
            "needed_ns": needed, "needed_par_ns": needed * vec["threads"], "law_share": law / needed,
            "rows_contiguous": next(ns for name, ns in layout.items() if name.startswith("lanes_period, the env")),
            "rows_strided": next(ns for name, ns in layout.items() if name.startswith("lanes_period, column")),
            "phases": st.get("phases", {}), "phase_lanes": PHASE_LANES}
