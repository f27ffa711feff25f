"""Native vector env: N EHSSTracking-v0 loops stepped in one compiled, parallel call.

``EHSSTrackingVectorEnv(num_envs, **kwargs)`` (or ``gymnasium.make_vec("EHSSTracking-v0", num_envs=N,
vectorization_mode="vector_entry_point", **kwargs)``) takes the same keyword arguments as
:class:`ehss_gym.envs.env.EHSSTrackingEnv` and runs the same kernel (:func:`ehss_gym.envs.kernels.advance`) on all lanes
in one compiled call, so sub-env i gives exactly what a single env gives with the same seed. Sub-envs that restarted
at different steps (autoreset after an early end) step in the same call, each from its own step index, at no extra
cost. With ``threads > 1`` the lanes are split into chunks advanced in parallel numba threads (worth it on idle cores
only: on a 2-core machine at load 1.2-1.6, 256 sub-envs ran 1.4-1.8x faster with ``threads=2`` (reports/perf's
runs), while at load ~10 OpenMP barriers made 2 threads 9x slower than 1).

Conventions (Gymnasium 1.x):

- ``reset(seed=s)`` seeds sub-env i with ``s + i`` (a list gives one seed per sub-env), as a single env
  reset with that seed; ``options={"scenario": ...}`` applies to every sub-env, or gives one scenario per
  sub-env as a list of length N; ``options={"reset_mask": mask}`` resets only the masked sub-envs.
- Autoreset mode ``NEXT_STEP`` (default): the step after a sub-env ends returns its reset observation,
  reward 0, ``terminated = truncated = False``, and ignores its action; its ``info["scenario"]`` is set.
  ``autoreset_mode=AutoresetMode.DISABLED``: an ended sub-env is not advanced again (its observation and
  info stay those of its last step, its actions are ignored) until ``reset`` (e.g. with a ``reset_mask``);
  this is what :func:`ehss_gym.envs.rollouts.rollout` uses to run a fixed set of episodes.
- ``infos`` is a dict of arrays (with ``_key`` masks): t, e, s, V, u_base, u_residual, u_applied,
  saturated, sat_fraction, friction_torque, clipped, n_clipped, diverged, lost_track every step; ``metrics``
  (and ``divergence_reason``) for sub-envs whose episode ended this step.
- ``step_held(actions, max_steps)``: the same actions for up to ``max_steps`` steps, the steps after the first in
  one compiled call, stopping after any sub-env's end (rewards summed); for a policy whose action does not depend on
  what it observes, such as a scripted law's zero residual (:func:`ehss_gym.envs.rollouts.rollout` uses it).
- Rendering is not supported (``render_mode`` must be None); render a single env instead.
- stable-baselines3 takes its own ``VecEnv``, not a Gymnasium vector env: give it
  :class:`ehss_gym.train.vec_env.NativeVecEnv` (this env behind SB3's interface; the class's repr, which SB3's
  refusal prints, says so).
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ehss_gym.core.layout import M_LOST, N_INFO

from .config import EnvConfig, warn_untuned
from .kernels import vector_actions, vector_ends
from .lanes import STEP_INFO_KEYS, Lanes, step_info
from .observation import OBS_BOUND

MAX_CHUNK = 128  # lanes integrated in lock-step by one thread
_NO_RECORD = np.zeros((0, 0, N_INFO))  # step_held without a record (the kernel's array argument)
_MASK_KEYS = tuple("_" + k for k in STEP_INFO_KEYS)  # the step keys' masks in the info (Gymnasium's "_key")
SB3_HINT = ("a Gymnasium vector env, which stable-baselines3 does not take; SB3's VecEnv over it is "
            "ehss_gym.train.vec_env.NativeVecEnv(num_envs, env_kwargs), see docs/RL.md")


class _HintedType(type):
    """The vector env's type, whose repr says what to give stable-baselines3 instead: SB3 refuses a Gymnasium vector
    env with a message that shows only the env's type (``stable_baselines3.common.vec_env.patch_gym._patch_env``)."""

    def __repr__(cls) -> str:
        return f"<class '{cls.__module__}.{cls.__qualname__}'> ({SB3_HINT})"


class EHSSTrackingVectorEnv(VectorEnv, metaclass=_HintedType):
    """N independent EHSS loops as one Gymnasium vector env (see the module docstring).

    Args:
        num_envs: number of sub-envs (>= 1).
        autoreset_mode: ``AutoresetMode.NEXT_STEP`` (default) or ``AutoresetMode.DISABLED`` (see the module
            docstring).
        threads: parallel chunks (>= 1; default 1 = one sequential call). Numba runs them on up to
            ``numba.get_num_threads()`` threads.
        chunk: lanes per chunk (default: ceil(num_envs / threads), at most 128 when threads > 1).
        render_mode: must be None.
        **kwargs: the keyword arguments of :class:`ehss_gym.envs.env.EHSSTrackingEnv`.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(self, num_envs: int = 1, threads: int = 1, chunk: int | None = None, render_mode: str | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP, **kwargs):
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
            raise ValueError(f"threads must be an integer >= 1, got {threads!r}")
        if render_mode is not None:
            raise ValueError(f"render_mode must be None for the vector env (render a single env), got {render_mode!r}")
        modes = (AutoresetMode.NEXT_STEP, AutoresetMode.DISABLED)
        try:
            autoreset_mode = AutoresetMode(autoreset_mode)
        except ValueError:
            autoreset_mode = None
        if autoreset_mode not in modes:
            raise ValueError(f"autoreset_mode must be one of {[m.value for m in modes]}, got {autoreset_mode!r}")
        self.metadata = {**self.metadata, "autoreset_mode": autoreset_mode}
        if chunk is None:
            chunk = -(-int(num_envs) // int(threads))
            if threads > 1:
                chunk = min(MAX_CHUNK, chunk)
        elif isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
            raise ValueError(f"chunk must be an integer >= 1, got {chunk!r}")
        self.render_mode = None
        self.num_envs = N = int(num_envs)
        self.config = cfg = EnvConfig.from_kwargs(kwargs)
        warn_untuned(cfg, kwargs)
        self._lanes = Lanes(cfg, N, int(chunk))
        self.observation_layout = self._lanes.layout
        D = len(self.observation_layout)
        self.single_observation_space = spaces.Box(-OBS_BOUND, OBS_BOUND, shape=(D,), dtype=np.float32)
        self.single_action_space = spaces.Box(-1.0, 1.0, shape=(self._lanes.action_dims,), dtype=np.float32)
        self.observation_space = batch_space(self.single_observation_space, N)
        self.action_space = batch_space(self.single_action_space, N)
        self._rngs: list[np.random.Generator | None] = [None] * N
        self._steps = np.zeros(N, dtype=np.int64)
        self._n_clipped = np.zeros(N, dtype=np.int64)
        self._autoreset = np.zeros(N, dtype=np.bool_)
        self._ended = np.zeros(N, dtype=np.bool_)  # DISABLED mode: ended and not reset since
        self._ready = False

    @property
    def scenario_template(self):
        """A Scenario with this env's controller settings (see EHSSTrackingEnv.scenario_template)."""
        return self._lanes.template

    def _reset_lanes(self, lanes, seeds, options, infos: dict) -> dict:
        """Start a new episode in each lane of ``lanes``: each draws its scenario from its own generator (seeded
        where its seed is given, or the first time), then all load together (:meth:`Lanes.load_many`: the base law's
        runs the reward needs in one batch); returns ``infos`` with their reset infos added. ``seeds`` and
        ``options``: one per lane of ``lanes``."""
        scs = []
        for b, seed, opts in zip(lanes, seeds, options):
            if seed is not None or self._rngs[b] is None:
                self._rngs[b], _ = seeding.np_random(seed)
            sc, info = self._lanes.draw(b, self.config, self._rngs[b], opts)
            scs.append(sc)
            infos = self._add_info(infos, info, b)
        self._lanes.load_many(lanes, scs)
        self._steps[lanes] = 0
        self._n_clipped[lanes] = 0
        return infos

    def reset(self, *, seed: int | list[int] | None = None, options: dict | None = None):
        N = self.num_envs
        if seed is None:
            seeds = [None] * N
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(N)]
        else:
            seeds = list(seed)
            if len(seeds) != N:
                raise ValueError(f"seed must be None, an int, or a list of {N} ints; got a list of {len(seeds)}")
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        if mask is None:
            mask = np.ones(N, dtype=np.bool_)
        elif not (isinstance(mask, np.ndarray) and mask.dtype == np.bool_ and mask.shape == (N,) and mask.any()):
            raise ValueError(f"options['reset_mask'] must be a boolean numpy array of shape ({N},) with at least one "
                             f"True, got {mask!r}")
        per_lane = options.get("scenario")
        if isinstance(per_lane, (list, tuple)):
            if len(per_lane) != N:
                raise ValueError(f"options['scenario'] as a list must give one scenario per sub-env ({N}), got "
                                 f"{len(per_lane)}")
        lanes = [int(b) for b in np.flatnonzero(mask)]
        opts = [{**options, "scenario": per_lane[b]} if isinstance(per_lane, (list, tuple)) else (options or None)
                for b in lanes]
        infos = self._reset_lanes(lanes, [seeds[b] for b in lanes], opts, {})
        self._lanes.observe(lanes)
        self._autoreset[lanes] = False
        self._ended[lanes] = False
        self._ready = True
        return self._lanes.obs[:N].copy(), infos

    def step(self, actions):
        return self._step(actions, 1, None)[:5]

    def step_held(self, actions, max_steps: int, *, record: np.ndarray | None = None):
        """:meth:`step` with the same ``actions`` up to ``max_steps`` times, stopping after the first step in which a
        sub-env ends: the steps after the first run in one compiled call, for a policy whose action does not depend on
        what it observes (a scripted law's zero residual). Each sub-env's state afterwards is what that many calls of
        :meth:`step` leave, bit for bit.

        Args:
            actions: (num_envs, action dims) in [-1, 1], as :meth:`step`'s.
            max_steps: at most this many steps (>= 1). Fewer run when a sub-env ends, or after a step in which a
                sub-env was reset (autoreset).
            record: optional float64 array (max_steps, num_envs, N_INFO) that receives, per step taken and sub-env
                that stepped, its last finite control sample (layout :mod:`ehss_gym.core.layout`, I_*).

        Returns:
            (observations, rewards, terminated, truncated, infos, steps): as :meth:`step`'s after the last step taken,
            except ``rewards``, each sub-env's rewards summed over the steps (in step order), and ``steps``, how many
            were taken.
        """
        if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
            raise ValueError(f"max_steps must be an integer >= 1, got {max_steps!r}")
        shape = (int(max_steps), self.num_envs, N_INFO)
        if record is not None and not (isinstance(record, np.ndarray) and record.dtype == np.float64
                                       and record.shape == shape):
            raise ValueError(f"record must be None or a float64 numpy array of shape {shape}, got "
                             f"{getattr(record, 'dtype', type(record).__name__)} {np.shape(record)}")
        return self._step(actions, int(max_steps), record)

    def _step(self, actions, max_steps: int, record: np.ndarray | None):
        if not self._ready:
            raise RuntimeError("call reset() before step()")
        N = self.num_envs
        lanes = self._lanes
        k = lanes.action_dims
        a = np.ascontiguousarray(actions, dtype=np.float64).reshape(N, -1)
        if a.shape[1] != k:
            raise ValueError(f"actions must have shape ({N}, {k}), got {np.shape(actions)}")
        # the clipped actions, which sub-envs had one clipped and which step (not resetting, nor ended); the clipped
        # ones counted and the others stopped, in one compiled call
        clip, clipped, stepped = np.empty_like(a), np.empty(N, dtype=np.bool_), np.empty(N, dtype=np.bool_)
        n_reset, n_step = vector_actions(a, self._autoreset, self._ended, clip, clipped, stepped, self._n_clipped,
                                         lanes.run)
        if n_step < 0:
            raise ValueError("actions contain NaN; actions must be numbers in [-1, 1] (out-of-range values are "
                             "clipped)")
        infos: dict = {}
        if n_reset:
            resetting = np.flatnonzero(self._autoreset)
            infos = self._reset_lanes([int(b) for b in resetting], [None] * len(resetting), [None] * len(resetting),
                                      infos)
            lanes.observe(resetting)
            lanes.run[resetting] = False  # a lane resetting is not advanced on its reset step
        # the action mode's writer, for the lanes that step (a lane just reset keeps its loaded state: zero action)
        if n_step == N:  # all of them: a slice, which numpy indexes several times faster than a list of lanes
            lanes.set_actions(slice(0, N), clip)
        elif n_step:
            lanes.set_actions(np.flatnonzero(stepped), clip[stepped])
        lanes.step()
        n, rew = 1, lanes.rew  # the rewards of the lanes that stepped, summed over the steps taken
        if record is not None:
            record[0, stepped] = lanes.info_ok[:N][stepped]
        if max_steps > 1 and not n_reset:
            n, rew = self._hold(stepped, clipped, max_steps - 1, record)
        # fresh arrays each step, so what a step returns outlives the next
        flags = np.empty((5, N), dtype=np.bool_)
        info_t, stats_t, rewards = np.empty((N_INFO, N)), np.empty((lanes.stats.shape[1], N)), np.empty(N)
        n_end = vector_ends(lanes.run, lanes.acc, lanes.T, self._steps, stepped, self._autoreset, n,
                            bool(self.config.terminate_on_lost_track), lanes.info_ok, lanes.stats, rew, flags, info_t,
                            stats_t, rewards)
        diverged, lost, terminated, truncated, ended = flags
        step = step_info(info_t, stats_t, clipped, self._n_clipped.copy(), diverged, lost)
        mask = np.ones(N, dtype=np.bool_)  # every sub-env has every step key
        for key, masked, v in zip(STEP_INFO_KEYS, _MASK_KEYS, step.values()):
            infos[key] = v
            infos[masked] = mask
        for b in np.flatnonzero(ended) if n_end else ():
            m = lanes.metrics(int(b))
            extra = {"metrics": m}
            if diverged[b]:
                extra["divergence_reason"] = m["divergence_reason"]
            infos = self._add_info(infos, extra, int(b))
        if self.metadata["autoreset_mode"] == AutoresetMode.DISABLED:
            self._ended |= ended
        else:
            self._autoreset = ended.copy()
        return lanes.obs[:N].copy(), rewards, terminated, truncated, infos, n

    def _hold(self, stepped, clipped, most: int, record) -> tuple[int, np.ndarray]:
        """After a step that reset no sub-env: up to ``most`` more steps with the actions held (:meth:`step_held`),
        none if a sub-env ended in it; their samples go to ``record[1:]``. Returns the agent steps taken in all (the
        first included) and the lanes' rewards (B,) summed over them in step order (those that did not step: 0)."""
        lanes = self._lanes
        N = self.num_envs
        run = lanes.run[:N]
        ended = stepped & ~run
        if self.config.terminate_on_lost_track:
            ended |= stepped & (lanes.acc[:N, M_LOST] > 0.0)
        # the steps left before the first truncation (this step counts once the call returns)
        left = (lanes.T[:N] - self._steps - 1)[stepped]
        most = min(most, int(left.min()) if len(left) else 0)
        if ended.any() or most <= 0:
            return 1, lanes.rew
        rsum = np.zeros(lanes.B)
        rsum[:N] = np.where(stepped, lanes.rew[:N], 0.0)
        rec = _NO_RECORD if record is None else record[1:]
        n = lanes.step_held(most, bool(self.config.terminate_on_lost_track), rec, rsum)
        self._n_clipped += clipped * n
        return 1 + n, rsum

    def close_extras(self, **kwargs):
        self._ready = False


__all__ = ["EHSSTrackingVectorEnv"]
