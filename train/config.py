"""The settings of a training run (:class:`Config`) and of a multi-seed launch (:class:`Launch`): the one list of
options of ``python -m ehss_gym.train.loop`` and ``ehss train`` (:mod:`ehss_gym.train.options` derives the flags
from the fields and their docstrings).

Light on purpose (no torch, no SB3): every ``ehss`` command imports the CLI module that builds this parser.
The agent's hyperparameters are :data:`ehss_gym.agents.specs.AGENTS`; a run overrides them with ``--hp``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
from dataclasses import dataclass

from ehss_gym.agents.specs import AGENTS, agent_names, env_kwargs_for, get_spec
from ehss_gym.core.settings import TASKS
from ehss_gym.core.validate import check_even_n
from ehss_gym.envs import ENV_ID
from ehss_gym.envs.config import EnvConfig, law_table_of, plant_of
from ehss_gym.infra import BACKENDS

from . import options, runs

# settings that do not change the result: left out of the run-name hash
NOT_HASHED = ("out", "resume", "progress", "timesteps", "verbose")


@dataclass
class Config:
    """Everything a training run depends on (the flags of ``python -m ehss_gym.train.loop`` are these fields)."""

    agent: str = "residual-ppo"
    """agent name: residual-ppo (PPO residual on the Sontag law), ppo (pure PPO, env mode direct) or residual-sac (SAC
    residual, the comparison algorithm)"""
    task: str = "velocity"
    """tracking task: velocity (output x2) or position (output x1)"""
    n: int = 2
    """power factor of the base CLF law (even >= 2)"""
    timesteps: int = 300_000
    """total agent steps to train for (an agent step is agent_period control periods: 1 ms for both agents)"""
    seed: int = 0
    """training seed: torch, NumPy, SB3 and the env scenario draws (sub-env i is seeded seed + i)"""
    eval_freq: int = 50_000
    """agent steps between held-out evaluations (rounded up to a rollout boundary)"""
    eval_episodes: int = 8
    """validation scenarios per evaluation (held-out seeds, disjoint from training and from the test block)"""
    eval_seconds: float = 2.0
    """duration of each validation episode [s] (2 s like the training episodes and the harness's held-out suite)"""
    checkpoint_freq: int = 50_000
    """agent steps between checkpoints (rounded up to a rollout boundary)"""
    n_envs: int | None = None
    """parallel envs (None = the agent's default)"""
    plant: str | None = None
    """the rig trained on: a TOML plant file or a shipped plant (table1, compact140); None = Table I. Its values are
    recorded in the run's env settings, so the run and its exported policy do not depend on the file afterwards"""
    law_settings: str | None = None
    """the base law's settings tuned for the plant: the law_settings.json of ehss baselines --plant FILE (its row for
    the task and n); None = the env's built-in settings (tuned for Table I). Recorded as values, like the plant"""
    hp: dict = dataclasses.field(default_factory=dict)
    """overrides of the agent's hyperparameters (fields of ehss_gym.agents.specs.AgentSpec) as KEY=JSON, e.g. --hp
    gamma=0.99 --hp 'env_kwargs={"agent_period": 20}'"""
    torch_threads: int = 1
    """torch threads of this process (runs of several seeds go one process per core)"""
    out: str | None = None
    """run folder (default runs/<run name>; with --seeds: the parent of the run folders)"""
    resume: bool = False
    """continue from the run folder's latest checkpoint"""
    progress: bool = True
    """the tqdm progress bar"""
    verbose: int = 0
    """SB3 verbosity"""

    def validate(self) -> Config:
        """Raise RunError naming a bad field and its accepted range; returns self."""
        if self.agent not in AGENTS:
            raise runs.RunError(f"--agent must be one of {agent_names()}, got {self.agent!r}")
        if self.task not in TASKS:
            raise runs.RunError(f"--task must be one of {list(TASKS)}, got {self.task!r}")
        tasks = self.spec().tasks
        if self.task not in tasks:
            raise runs.RunError(f"--task must be one of {list(tasks)} for agent {self.agent!r} (its base law was "
                                f"chosen for {'that task' if len(tasks) == 1 else 'those tasks'}), got {self.task!r}")
        if not isinstance(self.n, int):  # a float 4.0 would pass check_even_n but not the run name's n<k>
            raise runs.RunError(f"--n must be an even integer >= 2 (2, 4, 6, ...), got {self.n!r}")
        try:
            check_even_n(self.n, "--n")
        except ValueError as exc:
            raise runs.RunError(str(exc)) from None
        for name, low in (("timesteps", 1), ("eval_freq", 1), ("eval_episodes", 1), ("checkpoint_freq", 1),
                          ("torch_threads", 1), ("seed", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise runs.RunError(f"{options.flag(name)} must be an integer >= {low}, got {v!r}")
        if isinstance(self.eval_seconds, bool) or not isinstance(self.eval_seconds, (int, float)) \
                or not 0.01 <= self.eval_seconds <= 100.0:
            raise runs.RunError(f"--eval-seconds must be a number in [0.01, 100] (s), got {self.eval_seconds!r}")
        if self.n_envs is not None and (isinstance(self.n_envs, bool) or not isinstance(self.n_envs, int)
                                        or self.n_envs < 1):
            raise runs.RunError(f"--n-envs must be an integer >= 1, got {self.n_envs!r}")
        try:  # the env's own validation of the kwargs the agent will train with (the plant file read once, here)
            EnvConfig.from_kwargs(self.env_kwargs())
        except ValueError as exc:
            flag = "--plant" if self.plant is not None and "plant" in str(exc) else (
                "--law-settings" if self.law_settings is not None and "law" in str(exc) else "env settings")
            raise runs.RunError(f"{flag}: {exc}") from None
        return self

    def env_kwargs(self) -> dict:
        """The env settings the agent trains with: the agent's, and the plant's values (its file's content)."""
        kw = env_kwargs_for(self.spec(), self.task, self.n)
        if self.plant is not None:
            kw["plant"] = plant_of(self.plant).as_dict()
        if self.law_settings is not None:
            kw["law_settings"] = law_table_of(self.law_settings).as_dict()
        return kw

    def spec(self):
        """The agent's :class:`~ehss_gym.agents.specs.AgentSpec` with this run's overrides (``hp``, ``n_envs``)."""
        over = dict(self.hp)
        if self.n_envs is not None:
            over["n_envs"] = self.n_envs
        try:
            return get_spec(self.agent, **over)
        except (TypeError, ValueError) as exc:
            raise runs.RunError(f"--hp: {exc}") from None

    def full(self) -> dict:
        """The config plus the agent's hyperparameters and env kwargs: what config.json holds."""
        spec = self.spec()
        fields = dataclasses.asdict(self)
        for k in ("plant", "law_settings"):  # absent when not given: the runs before these settings keep their names
            if fields[k] is None:
                fields.pop(k)
        return {**fields, "agent_spec": spec.as_dict(), "env_kwargs": self.env_kwargs(), "env_id": ENV_ID}

    def run_name(self) -> str:
        """``<agent>_<task>_n<n>_s<seed>_<hash8>`` (:func:`ehss_gym.train.runs.run_name`)."""
        return runs.run_name(self.agent, self.task, self.n, self.seed, self.full(), exclude=NOT_HASHED)

    def run_dir(self) -> str:
        """The run folder: ``out``, or ``runs/<run name>``."""
        return self.out or os.path.join("runs", self.run_name())


@dataclass
class Launch:
    """How ``ehss train`` runs several seeds (its flags besides those of :class:`Config`)."""

    seeds: str | None = None
    """several seeds, e.g. 0-4 or 0,2,5: one process per seed, at most --workers at a time; each run goes to <out
    or runs>/<run name>"""
    workers: int | None = None
    """parallel seeds with --seeds on the local backend (default: the usable cores); with --backend ray on a
    local Ray instance, its CPUs"""
    backend: str = "local"
    """where the seeds of --seeds train: local (this machine, a fresh process per seed) or ray (a Ray cluster:
    --address, else RAY_ADDRESS, else a local Ray instance; pip install 'ehss-gym[ray]'); see docs/RAY.md"""
    address: str | None = None
    """the Ray cluster to join (HOST:PORT; with --backend ray)"""
    store: str | None = None
    """where each seed's job result is kept (default <out or runs>/jobs): a rerun skips the finished seeds"""
    no_store: bool = False
    """keep no job results (every seed trains again)"""
    config: str | None = None
    """a JSON file of Config fields, e.g. the best_config.json of ehss tune; the flags given override it"""

    def validate(self) -> Launch:
        """Raise RunError for a bad --workers; returns self (the backend is checked by the execution layer)."""
        if self.workers is not None and self.workers < 1:
            raise runs.RunError(f"--workers must be an integer >= 1, got {self.workers!r}")
        return self


def build_parser(parser: argparse.ArgumentParser | None = None, launch: bool = False) -> argparse.ArgumentParser:
    """The options of :class:`Config` (and, with ``launch``, of :class:`Launch`) on ``parser`` or a new one."""
    p = parser or argparse.ArgumentParser(prog="python -m ehss_gym.train.loop",
                                          description="Train residual PPO (or pure PPO) on EHSSTracking-v0.")
    options.add_options(p, Config, choices={"agent": agent_names(), "task": tuple(TASKS)})
    if launch:
        options.add_options(p, Launch, metavars={"backend": BACKENDS})
    return p


def read_config_file(path: str) -> dict:
    """The Config fields in JSON file ``path`` (``ehss train --config``; e.g. ``ehss tune``'s best_config.json).

    Raises:
        RunError: a missing or malformed file, or a key that is not a Config field (named, with the fields).
    """
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except OSError as exc:
        raise runs.RunError(f"--config {path}: cannot read it ({exc.strerror})") from None
    except ValueError as exc:
        raise runs.RunError(f"--config {path}: not JSON ({exc})") from None
    names = {f.name for f in dataclasses.fields(Config)}
    if not isinstance(data, dict) or set(data) - names:
        bad = sorted(set(data) - names) if isinstance(data, dict) else type(data).__name__
        raise runs.RunError(f"--config {path}: must be a JSON object of Config fields ({', '.join(sorted(names))});"
                            f" got {bad}")
    return data


def config_from_args(args: argparse.Namespace, **overrides) -> Config:
    """A validated Config from parsed options: the ``--config`` file's values (``ehss train``), then the flags
    given, then ``overrides`` (e.g. ``seed``, ``out``)."""
    path = getattr(args, "config", None)
    if path is not None:
        given = {f.name for f in dataclasses.fields(Config) if getattr(args, f.name, None) is not None}
        overrides = {**{k: v for k, v in read_config_file(path).items() if k not in given}, **overrides}
    return options.from_namespace(Config, args, **overrides).validate()


def launch_from_args(args: argparse.Namespace) -> Launch:
    """A validated Launch from parsed options (``ehss train``)."""
    return options.from_namespace(Launch, args).validate()


__all__ = ["Config", "Launch", "NOT_HASHED", "build_parser", "config_from_args", "launch_from_args"]
