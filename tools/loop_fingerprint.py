"""Fingerprint the loop at the env's defaults, to check that a change leaves it bit for bit as it was.

Usage::

    PYTHONPATH=<other checkout> python tools/loop_fingerprint.py before.npz   # the other version's loop
    python tools/loop_fingerprint.py after.npz                                # this checkout's
    python tools/loop_fingerprint.py --compare before.npz after.npz

Per task, with whichever ``ehss_gym`` is imported: ``simulate_batch`` on the 48 held-out scenarios, the paper's run
and 8 training scenarios (the first 30 log columns and the accumulators), and the native vector env (4 lanes, 3000
agent steps of seeded random residuals: observations and rewards). ``--compare`` reports, per array, whether the two
files hold the same bytes.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

LOG_COLUMNS = 30  # the log columns every version since the ruler has


def fingerprint(path: str) -> None:
    """Write the arrays of the module docstring to ``path`` (.npz)."""
    import ehss_gym
    from ehss_gym import simulate_batch
    from ehss_gym.core.scenarios import heldout_scenarios, paper_scenario, sample_scenario
    from ehss_gym.envs.config import EnvConfig
    from ehss_gym.envs.vector import EHSSTrackingVectorEnv

    print(f"ehss_gym from {ehss_gym.__file__}")
    out = {}
    for task in ("velocity", "position"):
        tmpl = EnvConfig.from_kwargs({"task": task}).template()
        scs = heldout_scenarios(48, tmpl) + [paper_scenario(tmpl)] + [sample_scenario(s, tmpl) for s in range(8)]
        trs = simulate_batch(scs)
        out[f"{task}_log"] = np.concatenate([t.log[:, :LOG_COLUMNS] for t in trs])
        out[f"{task}_acc"] = np.stack([t.acc for t in trs])
        env = EHSSTrackingVectorEnv(4, task=task)
        obs, _ = env.reset(seed=3)
        rng = np.random.default_rng(0)
        observations, rewards = [obs], []
        for _ in range(3000):
            obs, r, _, _, _ = env.step(rng.uniform(-1, 1, (4, 1)).astype(np.float32))
            observations.append(obs)
            rewards.append(r)
        out[f"{task}_obs"], out[f"{task}_rew"] = np.stack(observations), np.stack(rewards)
    np.savez(path, **out)


def compare(a_path: str, b_path: str) -> int:
    """Print per array whether the two fingerprints are equal byte for byte; 0 if all are."""
    a, b = np.load(a_path), np.load(b_path)
    same = True
    for k in sorted(set(a.files) | set(b.files)):
        eq = k in a.files and k in b.files and a[k].shape == b[k].shape and a[k].tobytes() == b[k].tobytes()
        same &= eq
        print(f"{k}: {'bitwise equal' if eq else 'DIFFERENT'}")
    return 0 if same else 1


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("paths", nargs="+", help="the .npz to write, or with --compare the two to compare")
    p.add_argument("--compare", action="store_true", help="compare two fingerprints")
    a = p.parse_args()
    if a.compare:
        return compare(*a.paths[:2])
    fingerprint(a.paths[0])
    return 0


if __name__ == "__main__":
    sys.exit(main())
