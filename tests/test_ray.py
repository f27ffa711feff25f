"""The Ray backend on a real local Ray instance (2 CPUs, 127.0.0.1): the same CSVs as the local backend for a quick
evaluation and a quick reproduction, a worker killed mid-run retried to the same results, two seeds trained,
and the ``ehss tune`` smoke search. One Ray instance serves the module (its tests share an xdist group)."""

from __future__ import annotations

import argparse
import gzip
import json
import os
import shutil
import signal
import sys
import tempfile
import threading
import time
import uuid
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import home_entries

from ehss_gym.cli import main as cli_main
from ehss_gym.core.sim import Scenario
from ehss_gym.infra.execution import NUMBA_CACHE_ENV, Backend, Executor, Job, dumps, numba_cache_dir, thread_env
from ehss_gym.study.records import batch_job
from ehss_gym.train.config import Config, build_parser, config_from_args

ray = pytest.importorskip("ray")
pytestmark = pytest.mark.xdist_group("ray")

TINY = ["--n-envs", "2", "--eval-episodes", "1", "--eval-seconds", "0.6", "--hp", "n_steps=64", "--hp",
        "batch_size=64", "--hp", "n_epochs=1"]


@pytest.fixture(scope="module")
def ray_instance(tmp_path_factory):
    """A local Ray instance of 2 CPUs bound to 127.0.0.1 (the commands use it instead of starting their own).

    Its token and session files stay out of the home folder: a new local instance writes a token to
    ~/.ray/auth_token unless RAY_AUTH_TOKEN_PATH names one, and every later ``ray start --head`` on the machine then
    demands it from its clients. The session folder is a short one under the system's temp folder (Ray's socket
    paths must fit in 107 bytes, which pytest's tmp_path does not leave room for), removed afterwards.
    """
    token = tmp_path_factory.mktemp("ray-auth") / "auth_token"
    token.write_text(uuid.uuid4().hex)
    session = tempfile.mkdtemp(prefix="ray-")
    home_before = home_entries()
    with pytest.MonkeyPatch.context() as env:
        # Ray turns token mode on for a new local instance by setting RAY_AUTH_MODE here (its config in this process
        # reads the variable when Ray loads, so it is Ray that must set it); removed again afterwards
        env.delenv("RAY_AUTH_MODE", raising=False)
        env.setenv("RAY_AUTH_TOKEN_PATH", str(token))
        env.setenv("RAY_TMPDIR", session)
        ray.init(address="local", num_cpus=2, include_dashboard=False, _node_ip_address="127.0.0.1",
                 log_to_driver=False, runtime_env={"env_vars": {**thread_env(1), NUMBA_CACHE_ENV: numba_cache_dir()}})
        # the test module's job functions travel by value (Ray's workers cannot import tests/)
        ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
        try:
            yield SimpleNamespace(ray=ray, home_before=home_before, session=session)
        finally:
            ray.shutdown()
            shutil.rmtree(session, ignore_errors=True)


def test_the_ray_instance_leaves_the_home_folder_as_it_found_it(ray_instance):
    """Before: ~/.ray/auth_token appeared, after which a plain ``ray start --head`` cluster refused the commands."""
    assert ray_instance.ray.get(ray_instance.ray.remote(lambda: 42).remote()) == 42
    assert home_entries() == ray_instance.home_before
    assert os.path.isdir(os.path.join(ray_instance.session, "ray"))  # Ray's session files went where they were sent


def _csvs(folder) -> dict:
    """Relative path -> bytes of every CSV under ``folder``."""
    return {os.path.relpath(os.path.join(d, n), folder): open(os.path.join(d, n), "rb").read()
            for d, _, names in os.walk(folder) for n in names if n.endswith((".csv", ".csv.gz"))}


def test_quick_evaluation_csvs_are_byte_identical_on_both_backends(ray_instance, tmp_path):
    """A scripted law, a PID and a learned (safe-weights) policy on the quick held-out suite: local worker processes
    and Ray tasks write the same bytes. (.ci/run compares the whole ehss evaluate --quick the same way: minutes.)"""
    argv = ["evaluate", "--quick", "--episodes", "2", "--no-progress", "--no-store", "--task", "velocity", "--suite",
            "heldout", "--policies", "clf-n2", "pid", "residual-ppo-velocity-n2"]
    assert cli_main([*argv, "--out", str(tmp_path / "local"), "--workers", "2"]) == 0
    assert cli_main([*argv, "--out", str(tmp_path / "ray"), "--backend", "ray"]) == 0
    local, remote = _csvs(tmp_path / "local"), _csvs(tmp_path / "ray")
    # comparisons.csv only with a learned policy in today's loop (the shipped models act in an earlier one)
    assert {"episodes.csv.gz", "summary.csv"} <= set(local) and local == remote
    assert b"residual-ppo-velocity-n2" in gzip.decompress(local["episodes.csv.gz"])


def test_quick_reproduction_csvs_are_byte_identical_on_both_backends(ray_instance, tmp_path):
    """Locally the batches run in this process over numba's threads; on Ray, one single-threaded task each."""
    argv = ["reproduce", "--quick", "--no-progress", "--no-store"]
    assert cli_main([*argv, "--out", str(tmp_path / "local")]) == 0
    assert cli_main([*argv, "--out", str(tmp_path / "ray"), "--backend", "ray"]) == 0
    local, remote = _csvs(tmp_path / "local"), _csvs(tmp_path / "ray")
    assert len(local) >= 5 and sorted(local) == sorted(remote)
    for name in local:
        assert local[name] == remote[name], name


def killed_once_job(config, seed, context):
    """A real batch job; the first attempt of the marked job writes its pid and waits to be killed."""
    marker = config["marker"]
    if seed == config["victim"] and not os.path.exists(marker):
        with open(marker + ".tmp", "w") as f:
            f.write(str(os.getpid()))
        os.replace(marker + ".tmp", marker)
        time.sleep(300)  # the test SIGKILLs this process long before
    out = batch_job({"scenarios": config["scenarios"], "keep": False}, seed, context)
    return {"runs": out, "pid": os.getpid()}


def test_a_worker_killed_mid_run_is_retried_and_gives_the_uninterrupted_results(ray_instance, tmp_path):
    marker = str(tmp_path / "victim.pid")
    scen = [[Scenario(n=n, sigma=1e5, current_limit=10.0, t_end=0.05, seed=s)] for n, s in ((2, 0), (4, 1), (6, 2))]
    jobs = [Job(killed_once_job, {"scenarios": sc, "marker": marker, "victim": 1}, i) for i, sc in enumerate(scen)]
    open(marker, "w").write("0")  # uninterrupted reference run first: no victim
    with Executor(Backend("local", workers=1)) as e:
        ref = e.map(jobs, in_process=True)
    os.unlink(marker)

    killed = {}  # the killer runs beside map(), which blocks until every job is done

    def killer():
        deadline = time.time() + 240
        while not os.path.exists(marker) and time.time() < deadline:
            time.sleep(0.1)
        killed["pid"] = int(open(marker).read())
        os.kill(killed["pid"], signal.SIGKILL)

    t = threading.Thread(target=killer, daemon=True)
    t.start()
    with Executor(Backend("ray", max_retries=2)) as e:
        got = e.map(jobs)
    t.join(5)
    assert killed["pid"] > 0 and got[1]["pid"] != killed["pid"]  # job 1 finished in another worker
    with pytest.raises(ProcessLookupError):
        os.kill(killed["pid"], 0)  # the killed worker is gone
    for a, b in zip(ref, got):  # bit for bit, NaNs included (their JSON text)
        assert dumps(a["runs"]) == dumps(b["runs"])


def test_two_seeds_train_on_ray_and_a_rerun_skips_them(ray_instance, tmp_path, capsys):
    argv = ["train", "--seeds", "0-1", "--backend", "ray", "--out", str(tmp_path), "--timesteps", "64",
            "--no-progress", *TINY]
    assert cli_main(argv) == 0
    runs_ = sorted(d for d in os.listdir(tmp_path) if d.startswith("residual-ppo"))
    assert len(runs_) == 2
    for d in runs_:
        summary = json.loads((tmp_path / d / "summary.json").read_text())
        assert summary["timesteps"] >= 64 and (tmp_path / d / "best" / "policy.safetensors").is_file()
        assert (tmp_path / d / "train.log").stat().st_size > 0
    assert "2 seed(s) trained, 0 already finished" in capsys.readouterr().out
    assert cli_main(argv) == 0
    assert "0 seed(s) trained, 2 already finished" in capsys.readouterr().out


def test_tune_smoke_search_writes_the_table_and_a_best_config_train_accepts(ray_instance, tmp_path, capsys):
    out = tmp_path / "tune"
    argv = ["tune", "--trials", "4", "--timesteps", "256", "--eval-freq", "128", "--grace", "128", "--n-envs", "2",
            "--eval-episodes", "1", "--eval-seconds", "0.6", "--hp", "n_steps=64", "--hp", "batch_size=64",
            "--out", str(out)]
    assert cli_main(argv) == 0
    rows = (out / "trials.csv").read_text().strip().splitlines()
    header = rows[0].split(",")
    assert len(rows) == 5 and {"best_objective", "steps", "learning_rate", "gamma", "n_epochs"} <= set(header)
    trials = json.loads((out / "trials.json").read_text())
    scores = [t["best_objective"] for t in trials]
    assert all(np.isfinite(scores)) and scores == sorted(scores)
    assert all(128 <= t["steps"] <= 256 for t in trials) and len({t["learning_rate"] for t in trials}) == 4
    best = json.loads((out / "best_config.json").read_text())
    assert best["hp"]["learning_rate"] == trials[0]["learning_rate"] and best["hp"]["n_steps"] == 64
    cfg = config_from_args(build_parser(launch=False).parse_args([]), **best)  # the fields of a Config
    assert cfg.hp == best["hp"]
    args = build_parser(argparse.ArgumentParser(), launch=True).parse_args(
        ["--config", str(out / "best_config.json"), "--seed", "3"])
    assert config_from_args(args) == Config(**{**best, "seed": 3})
    assert "TUNE.md" in os.listdir(out) and "Made by `ehss tune" in (out / "TUNE.md").read_text()
    capsys.readouterr()
    assert cli_main(argv) == 0  # resumed: the finished search is restored, no trial runs again
    assert json.loads((out / "trials.json").read_text()) == trials
