"""The benchmark suite runs and writes its report. Nothing here asserts anything about speed."""

from __future__ import annotations

import csv
import math
import os
import re
import subprocess
import sys

import jinja2
import jinja2.meta
import jinja2.nodes
import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from benchmarks import (  # noqa: E402
    bench_compile,
    bench_env,
    bench_memory,
    bench_sim,
    compile_child,
    lane_memory,
    lane_stages,
    report,
)
from benchmarks.common import (  # noqa: E402
    Section,
    Table,
    Target,
    current_rss,
    interleave,
    peak_rss,
    proc_kib_field,
    reset_peak_rss,
)

pytestmark = pytest.mark.xdist_group("benchmarks")  # one worker computes the measured sections (a module fixture) once


def test_quick_run_writes_report(tmp_path):
    out = tmp_path / "perf"
    p = subprocess.run([sys.executable, "-m", "benchmarks", "--quick", "--out", str(out)], cwd=ROOT,
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-4000:]
    perf = (out / "PERF.md").read_text()
    assert f"Made by `python -m benchmarks --quick --out {out}`" in perf
    for heading in ("## Machine", "## Package versions", "## Targets", "## 1. Closed-loop", "## 2. Environment",
                    "## 3. Training", "## 4. Memory", "## 5. Compile time", "load average"):
        assert heading in perf
    assert "FAILED" not in perf
    named = set(re.findall(r"`(\w+)\.csv`", perf))
    assert {"sim_vs_solve_ivp", "substeps_per_second", "batch_scaling", "sim_profile", "memory",
            "compile_time", "ppo_training", "training_cost"} <= named
    for name in named | {"targets"}:
        with open(out / f"{name}.csv") as f:
            lines = f.read().splitlines()
        assert lines[0].startswith("# made by: python -m benchmarks --quick")
        rows = list(csv.reader(lines[1:]))
        assert len(rows) >= 2 and all(len(r) == len(rows[0]) for r in rows), name


def test_scipy_peer_matches_simulator():
    """The solve_ivp peer integrates the same loop: same states as ehss_gym.simulate over 20 ms."""
    from ehss_gym import Scenario, simulate

    sc = Scenario(**bench_sim.SETTING, t_end=0.02, log_interval=1e-4)
    ref = bench_sim.ScipyLoop(sc).run()
    ours = simulate(sc).x
    diff, per_state = bench_sim.max_rel_diff(ours, ref)
    assert ref.shape == ours.shape
    assert np.abs(ref[-1, 3]) > 0  # the valve actually moved
    assert diff < 1e-8, per_state


def test_interleave_alternates_cases():
    calls = []
    times = interleave({"a": lambda: calls.append("a"), "b": lambda: calls.append("b") or 0.5}, 3)
    assert calls == ["a", "b"] * 3
    assert times["b"] == [0.5] * 3 and len(times["a"]) == 3


def test_target_status_and_shortfall():
    assert Target("x", 500.0, 1000.0).status == "MISS"
    assert Target("x", 500.0, 1000.0).shortfall == "2x short"
    assert Target("x", 1500.0, 1000.0).status == "hit"
    assert Target("t", 2.5, 2.0, unit="s", lower_is_better=True).status == "MISS"
    assert Target("t", 1.5, 2.0, unit="s", lower_is_better=True).status == "hit"
    assert Target("x", None, 1.0).status == "not measured"


def test_broken_section_template_keeps_the_page(tmp_path):
    """A section whose template fails shows the traceback in PERF.md; the rest is written, then the run fails."""
    broken = Section("memory", "4. Memory", template="memory.md.j2")  # no context: its names are undefined
    plain = Section("train", "3. Training", notes=["a note"])
    for s in (broken, plain):
        s.seconds, s.load_before, s.load_after = 1.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    meta = {"command": "cmd", "date": "now", "quick": True, "machine": {"logical cores": 2}, "versions": {},
            "load_start": (0.0, 0.0, 0.0), "load_end": (0.0, 0.0, 0.0), "wall_s": 1.0}
    with pytest.raises(RuntimeError, match="memory"):
        report.write(str(tmp_path), [broken, plain], meta)
    perf = (tmp_path / "PERF.md").read_text()
    assert "FAILED rendering its template" in perf and "- a note" in perf


SECTION_TABLES = {
    "sim.md.j2": ["setting_check", "sim_vs_solve_ivp", "substeps_per_second", "batch_scaling", "setup_blas_threads",
                  "sim_profile"],
    "env.md.j2": ["env_steps", "env_profile", "vector_env", "lane_stages"],
    "memory.md.j2": ["memory", "memory_per_lane"],
    "compile.md.j2": ["compile_time"],
}
# a phrase of each conditional paragraph: in the page when its branch is taken, absent when it is not
CONDITIONAL = {
    "sim.md.j2": ["--quick: the '1 s' case", "**Why the 1000x target is missed", "**Substeps/s/core.**",
                  "the filters' expm waits"],
    "env.md.j2": ["**What one env step costs", "**Native vector env", "**Where the vector env's compiled step goes",
                  "**Why EHSSTracking-v0 misses 1x",
                  "Profile of the 256-sub-env vector step", "**Why the vector env misses 20x", "(PyPI) runs in"],
    "memory.md.j2": ["MemAvailable", "--quick: 2 scenarios"],
    "compile.md.j2": ["JIT cost of the first", "Warm start-up breakdown", "Where `import ehss_gym`"],
}


@pytest.fixture(scope="module")
def measured():
    """Each section's raw measurements on tiny problems (real values, in this process; no timing is asserted)."""
    base = bench_sim.Scenario(**bench_sim.SETTING)
    size = bench_sim.Sizes(t_short=0.002, t_long=0.004, reps_short=1, reps_long=1, n_batch=4, t_batch=0.002,
                           t_scale=0.002, setup_calls=1, setup_procs=1, peer_periods=5)
    bench_sim.simulate(base.replace(t_end=0.01))
    _, cases = bench_sim.versus_solve_ivp(base, size)
    _, rates = bench_sim.substeps_per_second(base, size, cases["20 s"])
    peer_us = cases["1 s"]["peer_s"] / base.replace(t_end=size.t_short).n_steps * 1e6
    _, *profile_results = bench_sim.where_time_goes(base.replace(t_end=size.t_short), 5, peer_us)
    sim = {"base": base, "size": size, "cases": cases, "rates": rates, "profile": tuple(profile_results),
           "peer_us": peer_us}
    vt = {"single env (gym.make)": [0.01], **{n: [0.01 * n] for n in bench_env.VEC_SIZES}, "parallel": [1.0]}
    _, vec = bench_env._vector_table(vt, {n: 10 for n in bench_env.VEC_SIZES}, 100, 2)
    vec["compiled_ns"] = 300.0
    vec["stages"] = lane_stages.stage_costs(4, periods=1, repeats=1)
    vec["stages"]["phases"] = lane_stages.phase_costs(4, phases=(1, 2), repeats=1)
    env = {"kc": bench_env.step_breakdown(True), "profiles": bench_env.step_profiles(20), "vec": vec}
    sim_child, env_child = compile_child.child("sim"), compile_child.child("env")
    compile_results = {"sim, cold cache": [sim_child], "sim, warm cache": [sim_child],
                       "env, cold cache": [env_child], "env, warm cache": [env_child]}
    return {"sim": sim, "env": env, "compile": compile_results, "memory": bench_memory.child(2, 0.01, 1e-3)}


def _contexts(m: dict, every: bool, monkeypatch) -> dict[str, dict]:
    """Each section template's context from the sections' own report_context, with every conditional paragraph's
    branch taken (``every``) or none."""
    sim, env = m["sim"], m["env"]
    monkeypatch.setattr(bench_sim, "TARGET_RATIO", 1000.0 if every else 0.0)
    monkeypatch.setattr(bench_sim, "TARGET_SUBSTEPS", math.inf if every else 0.0)
    setup_ms = {"default": 3.0, "1": 1.0} if every else {"default": 1.0, "1": 1.0}
    rates = {bench_env.OURS: 1.0, bench_env.PENDULUM: 2.0 if every else 0.5}
    gem = {"status": "", "version": "1.0"} if every else {"status": "not installed here", "version": ""}
    peers = (gem, [(bench_env.OURS, "action Box(-1, 1)")], env["profiles"])
    v_profile = [(0.5, "ehss_gym/envs/kernels.py:1(advance)")] if every else None
    compile_results = m["compile"] if every else {"sim, warm cache": m["compile"]["sim, warm cache"]}
    return {
        "sim.md.j2": bench_sim.report_context(every, sim["size"], sim["base"], sim["cases"], sim["rates"],
                                              sim["profile"], sim["peer_us"], setup_ms),
        "env.md.j2": bench_env.report_context(300, 2, peers, env["kc"] if every else None, rates, "",
                                              env["vec"], v_profile),
        "memory.md.j2": bench_memory.report_context(every, (2, 0.01), 1e-2 if every else 1e-3,
                                                    2**30 if every else None, m["memory"]),
        "compile.md.j2": bench_compile.report_context(not every, "" if every else "env not available: test",
                                                      compile_results, 9.0 if every else None,
                                                      [(120_000, "ehss_gym"), (50_000, "numba")] if every else []),
    }


# left out when the env's internals or the vector env are not there
OPTIONAL_TABLES = {"env_profile", "vector_env", "lane_stages"}


def _tables(template: str, every: bool = True) -> list[Table]:
    """A one-row stand-in for each table the section hands its template (the optional ones only with ``every``)."""
    tables = []
    for name in SECTION_TABLES[template]:
        if every or name not in OPTIONAL_TABLES:
            tables.append(Table(name, columns=["a", "b"]))
            tables[-1].add(1, "x")
    return tables


@pytest.mark.parametrize("every", [True, False], ids=["every-branch", "no-branch"])
def test_section_templates_render(measured, monkeypatch, every):
    """Each section's template renders (undefined names are errors) with what its report_context supplies, with
    every conditional paragraph taken and with none; it names no variable that the context lacks."""
    contexts = _contexts(measured, every, monkeypatch)
    env = report.environment(report.TEMPLATES)
    for template, ctx in contexts.items():
        ast = env.parse(env.loader.get_source(env, template)[0])
        local = {a.target.name for a in ast.find_all(jinja2.nodes.Assign)}  # {% set %} inside {% if %} blocks
        assert jinja2.meta.find_undeclared_variables(ast) - local <= set(ctx) | {"tables"}, template
        tables = _tables(template, every)
        text = report.section_body(Section("key", "title", tables=tables, template=template, context=ctx))
        for phrase in CONDITIONAL[template]:
            assert (phrase in text) == every, (template, phrase)
        assert re.findall(r"\(`(\w+)\.csv`\)", text) == [t.name for t in tables], template
        assert "None" not in text and "{{" not in text and "{%" not in text and "\n\n\n" not in text, template


def test_every_template_parses():
    env = report.environment(report.TEMPLATES)
    names = sorted(f for f in os.listdir(report.TEMPLATES) if f.endswith(".j2"))
    assert set(SECTION_TABLES) | {"perf.md.j2", "notes.md.j2", "macros.md.j2", "command_timing.txt.j2"} == set(names)
    for name in names:
        env.get_template(name)  # raises jinja2.TemplateSyntaxError


def test_command_timing_lines(monkeypatch):
    """The lines bench_evaluate / bench_reproduce print, word for word (as before they came from a template)."""
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    res = {"wall_s": 200.0, "cpu_s": 321.456, "load_before": 0.5, "load_after": 1.234, "episodes": 88, "workers": 2,
           "phases": {"load": 1.23, "episodes": 98.76}}
    assert report.command_timing("evaluate", res, quick=False) == (
        "ehss evaluate (full default run): 88 episodes, 2 workers; wall 200.0 s (phases: load 1.2 s, episodes "
        "98.8 s), CPU 321.5 s (CPU/2 = 160.7 s) on 2 CPU(s); 1-min load average 0.50 before, 1.23 after\n"
        "target <= 180 s wall on 2 cores: MISSED (machine shared: other load was running)\n"
        "target <= 60 s of episodes on 2 quiet cores: 98.8 s, MISSED (machine shared: other load was running)\n")
    quiet = {**res, "wall_s": 70.0, "load_before": 0.1, "phases": {"load": 1.0, "episodes": 59.96}}
    assert report.command_timing("evaluate", quiet, quick=False).endswith(
        "target <= 180 s wall on 2 cores: met\ntarget <= 60 s of episodes on 2 quiet cores: 60.0 s, met\n")
    no_phase = report.command_timing("evaluate", {**res, "phases": {}}, quick=False)
    assert "of episodes" not in no_phase and no_phase.endswith("other load was running)\n")
    assert report.command_timing("reproduce", {**res, "wall_s": 100.0, "load_before": 0.1}, quick=False) == (
        "ehss reproduce (full default run): wall 100.0 s, CPU 321.5 s on 2 CPU(s); 1-min load average 0.10 before, "
        "1.23 after\ntarget <= 120 s wall on 2 cores: met\n")
    assert report.command_timing("reproduce", res, quick=True).endswith("1.23 after\n")


def test_undefined_name_is_an_error():
    """A name the code does not supply fails the render instead of printing nothing (StrictUndefined)."""
    with pytest.raises(jinja2.UndefinedError, match="'env_status' is undefined"):
        report.render_template("compile.md.j2", tables={"compile_time": _tables("compile.md.j2")[0]})


def test_table_rejects_wrong_row_length():
    t = Table("t", "t", ["a", "b"])
    with pytest.raises(ValueError, match="expected 2"):
        t.add(1)


def test_bench_cli_rejects_bad_only():
    from ehss_gym.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["bench", "--only", "nonsense"])
    assert exc.value.code == 2


def test_bench_cli_without_checkout(monkeypatch, capsys):
    from ehss_gym.cli import bench, main

    monkeypatch.setattr(bench, "_benchmarks_module", lambda: None)
    assert main(["bench", "--quick"]) == 2
    assert "source checkout" in capsys.readouterr().err


def test_a_reset_peak_is_the_resident_set_then_not_an_earlier_peak():
    """The memory benchmark's children reset their peak RSS after the warm-up (Linux keeps a parent's across exec).
    After a 320 MB array is touched and freed, the peak still holds it; reset, it is the resident set (VmRSS, read
    apart from the peak) and no longer the array's."""
    # the platform's support, read apart from the function under test: where Linux offers the reset, a
    # reset_peak_rss that fails to use it fails here instead of skipping
    if not os.access("/proc/self/clear_refs", os.W_OK):
        pytest.skip("this platform has no writable /proc/self/clear_refs (Linux 4.0 on)")
    a = np.ones(40_000_000)
    a[::4096] = 2.0
    del a
    before = peak_rss()
    assert reset_peak_rss()
    after = peak_rss()
    assert after < before - 200 * 2**20
    assert abs(after - proc_kib_field("/proc/self/status", "VmRSS")) < 64 * 2**20
    assert abs(after - current_rss()) < 64 * 2**20


def test_a_lane_buffer_and_its_views_are_counted_once():
    """The vector env's buffer bytes (benchmarks.lane_memory.owned_bytes) count an array once, not its views."""
    class Owner:
        pass

    o = Owner()
    o.a = np.zeros(100)
    o.view = o.a[10:]
    o.rows = o.a.reshape(10, 10)[2]
    o.b = np.zeros(5, dtype=np.float32)
    o.n = 3
    assert lane_memory.owned_bytes(o) == 100 * 8 + 5 * 4
