"""docs/RAY.md's cluster on one machine, run as written on a machine where Ray never ran (an empty home folder: no
``~/.ray``, no token): the documented commands make the cluster's token, start the head, run an ``ehss`` job on it
and remove the token.

Two changes to the commands, both about sharing the machine: the port is a free one instead of 6379, and the head
runs with ``--block`` under ``setsid`` so that the test stops its own process group instead of ``ray stop`` (which
stops every Ray process of the machine). The ``ehss evaluate --quick`` of the docs is cut to one held-out episode
of one law (options appended to the documented line): the same path, a job on the cluster, in seconds.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time

import pytest

from ehss_gym.infra.execution import numba_cache_dir

pytest.importorskip("ray")
pytestmark = pytest.mark.xdist_group("ray")  # one Ray cluster at a time on the machine

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SMALL = ["--suite", "heldout", "--task", "velocity", "--policies", "clf-n2", "--episodes", "1", "--n-boot", "100",
         "--no-store", "--no-progress"]


def doc_block(name: str) -> list[str]:
    """The command lines of docs/RAY.md's bash block after ``<!-- one-machine-cluster:NAME -->``."""
    text = open(os.path.join(ROOT, "docs", "RAY.md"), encoding="utf-8").read()
    m = re.search(rf"<!-- one-machine-cluster:{name} -->\s*```bash\n(.*?)```", text, re.S)
    assert m, f"docs/RAY.md has no bash block after <!-- one-machine-cluster:{name} -->"
    return [ln for ln in m.group(1).splitlines() if ln.strip()]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _script(port: int, out: str, ray_log: str, group_file: str) -> str:
    """The documented commands as one bash script (the two changes of the module docstring)."""
    lines = ["set -euo pipefail"]
    for ln in doc_block("start"):
        if ln.startswith("ray start"):
            lines.append(f"setsid {ln} --block > {ray_log} 2>&1 &")
            lines.append(f"echo $! > {group_file}")
            lines.append(f"for _ in $(seq 120); do grep -q 'Ray runtime started' {ray_log} && break; sleep 1; done")
            lines.append(f"grep -q 'Ray runtime started' {ray_log}")
        else:
            lines.append(ln)
    lines += [f"{ln} {' '.join(SMALL)} --out {out}" for ln in doc_block("use")]
    lines += [ln for ln in doc_block("stop") if not ln.startswith("ray stop")]
    lines.append('test ! -e "$RAY_AUTH_TOKEN_PATH"')  # the token went with the cluster
    return "\n".join(ln.replace("6379", str(port)) for ln in lines) + "\n"


def _stop_group(group_file: str) -> None:
    """SIGTERM, then SIGKILL, to the head's process group (the cluster's processes only)."""
    try:
        pgid = int(open(group_file).read())
    except (OSError, ValueError):
        return
    for sig, wait in ((signal.SIGTERM, 45), (signal.SIGKILL, 0)):
        try:
            os.killpg(pgid, sig)
        except ProcessLookupError:
            return
        deadline = time.time() + wait
        while time.time() < deadline:
            try:
                os.killpg(pgid, 0)
            except ProcessLookupError:
                return
            time.sleep(0.5)


def test_the_documented_one_machine_cluster_runs_a_job_where_ray_never_ran(tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    out, group = tmp_path / "eval", str(tmp_path / "group")
    bin_dir = os.path.dirname(sys.executable)
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}  # no token or mode from the caller
    # an empty home folder (no ~/.ray); Ray's session files in a short folder of the test (socket paths must fit in
    # 107 bytes); numba's cache where the package's Ray workers keep it (it is per version of the source)
    session = tempfile.mkdtemp(prefix="ray-")
    env.update(HOME=str(home), PATH=bin_dir + os.pathsep + env.get("PATH", ""), RAY_TMPDIR=session,
               NUMBA_CACHE_DIR=numba_cache_dir())
    try:
        p = subprocess.run(["bash", "-c", _script(_free_port(), str(out), str(tmp_path / "ray.log"), group)],
                           env=env, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    finally:
        _stop_group(group)
        subprocess.run(["rm", "-rf", session], check=False)
    log = (tmp_path / "ray.log").read_text() if (tmp_path / "ray.log").exists() else ""
    assert p.returncode == 0, p.stderr[-3000:] + log[-2000:]
    assert "1 job(s) computed" in p.stderr and (out / "REPORT.md").is_file()
    assert "--backend ray --address 127.0.0.1:" in (out / "REPORT.md").read_text()
    assert not (home / ".ray" / "auth_token").exists()  # the token never went to the home folder

