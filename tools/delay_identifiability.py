"""Whether the residual agent's observation tells the episode's sensor delay: a classifier on what the agent sees.

Usage::

    python tools/delay_identifiability.py [--episodes 48] [--task position] [--action MODE] [--probe A]
        [--probe-period STEPS] [--probe-seconds T]

Why: on the unmodelled suite the oracle that knows each episode's sensor delay (1 or 2 control samples, equally
likely) and compensates it is the one that reaches the largest gain in position (reports/headroom); its causal
counterpart ``dcomp-n2`` compensates a fixed 1 sample. A residual policy gains over ``dcomp-n2`` from the delay only if
it can tell a 2-sample episode from a 1-sample one from its observations.

How: each of the first ``--episodes`` episodes of ``ehss evaluate``'s unmodelled suite is run twice, with its delay set
to 1 and to 2 samples and everything else (reference, plant, valve, quantisation, noise seed) the same, in the
residual agents' env (``agents.specs``' residual-sac env settings; action 0, i.e. the base law, as at the start of
training). Per run, features of every observation entry over the episode (mean, standard deviation, the
autocorrelation at lags 1 and 5 agent steps, its slope on and correlation with the reference model output's rate)
feed an L2-regularised logistic regression, scored by cross-validation with both runs of an episode in the same fold
(10 folds), so the classifier cannot recognise an episode and must recognise the delay. The positive
control gives the same classifier the same features of the true output error (y - y_ref, which the agent does not
see): it shows the classifier finds the delay when a signal carries it.

The rule, written before the runs: the observation "carries the delay" if the cross-validated accuracy's 95 % Wilson
interval lies above 0.5; "shows no sign of it" if the interval contains 0.5. The verdict counts only if the positive
control's accuracy is at least 0.95 (otherwise the classifier is too weak to judge). What it cannot see: a policy
that probes the loop (moves its action to excite it) may learn more than the base law's own runs show.

``--probe A`` asks that question for one probe: the runs act with a square wave of +-A action units on every entry
of the action (``--action``, default the residual agents' schedule; the reference action moves the law's reference
instead), a period of ``--probe-period`` agent steps, the same in both runs of an episode; ``--probe-seconds T``
probes only in the episode's first T seconds and classifies on that time only. The rule above judges it unchanged
(written before the probe's runs): an interval above 0.5 says a policy that probes this way can tell the delay from
what it observes, which a policy with memory could then use; an interval containing 0.5 says this probe does not bring
it out (another probe might). The probe's cost is printed too: the ruler's overall figure of the probed runs against
the base law on the same runs, which is what a policy pays to learn the delay this way.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace

import numpy as np

from ehss_gym.agents.specs import get_spec
from ehss_gym.envs import EnvConfig
from ehss_gym.envs.actions import action_dims, action_mode
from ehss_gym.envs.rollouts import rollout
from ehss_gym.evaluation.scoring import episode_log_ratios, figure_of
from ehss_gym.evaluation.suites import EvalConfig, build_episodes

LAGS = (1, 5)  # autocorrelation lags [agent steps]
FOLDS = 10
L2 = 1.0  # the logistic regression's ridge on standardised features


class Recorder:
    """The zero action (the base law), or with ``probe`` > 0 a probe: a square wave of +-``probe`` on every action
    entry with a period of ``period`` agent steps (the same in every run, so any difference it brings out is the
    delay's); records every observation batch it is given (SB3's predict signature)."""

    def __init__(self, action_dims: int, probe: float = 0.0, period: int = 10, steps: int | None = None):
        self.dims, self.seen, self.probe, self.period, self.steps = action_dims, [], probe, period, steps

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        j = len(self.seen)
        self.seen.append(np.array(observation, dtype=np.float64))
        on = self.steps is None or j < self.steps
        a = self.probe * (1.0 if (j // (self.period // 2 or 1)) % 2 == 0 else -1.0) if on else 0.0
        return np.full((len(observation), self.dims), a, dtype=np.float32), state


def features(x: np.ndarray, rate: np.ndarray) -> np.ndarray:
    """Per column of x (T, D): mean, standard deviation, autocorrelation at :data:`LAGS`, and the slope and correlation
    of the column on ``rate`` (T,), the reference model output's rate (a delay d shifts the true output by about
    d h times it); shape (D * 6,)."""
    ok = np.isfinite(x).all(axis=1) & np.isfinite(rate)
    x, rate = x[ok], rate[ok]
    mu, sd = x.mean(axis=0), x.std(axis=0)
    z = (x - mu) / np.where(sd > 0.0, sd, 1.0)
    ac = [np.mean(z[lag:] * z[:-lag], axis=0) for lag in LAGS]
    r = rate - rate.mean()
    cov = (x - mu).T @ r / len(r)
    slope = cov / max(float(np.mean(r * r)), 1e-300)
    corr = cov / (np.where(sd > 0.0, sd, 1.0) * max(float(r.std()), 1e-300))
    return np.concatenate([mu, sd, *ac, slope, corr])


def probe_cost(probed: list[dict], base: list[dict], runs: list[dict], task: str) -> tuple[float, dict]:
    """The ruler's overall figure of the probed runs against the base law's on the same runs (the geometric mean of
    the classes' geometric means of the episodes' ratios), and each class's figure."""
    logs: dict = {}
    for m, b, p in zip(probed, base, runs):
        noisy = any(v > 0.0 for v in p["noise_std"])
        for c, v in episode_log_ratios(m, b, noisy, task).items():
            logs.setdefault(c, []).append(v)
    return figure_of(logs)


def logistic_fit(X: np.ndarray, y: np.ndarray, l2: float = L2, iters: int = 50) -> np.ndarray:
    """Weights (with the bias last) of an L2-regularised logistic regression, by Newton's method."""
    A = np.hstack([X, np.ones((len(X), 1))])
    w = np.zeros(A.shape[1])
    reg = np.full(A.shape[1], l2)
    reg[-1] = 0.0  # the bias is not shrunk
    for _ in range(iters):
        p = 1.0 / (1.0 + np.exp(-np.clip(A @ w, -30.0, 30.0)))
        g = A.T @ (p - y) + reg * w
        H = (A * (p * (1.0 - p))[:, None]).T @ A + np.diag(reg) + 1e-9 * np.eye(A.shape[1])
        step = np.linalg.solve(H, g)
        w -= step
        if np.max(np.abs(step)) < 1e-10:
            break
    return w


def cv_accuracy(F: np.ndarray, y: np.ndarray, group: np.ndarray, folds: int = FOLDS) -> float:
    """Cross-validated accuracy, the rows of a group always in the same fold; features standardised on the training
    rows of each fold."""
    ids = np.unique(group)
    fold_of = {g: i % folds for i, g in enumerate(ids)}
    f = np.array([fold_of[g] for g in group])
    right = 0
    for k in range(folds):
        tr, te = f != k, f == k
        if not te.any():
            continue
        mu, sd = F[tr].mean(axis=0), F[tr].std(axis=0)
        sd = np.where(sd > 0.0, sd, 1.0)
        w = logistic_fit((F[tr] - mu) / sd, y[tr])
        pred = np.hstack([(F[te] - mu) / sd, np.ones((te.sum(), 1))]) @ w > 0.0
        right += int(np.sum(pred == (y[te] > 0.5)))
    return right / len(y)


def wilson(p: float, n: int, z: float = 1.96) -> tuple[float, float]:
    """The 95 % Wilson interval of a proportion p of n trials."""
    d = 1.0 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1.0 - p) / n + z * z / (4 * n * n)) / d
    return c - h, c + h


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=48, help="unmodelled-suite episodes, each run at delay 1 and 2")
    ap.add_argument("--task", choices=("position", "velocity"), default="position")
    ap.add_argument("--action", default=None,
                    help="the env's action mode (default: the residual agents', agents.specs)")
    ap.add_argument("--probe", type=float, default=0.0,
                    help="amplitude of a square-wave probe on every action entry, in action units (default 0: the "
                         "base law)")
    ap.add_argument("--probe-period", type=int, default=10, help="the probe's period [agent steps]")
    ap.add_argument("--probe-seconds", type=float, default=None,
                    help="probe only for the episode's first this many seconds, and classify on the observations of "
                         "that time only (default: the whole episode)")
    args = ap.parse_args(argv)
    eps = build_episodes(EvalConfig(suites=("unmodelled",), tasks=(args.task,), heldout_episodes=args.episodes))
    runs = [{**ep.physical, "unmodelled": replace(ep.physical["unmodelled"], delay=d)} for d in (1, 2) for ep in eps]
    spec = get_spec("residual-sac")
    kw = {"task": args.task, "n": 2, "mode": spec.mode, **spec.env_kwargs,
          **({"action": args.action} if args.action else {})}
    cfg = EnvConfig.from_kwargs(kw)
    window = None if args.probe_seconds is None else int(round(args.probe_seconds / (cfg.agent_period *
                                                                                      cfg.control_period)))
    rec = Recorder(action_dims(action_mode(cfg.action), cfg.dob_hz), args.probe, args.probe_period, window)
    res = rollout(rec, kw, runs, trace=True)
    obs = np.stack(rec.seen, axis=1)  # (runs, T, D)
    steps = [r.metrics["agent_steps"] if window is None else min(r.metrics["agent_steps"], window) for r in res]
    y = np.array([0.0] * len(eps) + [1.0] * len(eps))
    group = np.array(list(range(len(eps))) * 2)
    # obs[:, j] is what the agent saw before step j, the trace's row j what step j ended with: obs[:, j + 1] and
    # trace row j are the same sample
    rates = [np.gradient(r.trace["y_ref"], r.trace["t"]) for r in res]
    F_obs = np.stack([features(obs[i, 1:steps[i]], rates[i][:steps[i] - 1]) for i in range(len(runs))])
    F_true = np.stack([features((r.trace["y"] - r.trace["y_ref"])[:steps[i], None], rates[i][:steps[i]])
                       for i, r in enumerate(res)])
    n = len(runs)
    probe = (f"a +-{args.probe:g} square-wave probe of {args.probe_period} agent steps on action {cfg.action!r}"
             if args.probe > 0.0 else f"the base law (action {cfg.action!r} zero)")
    if window is not None:
        probe += f", the first {window} agent steps only"
    print(f"{args.task}: {len(eps)} unmodelled episodes x delay 1 and 2 samples = {n} runs under {probe}, "
          f"{obs.shape[2]} observation entries, {F_obs.shape[1]} features")
    acc_c = cv_accuracy(F_true, y, group)
    lo_c, hi_c = wilson(acc_c, n)
    print(f"positive control (the true error, unseen by the agent): accuracy {acc_c:.3f} [{lo_c:.3f}, {hi_c:.3f}]")
    acc = cv_accuracy(F_obs, y, group)
    lo, hi = wilson(acc, n)
    print(f"the agent's observation: accuracy {acc:.3f} [{lo:.3f}, {hi:.3f}]")
    if args.probe > 0.0:
        base = rollout(Recorder(rec.dims), kw, runs)  # the base law on the same runs: the probe's cost
        g, cls = probe_cost([r.metrics for r in res], [r.metrics for r in base], runs, args.task)
        print(f"the probe's cost: the ruler's overall figure {g:.3f} against the base law on the same runs ("
              + ", ".join(f"{c} {v:.3f}" for c, v in cls.items()) + ")")
    if acc_c < 0.95:
        print("verdict: none (the positive control is below 0.95: the classifier is too weak to judge)")
    elif lo > 0.5:
        print("verdict: the observation carries the delay")
    else:
        print("verdict: the observation shows no sign of the delay (its interval contains 0.5)")


if __name__ == "__main__":
    main()
