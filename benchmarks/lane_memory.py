"""Memory of the native vector env per sub-env (lane): its buffers' bytes, the resident set it holds, and its peak.

Run in a fresh subprocess per size (``python -m benchmarks.lane_memory --child N``) so nothing else inflates it:
the child imports ehss_gym, steps a one-lane vector env (kernels loaded), reads its resident set (``/proc/self/statm``)
as the baseline, then makes a vector env of N sub-envs, resets it and steps it AGENT_STEPS times with random actions
(episodes end and reset within them), and reads it again while the env is alive; and the peak over the same span
(:func:`benchmarks.common.reset_peak_rss` before, :func:`benchmarks.common.peak_rss` after).

The buffers' bytes are the sum of ``nbytes`` of every array the env's lanes own (the hot blocks, the per-lane
buffers, the compiled step's scratch, the observations); views of them are not counted twice.
"""

from __future__ import annotations

import sys

import numpy as np

from .common import child_main, current_rss, peak_rss, reset_peak_rss, run_child

AGENT_STEPS = 500  # more than an episode of EPISODE_SECONDS (400 agent steps at the default periods): resets included
EPISODE_SECONDS = 0.1
SIZES = (64, 4096)  # sub-envs of the two children whose difference gives the per-lane figures


def owned_bytes(obj) -> int:
    """Sum of ``nbytes`` of the numpy arrays among ``obj``'s attributes that own their memory."""
    return sum(v.nbytes for v in vars(obj).values() if isinstance(v, np.ndarray) and v.base is None)


def child(n: int) -> dict:
    """Run in the subprocess: the resident set before and after a vector env of ``n`` sub-envs has stepped, and its
    buffers' bytes."""
    from ehss_gym.envs.vector import EHSSTrackingVectorEnv

    warm = EHSSTrackingVectorEnv(1, episode_seconds=EPISODE_SECONDS)
    warm.reset(seed=0)
    warm.step(np.zeros((1,) + warm.single_action_space.shape, dtype=np.float32))
    warm.close()
    base = current_rss()
    reset_peak_rss()
    env = EHSSTrackingVectorEnv(n, episode_seconds=EPISODE_SECONDS)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(AGENT_STEPS):
        env.step(rng.uniform(-1.0, 1.0, (n,) + env.single_action_space.shape).astype(np.float32))
    return {"n": n, "baseline_rss": base, "rss": current_rss(), "peak_rss": peak_rss(),
            "buffer_bytes": owned_bytes(env._lanes)}


def measure() -> dict:
    """:func:`child` at each of SIZES, each in a fresh process, and the per-lane figures from their difference:
    ``buffers_per_lane``, ``rss_per_lane`` (the resident set the env holds) and ``peak_per_lane`` (the peak it adds)
    [bytes], and the children's results under ``runs``."""
    runs = [run_child("lane_memory", [n], timeout=1800) for n in SIZES]
    a, b = runs
    dn = b["n"] - a["n"]
    return {"runs": runs, "buffers_per_lane": (b["buffer_bytes"] - a["buffer_bytes"]) / dn,
            "rss_per_lane": ((b["rss"] - b["baseline_rss"]) - (a["rss"] - a["baseline_rss"])) / dn,
            "peak_per_lane": ((b["peak_rss"] - b["baseline_rss"]) - (a["peak_rss"] - a["baseline_rss"])) / dn}


def main(argv=None) -> int:
    return child_main(child, {"N": int}, "vector env memory benchmark child", argv)


if __name__ == "__main__":
    sys.exit(main())
