"""Compile numba's kernels into the session's cache before the test workers start (``tests/conftest.py``).

``python tests/warm_kernels.py sim|env``: one part of ``ehss warmup`` (:mod:`ehss_gym.cli.warmup`): the simulator's
kernels and the step bound's, or the env's, two sets that share almost nothing and so compile side by side in two
processes. With a warm cache each takes the time to load it (a few seconds). Without this, every xdist worker, every
worker process of an ``ehss evaluate`` under test and every Ray worker compiled the kernels it met first, each on its
own.
"""

from __future__ import annotations

import sys

from ehss_gym.cli.warmup import PARTS

if __name__ == "__main__":
    if len(sys.argv) != 2 or sys.argv[1] not in PARTS:
        raise SystemExit(f"usage: python {sys.argv[0]} {'|'.join(PARTS)}")
    PARTS[sys.argv[1]]()
