"""The note on stderr while numba compiles the package's kernels on a cold cache (ehss_gym/core/compile_note.py),
and ``ehss warmup``, which compiles them ahead.

The subprocess tests compile only what ``gym.make`` compiles (two small kernels, under a CPU-second) in a fresh
numba cache under tmp_path: about 6 CPU-seconds for the file's default tests (three interpreters that import the
package; pytest's start-up included), not the tens of seconds of the env's first step. The ``slow`` test compiles
the env's kernels cold (about 56 CPU-seconds).
"""

import os
import subprocess
import sys
from types import SimpleNamespace

import pytest

from ehss_gym.core.compile_note import CompileNote
from ehss_gym.infra import NO_COMPILE_NOTE_ENV

# the first kernels a Gymnasium user meets: gym.make compiles the plant's and the controller's constants
MAKE = "import gymnasium as gym, ehss_gym; gym.make('EHSSTracking-v0')"
# a user's first steps: the env's kernels
STEP = MAKE.replace("gym.make('EHSSTracking-v0')", "env = gym.make('EHSSTracking-v0'); env.reset(seed=0); "
                    "env.step(env.action_space.sample())")
FIRST_LINE = "compiling the simulator's kernels once"
SECOND_LINE = "kernels compiled in"


def make_env(tmp_path, cache: str, *args: str, **env) -> subprocess.CompletedProcess:
    """``python -c MAKE`` (or ``python args``) in a fresh interpreter with numba's cache in ``tmp_path/cache``."""
    run_env = {k: v for k, v in os.environ.items() if k != NO_COMPILE_NOTE_ENV}
    run_env.update(NUMBA_CACHE_DIR=str(tmp_path / cache), **env)
    return subprocess.run([sys.executable, *(args or ("-c", MAKE))], env=run_env, cwd=tmp_path, capture_output=True,
                          text=True, check=True, timeout=1800)


def test_the_note_on_a_cold_cache_and_not_on_a_warm_one(tmp_path):
    cold = make_env(tmp_path, "numba")
    lines = [line for line in cold.stderr.splitlines() if line.startswith("ehss-gym: ")]
    assert len(lines) == 2, cold.stderr
    assert FIRST_LINE in lines[0] and str(tmp_path / "numba") in lines[0]  # where the cache goes
    assert SECOND_LINE in lines[1] and "CPU-seconds" in lines[1]
    assert cold.stdout == ""  # stdout is the caller's (the CLI's output is parsed)
    assert any(tmp_path.joinpath("numba").rglob("*.nbi"))  # numba did write the cache the note speaks of
    warm = make_env(tmp_path, "numba")
    assert "ehss-gym:" not in warm.stderr and warm.stdout == ""


def test_the_note_can_be_hidden(tmp_path):
    cold = make_env(tmp_path, "numba", **{NO_COMPILE_NOTE_ENV: "1"})
    assert any(tmp_path.joinpath("numba").rglob("*.nbi"))  # it did compile
    assert "ehss-gym:" not in cold.stderr and cold.stdout == ""


def _event(module: str = "ehss_gym.core.physics", cache_path: str | None = "/cache/core"):
    fn = SimpleNamespace(__module__=module)
    return SimpleNamespace(data={"dispatcher": SimpleNamespace(py_func=fn, stats=SimpleNamespace(
        cache_path=cache_path))})


def _compile(note: CompileNote, *events) -> None:
    """Compilations nested in the order given (the first outermost)."""
    for ev in events:
        note.on_start(ev)
    for ev in reversed(events):
        note.on_end(ev)


def _notes(capsys) -> list[str]:
    return [line for line in capsys.readouterr().err.splitlines() if line.startswith("ehss-gym: ")]


def test_one_note_for_the_compilations_in_a_row_and_their_callees(capsys, monkeypatch):
    monkeypatch.delenv(NO_COMPILE_NOTE_ENV, raising=False)
    note = CompileNote(quiet_seconds=600.0)  # the timer never fires by itself here: close() stands for it
    _compile(note, _event(), _event(), _event("ehss_gym.envs.kernels"))  # a kernel and its callees
    _compile(note, _event("ehss_gym.envs.kernels"))  # the next top-level kernel, within the quiet time
    assert len(_notes(capsys)) == 1  # only the first line so far
    note.close()
    assert [SECOND_LINE in line for line in _notes(capsys)] == [True]
    note.close()  # the process's exit: nothing left to say
    assert _notes(capsys) == []
    _compile(note, _event())  # later in the same process: a note of its own
    note.close()
    assert ["compiling more" in line for line in _notes(capsys)] == [True, False]


def test_no_note_for_other_code_or_uncached_kernels(capsys, monkeypatch):
    monkeypatch.delenv(NO_COMPILE_NOTE_ENV, raising=False)
    note = CompileNote(quiet_seconds=600.0)
    _compile(note, _event(module="user_code"), _event(cache_path=None))  # a user's kernel; one numba never caches
    note.close()
    assert _notes(capsys) == []
    _compile(note, _event(module="user_code"), _event())  # a user's kernel calling ours: ours still compile
    note.close()
    assert len(_notes(capsys)) == 2


@pytest.mark.slow
def test_after_warmup_a_first_env_step_compiles_nothing(tmp_path):
    """``ehss warmup --part env`` (with --no-progress: no note) leaves nothing for a user's first env step to compile:
    its list of kernels is the code paths it runs, and this checks that they are the env's."""
    warm = make_env(tmp_path, "numba", "-m", "ehss_gym.cli", "warmup", "--part", "env", "--no-progress")
    assert "ehss-gym:" not in warm.stderr and "kernels compiled or loaded (env " in warm.stdout
    first = make_env(tmp_path, "numba", "-c", STEP)
    assert "ehss-gym:" not in first.stderr and first.stdout == ""
