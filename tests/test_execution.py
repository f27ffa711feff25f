"""The execution layer (ehss_gym.infra.execution) without Ray: plain-data results, content addresses, the store,
local worker processes, an interrupted sweep restarted, and the bad-input errors of every command that fans out.
The Ray backend's tests are in tests/test_ray.py."""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from ehss_gym.cli import main as cli_main
from ehss_gym.core.sim import Scenario
from ehss_gym.infra import execution as ex
from ehss_gym.infra.execution import Backend, ExecutionError, Executor, Job, Store, decode, encode, job_key
from ehss_gym.study.records import batch_job


def square_job(config, seed, context):
    """A job for the tests: plain data from the config, the seed and the context."""
    return {"y": np.arange(3.0) * seed * config["a"], "pair": (seed, config["a"]), "ctx": context,
            "pid": os.getpid()}


def failing_job(config, seed, context):
    raise ValueError(f"bad value {config['a']}")


def object_job(config, seed, context):
    return {"obj": object()}


# --- plain data and addresses ------------------------------------------------------------------------------


def test_encode_round_trips_plain_data_exactly():
    data = {"f": 0.1 + 0.2, "nan": math.nan, "inf": -math.inf, "t": (1, "a", None), "l": [True, 2.5e-300],
            "a32": np.linspace(0, 1, 5, dtype=np.float32), "i8": np.arange(6, dtype=np.int8).reshape(2, 3),
            "s": np.float64(1 / 3), "n": np.int64(7), 3: "int key", "__x": 1, "b": b"\x00\xffweights"}
    back = decode(json.loads(json.dumps(encode(data))))
    assert back.keys() == data.keys()
    assert back["f"] == data["f"] and math.isnan(back["nan"]) and back["inf"] == -math.inf
    assert back["t"] == (1, "a", None) and isinstance(back["t"], tuple) and back["l"] == [True, 2.5e-300]
    for k in ("a32", "i8"):
        assert back[k].dtype == data[k].dtype and back[k].shape == data[k].shape and (back[k] == data[k]).all()
    assert type(back["s"]) is np.float64 and back["s"] == data["s"] and type(back["n"]) is np.int64
    assert back["b"] == data["b"] and back[3] == "int key" and back["__x"] == 1


@pytest.mark.parametrize("bad", [object(), {"x": [1, {2, 3}]}, np.array([None, 1], dtype=object)])
def test_a_result_that_is_not_plain_data_is_refused(bad):
    with pytest.raises(TypeError, match="plain data|object arrays"):
        encode(bad)


def test_job_keys_change_with_every_input_and_only_with_them():
    sc = Scenario(n=2, sigma=1e5, t_end=0.1)
    a = Job(batch_job, {"scenarios": [sc], "keep": False}, 3)
    same = Job(batch_job, {"keep": False, "scenarios": [Scenario(n=2, sigma=1e5, t_end=0.1)]}, 3, label="other")
    assert job_key(a) == job_key(same)  # dict order and labels do not matter
    for other in (Job(batch_job, {"scenarios": [sc.replace(sigma=1e5 + 1)], "keep": False}, 3),
                  Job(batch_job, {"scenarios": [sc], "keep": True}, 3),
                  Job(batch_job, {"scenarios": [sc], "keep": False}, 4),
                  Job(square_job, {"scenarios": [sc], "keep": False}, 3)):
        assert job_key(other) != job_key(a)


# --- the store and the local backend --------------------------------------------------------------------------


def test_store_skips_complete_jobs_and_keeps_results_exact(tmp_path):
    jobs = [Job(square_job, {"a": 0.1}, s) for s in range(4)]
    with Executor(Backend(workers=1), tmp_path / "store") as e:
        first = e.map(jobs, context="c")
    assert (e.computed, e.skipped) == (4, 0)
    store = Store(tmp_path / "store")
    assert sorted(store.keys()) == sorted(job_key(j) for j in jobs)
    assert all(sorted(os.listdir(store.folder(k))) == ["job.json", "result.json"] for k in store.keys())
    assert not [d for d in os.listdir(store.root) if d.startswith(".tmp")]
    with Executor(Backend(workers=1), tmp_path / "store") as e:
        again = e.map(jobs + [Job(square_job, {"a": 0.1}, 9)], context="c")
    assert (e.computed, e.skipped) == (1, 4)  # only the new job ran
    for x, y in zip(first, again):
        assert (x["y"] == y["y"]).all() and x["pair"] == y["pair"] and x["pid"] == y["pid"]


def test_a_result_being_written_is_neither_listed_nor_loaded_until_it_is_complete(tmp_path, monkeypatch):
    """The store's half of a killed sweep: a writer between its last byte and the rename into place (where a SIGKILL
    can land) leaves a temporary folder that holds a result file; no reader may count or serve it."""
    store, job = Store(tmp_path), Job(square_job, {"a": 2.0}, 1)
    key, seen = job_key(job), {}
    real_replace = os.replace

    def replace_seen_first(src, dst):
        seen.update(keys=store.keys(), text=store.load(key))  # what a reader sees just before the rename
        real_replace(src, dst)

    monkeypatch.setattr(ex.os, "replace", replace_seen_first)
    store.save(key, job, '{"x":1}')
    assert seen == {"keys": [], "text": None}
    assert store.keys() == [key] and store.load(key) == '{"x":1}'


def test_a_writer_killed_before_its_rename_leaves_nothing_counted_as_a_result(tmp_path):
    """A temporary folder left by a killed writer (result file complete, never renamed) is not a result: the key
    stays missing, the job runs again and its result is then stored normally."""
    store, job = Store(tmp_path), Job(square_job, {"a": 2.0}, 1)
    key = job_key(job)
    left = os.path.join(tmp_path, key[:2], f".tmp-{key[:8]}-killed")
    os.makedirs(left)
    with open(os.path.join(left, "result.json"), "w") as f:
        f.write(ex.dumps(square_job({"a": 2.0}, 1, None)))
    assert store.keys() == [] and store.load(key) is None
    with Executor(Backend(workers=1), store) as e:
        e.map([job])
    assert (e.computed, e.skipped) == (1, 0) and store.keys() == [key]


def test_local_worker_processes_give_the_in_process_results(tmp_path):
    jobs = [Job(square_job, {"a": 1.5}, s) for s in range(3)]
    with Executor(Backend(workers=1)) as e:
        here = e.map(jobs, context=[1, 2])
    with Executor(Backend(workers=2)) as e:
        there = e.map(jobs, context=[1, 2], fresh_process=True)
    assert {r["pid"] for r in here} == {os.getpid()}
    assert os.getpid() not in {r["pid"] for r in there} and len({r["pid"] for r in there}) == 3  # fresh each
    for a, b in zip(here, there):
        assert (a["y"] == b["y"]).all() and a["pair"] == b["pair"] and b["ctx"] == [1, 2]


def test_a_failing_job_is_named_and_earlier_results_are_kept(tmp_path):
    jobs = [Job(square_job, {"a": 1.0}, 0), Job(failing_job, {"a": 7}, 1, label="the bad one")]
    with Executor(Backend(workers=1), tmp_path) as e, \
            pytest.raises(RuntimeError, match="job the bad one .*bad value 7"):
        e.map(jobs)
    assert len(Store(tmp_path).keys()) == 1
    with Executor(Backend(workers=1)) as e, pytest.raises(RuntimeError, match="plain data"):
        e.map([Job(object_job, {}, 0)])


def test_an_interrupted_sweep_restarted_recomputes_only_the_missing_jobs(tmp_path):
    """ehss reproduce --quick killed (SIGKILL) once some batches are stored; the same command then computes only the
    others and writes the report."""
    store, out = tmp_path / "store", tmp_path / "out"
    argv = [sys.executable, "-m", "ehss_gym.cli", "reproduce", "--quick", "--no-progress", "--store", str(store),
            "--out", str(out)]
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 600
        while len(Store(store).keys()) < 6 and proc.poll() is None and time.time() < deadline:
            time.sleep(0.2)
        assert proc.poll() is None, "the sweep ended before it could be interrupted"
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait()
    done = len(Store(store).keys())
    assert 6 <= done < 25
    res = subprocess.run(argv, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    m = re.search(r"\((\d+) simulation batch\(es\) computed, (\d+) from the store\)", res.stdout)
    computed, skipped = int(m.group(1)), int(m.group(2))
    assert skipped == done and computed == len(Store(store).keys()) - done > 0
    assert sorted(p.name for p in out.rglob("*.csv")) and (out / "REPORT.md").is_file()
    # (a stored result decodes to the computed one exactly: test_store_skips_complete_jobs_and_keeps_results_exact)


# --- bad input --------------------------------------------------------------------------------------------


COMMANDS = {"evaluate": ["evaluate", "--quick", "--policies", "clf-n2", "--suite", "paper", "--task", "velocity"],
            "reproduce": ["reproduce", "--quick"],
            "train": ["train", "--seeds", "0-1", "--timesteps", "64"]}


@pytest.mark.parametrize("cmd", sorted(COMMANDS))
def test_an_unknown_backend_exits_2_naming_it(cmd, tmp_path, capsys):
    argv = [*COMMANDS[cmd], "--out", str(tmp_path), "--store", str(tmp_path / "jobs")]
    assert cli_main([*argv, "--backend", "dask"]) == 2
    err = capsys.readouterr().err
    assert "--backend must be one of local, ray, got 'dask'" in err


@pytest.mark.parametrize("cmd", sorted(COMMANDS) + ["tune"])
def test_ray_asked_for_without_ray_installed_exits_2_saying_how_to_install_it(cmd, tmp_path, capsys, monkeypatch):
    real = ex.importlib.import_module

    def no_ray(name, *a):
        if name == "ray" or name.startswith("ray."):
            raise ModuleNotFoundError("No module named 'ray'")
        return real(name, *a)

    monkeypatch.setattr(ex.importlib, "import_module", no_ray)
    argv = ["tune", "--trials", "1"] if cmd == "tune" else [*COMMANDS[cmd], "--backend", "ray", "--store",
                                                              str(tmp_path / "jobs")]
    assert cli_main([*argv, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "needs Ray, which is not installed" in err and "pip install 'ehss-gym[ray]'" in err


@pytest.mark.parametrize("cmd", sorted(COMMANDS) + ["tune"])
def test_an_unreachable_address_exits_2_naming_it(cmd, tmp_path, capsys):
    pytest.importorskip("ray")
    argv = ["tune", "--trials", "1"] if cmd == "tune" else [*COMMANDS[cmd], "--backend", "ray", "--store",
                                                              str(tmp_path / "jobs")]
    t0 = time.perf_counter()
    assert cli_main([*argv, "--out", str(tmp_path), "--address", "127.0.0.1:9"]) == 2
    err = capsys.readouterr().err
    assert "--address 127.0.0.1:9: no Ray cluster reachable there" in err
    assert time.perf_counter() - t0 < 60  # not Ray's own minute-long connection retries


def test_an_unreachable_address_is_an_error_even_when_the_store_holds_every_result(tmp_path, capsys):
    """A command asked to reach a cluster says it cannot, rather than answering from the store without trying."""
    pytest.importorskip("ray")
    jobs = [Job(square_job, {"a": 1.0}, s) for s in range(2)]
    with Executor(Backend(workers=1), tmp_path / "store") as e:
        e.map(jobs)
    with pytest.raises(ExecutionError, match="--address 127.0.0.1:9: no Ray cluster reachable there"):
        with Executor(Backend("ray", address="127.0.0.1:9"), tmp_path / "store") as e:
            e.map(jobs)
    argv = [*COMMANDS["evaluate"], "--out", str(tmp_path / "out"), "--store", str(tmp_path / "jobs")]
    assert cli_main(argv) == 0
    capsys.readouterr()
    assert cli_main([*argv, "--backend", "ray", "--address", "127.0.0.1:9"]) == 2
    assert "--address 127.0.0.1:9: no Ray cluster reachable there" in capsys.readouterr().err


def test_address_without_the_ray_backend_and_a_malformed_address_are_refused():
    with pytest.raises(ExecutionError, match="needs --backend ray"):
        Backend("local", address="127.0.0.1:6379").validate()
    with pytest.raises(ExecutionError, match="must be HOST:PORT"):
        ex.check_address("localhost")
    with pytest.raises(ExecutionError, match="--workers must be an integer >= 1"):
        Backend("local", workers=0).validate()
