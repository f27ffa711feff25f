"""How much of the scripted laws' error on the unmodelled suite each unmodelled effect causes, one cause at a time.

Usage::

    python tools/unmodelled_ablation.py [--episodes 8]

Per task, the episodes of ``ehss evaluate``'s unmodelled suite (the first ``--episodes`` of them) are run by the
scripted laws (``clf-n2``, ``clf-n4``, ``clf-n6``: the env's defaults at that n; ``dob-n2``: n = 2 with the disturbance
observer at ``DOB_HZ``) with the effects as drawn ("all"), none of them ("none": the same episodes as the model sees
them), and each group alone: the valve's threshold and hysteresis ("valve"), the sensor delay ("delay"), the
encoder and velocity quantisation ("quant"). Printed: the means over episodes of the tracking-window RMSE of the true
error (``trk_rmse``, output unit), the disturbance-window peak (``dst_peak``) and the control TV rate (``tv_u_rate``,
mA/s), and each variant's ratio to "none".
"""

from __future__ import annotations

import argparse

import numpy as np

from ehss_gym.controllers import DOB_HZ
from ehss_gym.core.sim import simulate_batch
from ehss_gym.core.unmodelled import NONE
from ehss_gym.envs import EnvConfig
from ehss_gym.evaluation.suites import EvalConfig, build_episodes

LAWS = {"clf-n2": {"n": 2}, "clf-n4": {"n": 4}, "clf-n6": {"n": 6}, "dob-n2": {"n": 2, "dob_hz": DOB_HZ}}
KEYS = ("trk_rmse", "dst_peak", "tv_u_rate")


def variants(um) -> dict:
    """The effects of one episode, all, none and each group alone."""
    return {"all": um, "none": NONE,
            "valve": NONE.__class__(threshold=um.threshold, hysteresis=um.hysteresis),
            "delay": NONE.__class__(delay=um.delay),
            "quant": NONE.__class__(encoder_counts=um.encoder_counts, velocity_step=um.velocity_step)}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=8, help="unmodelled-suite episodes per task (default 8)")
    args = ap.parse_args(argv)
    for task in ("velocity", "position"):
        eps = build_episodes(EvalConfig(suites=("unmodelled",), tasks=(task,), heldout_episodes=args.episodes))
        for law, kw in LAWS.items():
            tmpl = EnvConfig.from_kwargs({"task": task, **kw}).template()
            names = list(variants(NONE))
            scs = [tmpl.replace(**{**ep.physical, "unmodelled": variants(ep.physical["unmodelled"])[v]})
                   for v in names for ep in eps]
            ms = [t.metrics() for t in simulate_batch(scs)]
            means = {v: {k: float(np.nanmean([m[k] for m in ms[i * len(eps):(i + 1) * len(eps)]])) for k in KEYS}
                     for i, v in enumerate(names)}
            lost = {v: sum(bool(m["lost_track"]) or bool(m["diverged"]) for m in ms[i * len(eps):(i + 1) * len(eps)])
                    for i, v in enumerate(names)}
            for v in names:
                ratio = "  ".join(f"{k}/none {means[v][k] / means['none'][k]:7.3g}" for k in KEYS)
                vals = "  ".join(f"{k} {means[v][k]:.3g}" for k in KEYS)
                print(f"{task:8s} {law:7s} {v:6s} {vals}  {ratio}  lost {lost[v]}/{len(eps)}")


if __name__ == "__main__":
    main()
