"""Issue 16 bug 3: a quick run never writes into the committed reports/ (or docs/) unless --out says so."""

import types

import pytest

from ehss_gym.cli import bench, evaluate, fidelity, main, reproduce


@pytest.fixture
def captured(monkeypatch, tmp_path):
    """Each report command's heavy work replaced by a recorder of where it would write."""
    monkeypatch.chdir(tmp_path)
    seen = {}

    def fake_write_report(res, out):
        seen["evaluate"] = out
        return out + "/REPORT.md"

    fake_res = types.SimpleNamespace(rows=[], wall_time=0.0, workers=1, timings={}, summary=[], notes=[], started=0.0)
    monkeypatch.setattr(evaluate, "evaluate", lambda *a, **k: fake_res)
    monkeypatch.setattr(evaluate, "write_report", fake_write_report)
    monkeypatch.setattr(reproduce, "main_reproduce",
                        lambda out, quick=False, progress=True, cmd=None, executor=None:
                        seen.setdefault("reproduce", out))

    def fake_fidelity(out, docs, quick=False, progress=True, cmd=""):
        seen["fidelity"] = (out, docs)
        return out

    monkeypatch.setattr(fidelity, "measure_and_write", fake_fidelity)
    fake_bench = types.SimpleNamespace(build_parser=lambda: _bench_parser(),
                                       run=lambda args, cmd: seen.setdefault("bench", args.out) and 0)
    monkeypatch.setattr(bench, "_benchmarks_module", lambda: fake_bench)
    return seen


def _bench_parser():
    import argparse

    from benchmarks.__main__ import add_arguments

    p = argparse.ArgumentParser()
    add_arguments(p)
    return p


@pytest.mark.parametrize("cmd", ["evaluate", "reproduce", "fidelity", "bench"])
def test_quick_runs_write_under_runs_quick(captured, cmd):
    assert main([cmd, "--quick", "--no-progress"] if cmd != "bench" else [cmd, "--quick"]) == 0
    out = captured[cmd][0] if cmd == "fidelity" else captured[cmd]
    assert out.replace("\\", "/").startswith("runs/quick/"), out
    if cmd == "fidelity":
        assert captured[cmd][1] is None  # docs/MODEL.md is left alone too


@pytest.mark.parametrize("cmd,shipped", [("evaluate", "reports/comparison"), ("reproduce", "reports/paper"),
                                         ("fidelity", "reports/fidelity"), ("bench", "reports/perf")])
def test_full_runs_and_explicit_out_keep_their_folders(captured, cmd, shipped):
    extra = [] if cmd == "bench" else ["--no-progress"]
    extra += ["--docs", "none"] if cmd == "fidelity" else []  # no docs/MODEL.md in this folder
    assert main([cmd, *extra]) == 0
    out = captured.pop(cmd)
    assert (out[0] if cmd == "fidelity" else out).replace("\\", "/") == shipped
    assert main([cmd, "--quick", "--out", "reports/mine", *extra]) == 0
    out = captured.pop(cmd)
    assert (out[0] if cmd == "fidelity" else out) == "reports/mine"
