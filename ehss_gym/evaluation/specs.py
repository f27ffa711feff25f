"""Policy specs: what to evaluate, parsed from ``--policies`` entries, shipped models or Python objects.

A :class:`PolicySpec` names a policy, its kind, the env settings it acts in and one *run* per training seed
(:mod:`ehss_gym.evaluation.loading` turns a run into an object with ``predict``). Forms of a ``--policies``
entry (:func:`parse_policy`):

- ``clf-n<even n>`` and ``pid``: the scripted laws of :mod:`ehss_gym.controllers` (both tasks); the CLF law's
  variants by name, ``<law>-n<k>`` and ``<law>-<estimator>-n<k>`` (e.g. ``lin-sontag-n4``, ``sontag-foh-n2``),
  ``dob-n<even n>``, the law with the disturbance observer on the combined error, and ``dcomp-n<even n>``, the law
  with its reference delayed (:func:`ehss_gym.controllers.parse_scripted`);
- ``sb3:PATH``: a model of any stable-baselines3 (or sb3-contrib) algorithm, its algorithm read from the .zip and
  its env settings, the mode included, from the env spec saved with it (:func:`saved_env_kwargs`; an error
  without one);
- ``residual-ppo:PATH`` and ``ppo-direct:PATH``: a model file (safe-weights stem or SB3 .zip) or a glob of
  several training seeds, checked against the mode it was trained in (a .zip with no saved env spec is scored
  in the prefix's mode at the env's defaults, with a printed :class:`PolicyWarning`);
- the name of a model shipped in ``ehss_gym/models`` (``-seed<k>`` files grouped into one spec);
- ``LABEL=SPEC``: any of the above under the report name LABEL (two models of one run, which would otherwise share
  the run's name).
"""

from __future__ import annotations

import glob
import json
import os
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ehss_gym.agents.safeweights import shipped_models
from ehss_gym.controllers import (
    COMPENSATOR_TEXT,
    compensated_tasks,
    compensator_kind,
    compensator_loops,
    compensator_rows,
    dob_rows,
    parse_scripted,
)
from ehss_gym.core.validate import check_even_n
from ehss_gym.envs import ENV_ID, EnvConfig
from ehss_gym.envs.config import DEFAULTS, LOOP_KEYS, in_legacy_loop

from .loading import ZOO_ARGS, ZOO_CONFIG, PolicyError, load_safe, make_env, read_zoo_record
from .suites import TASKS

# the law every ratio of the evaluation is taken to (evaluation.scoring): the env's default law
REFERENCE_POLICY = f"clf-n{DEFAULTS.n}"
SCRIPTED_DEFAULT = ("clf-n2", "clf-n4", "clf-n6", "dob-n2", "dcomp-n2", "vinv-n2", "eso-n2", "pid")
LEARNED_KINDS = ("residual-ppo", "ppo-direct", "sb3")  # sb3: any algorithm, its mode from the saved env spec
# The settings that shape the base law's closed loop (the env's loop settings but the task, n and when a run is
# flagged as lost): a learned policy trained at other values is compared with the laws at its own.
CONTROLLER_KEYS = tuple(k for k in LOOP_KEYS if k not in ("task", "n", "lost_track"))
CLF_RE = re.compile(r"^clf-n(\d+)$")
_SEED_RE = re.compile(r"^(.*?)[-_](?:seed|s)(\d+)$")
LABEL_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]{0,63}$")  # a policy's report name given as LABEL=SPEC
_GENERIC = ("policy", "model", "best_model", "final_model", "best", "final", "checkpoints", ENV_ID)
_NOT_ENV = ("scenario", "render_mode")  # env kwargs a policy does not carry over (set per episode)


@dataclass
class PolicySpec:
    """A policy to evaluate, with one entry in ``runs`` per training seed.

    Attributes:
        name: label in the report (unique).
        kind: "clf", "pid", "residual-ppo", "ppo-direct", "sb3" or "object".
        runs: per training seed, what :func:`ehss_gym.evaluation.loading.load_run` loads: a model path (str) or
            an object with ``predict`` (scripted policies: a dict describing them).
        env_kwargs: keyword arguments of the env the policy acts in (without ``task`` for scripted
            policies, which run on every task).
        tasks: tasks it runs on.
        source: human-readable origin (for the report).
        task_kwargs: task -> env kwargs for that task on top of ``env_kwargs`` (a scripted law's settings tuned per
            task, from a law-settings file).
    """

    name: str
    kind: str
    runs: list
    env_kwargs: dict
    tasks: tuple = TASKS
    source: str = ""
    task_kwargs: dict = field(default_factory=dict)

    @property
    def learned(self) -> bool:
        """True for trained models and Python objects (everything but the scripted laws)."""
        return self.kind in (*LEARNED_KINDS, "object")

    def env_kwargs_for(self, task: str) -> dict:
        """The env kwargs of this policy on ``task``."""
        kw = {**self.env_kwargs, **self.task_kwargs.get(task, {})}
        kw["task"] = task
        return kw


def _kind_of_mode(mode: str) -> str:
    """The spec kind of a model trained in env mode ``mode`` ("residual" or "direct")."""
    return "residual-ppo" if mode == "residual" else "ppo-direct"


def valid_forms() -> str:
    """Every accepted form of a ``--policies`` entry, with the shipped model names (for error messages)."""
    names = sorted(shipped_models())
    shipped = ", ".join(names) if names else "none shipped yet"
    return ("clf-n<even n >= 2> (e.g. clf-n2, clf-n4, clf-n6), the CLF variants <law>-n<k> and "
            "<law>-<estimator>-n<k> (e.g. lin-sontag-n4, sontag-foh-n2), dob-n<even n> (the CLF law with the "
            "disturbance observer, e.g. dob-n2), dcomp-n<even n> (the CLF law with its reference delayed, e.g. "
            "dcomp-n2), vinv-n<even n> (the CLF law with the valve's dead band and hysteresis inverted, e.g. vinv-n2), "
            "eso-n<even n> (the CLF law with the extended-state observer as its estimator, e.g. eso-n2), "
            "pid, residual-ppo:PATH, ppo-direct:PATH, "
            "sb3:PATH (any SB3 algorithm, the mode from its saved env spec; PATH = an SB3 .zip, a safe-weights stem "
            f"PATH with PATH.safetensors + PATH.json, a glob matching several training seeds, or an rl-zoo3 run "
            f"folder), or a shipped model name ({shipped}); any of them as LABEL=SPEC to name it in the report")


def scripted_spec(name: str, label: str | None = None, env_overrides: dict | None = None,
                  gains: dict | None = None, laws=None) -> PolicySpec:
    """A scripted CLF law (``clf-n<n>`` or a variant, :func:`ehss_gym.controllers.parse_scripted`) or ``pid`` as a
    :class:`PolicySpec` (runs on both tasks).

    Args:
        name: "clf-n<even n>", "<law>-n<k>", "<law>-<estimator>-n<k>", "dob-n<even n>", "dcomp-n<even n>",
            "vinv-n<even n>", "eso-n<even n>" or "pid".
        label: report name (default ``name``); needed when ``env_overrides`` change the law.
        env_overrides: env settings changed from the defaults (e.g. ``{"sigma": 1.0}``: the paper's scale).
        gains: PID only: task -> (kp [mA per output unit], ki [mA per unit*s], kd [mA per unit/s]) instead of
            the tuned gains.
        laws: a compensator's rows from this law table (:class:`ehss_gym.envs.law_table.LawTable`, a plant's)
            instead of Table I's (the harness applies an evaluation's table to a spec made without it).

    Raises:
        PolicyError: an unknown name or an odd power factor.
    """
    over = dict(env_overrides or {})
    kw = parse_scripted(name) if name != "pid" else None
    if kw is not None:
        try:
            n = check_even_n(kw["n"])
        except ValueError:
            raise PolicyError(f"unknown policy {name!r}: the CLF power factor must be an even integer >= 2 "
                              f"(clf-n2, clf-n4, clf-n6, dob-n2, ...)") from None
        law = {k: kw[k] for k in ("law", "estimator") if k in kw}
        what = "the env's default CLF law" if not law else ", ".join(f"{k} {v}" for k, v in law.items())
        rows = {}
        if "dob_hz" in kw and n == 2 and not {"dob_hz", "smoothing", "layer_gain"} & set(over):
            rows = dob_rows(TASKS)  # the tuned observer rows (a law table's replace them)
            what += ", disturbance observer at " + ", ".join(f"{r['dob_hz']:.3g} Hz ({t})" for t, r in rows.items())
        elif "dob_hz" in kw:
            what += f", disturbance observer at {kw['dob_hz']:g} Hz"
        kind, tasks, run = compensator_kind(name), TASKS, {"kind": "clf", "n": n}
        if kind is not None and not set(kw) & set(over) - {"n", "mode"}:
            # the task's own size; on a task where its rule chose none it is clf-n<k>, so it is not run there
            tasks = compensated_tasks(kind, TASKS, laws)
            rows = compensator_loops(kind, tasks, laws)
            what += ", " + ("; ".join(f"{COMPENSATOR_TEXT[kind].format(**r)} ({t})"
                                      for t, r in compensator_rows(kind, tasks, laws).items())
                            or "no compensation chosen on any task")
            if laws is not None:
                what += f", rows of {laws.describe()}"
            run["scripted"] = name  # the harness takes an evaluation's law table's rows from here
        src = f"scripted CLF law ({what}), n = {n}" + (f", {over}" if over else "")
        return PolicySpec(name=label or name, kind="clf", runs=[run],
                          env_kwargs={**kw, **over}, tasks=tasks, task_kwargs=rows, source=src)
    if name == "pid":
        run = {"kind": "pid"}
        if gains:
            run["gains"] = {t: tuple(float(g) for g in v) for t, v in gains.items()}
        src = ("scripted PID (ehss_gym.controllers)" + (f", {over}" if over else "")
               + (f", gains {gains}" if gains else ""))
        return PolicySpec(name=label or "pid", kind="pid", runs=[run], env_kwargs={"mode": "direct", **over},
                          source=src)
    raise PolicyError(f"unknown policy {name!r}; valid: {valid_forms()}")


class PolicyWarning(UserWarning):
    """A policy that is evaluated on an assumption the harness could not check (printed, not an error)."""


def _read_record(path: str) -> dict | None:
    """The env settings a record file holds, or None: ``{"env_kwargs": ...}`` (ehss-gym's sidecar and run
    config.json), a Gymnasium EnvSpec JSON (``env.spec.to_json()``: ``{"id": ..., "kwargs": ...}``) or rl-zoo3's
    args.yml (``env`` and ``env_kwargs``).

    Raises:
        PolicyError: a record of another env.
    """
    if path.endswith(".yml"):
        d = read_zoo_record(path)
    else:
        try:
            with open(path, encoding="utf-8") as f:
                d = json.load(f)
        except (OSError, ValueError):
            return None
    if not isinstance(d, dict):
        return None
    env_id = d.get("env_id", d.get("id", d.get("env")))
    kw = d.get("env_kwargs", d.get("kwargs") if "id" in d else None)
    if env_id is not None and str(env_id).split(":")[-1] != ENV_ID:
        raise PolicyError(f"the env spec saved in {path} is of {env_id!r}, not {ENV_ID!r}")
    if path.endswith(".yml") and env_id is not None and not kw:
        kw = _zoo_config_env_kwargs(os.path.join(os.path.dirname(path), ZOO_CONFIG))
    return dict(kw) if isinstance(kw, dict) else None


def _zoo_config_env_kwargs(path: str) -> dict:
    """The env kwargs of rl-zoo3's ``config.yml`` (its config file's ``env_kwargs``, which it trained with when no
    ``--env-kwargs`` replaced them); {} when it lists none (the env's defaults).

    Raises:
        PolicyError: a config.yml that exists but cannot be read (its env settings would be guessed).
    """
    if not os.path.isfile(path):
        return {}
    d = read_zoo_record(path)
    kw = d.get("env_kwargs", {}) if d is not None else None
    if not isinstance(kw, dict):
        raise PolicyError(f"cannot read the env_kwargs rl-zoo3 trained with from {path}")
    return kw


def saved_env_kwargs(zip_path: str) -> tuple[dict | None, str | None]:
    """The env settings saved with an SB3 .zip, and the file that holds them; (None, None) if there is none.

    Looked for, in this order: ``STEM.json`` next to the .zip (``{"env_kwargs": {...}}`` or a Gymnasium EnvSpec
    JSON, ``env.unwrapped.spec.to_json()``); ``config.json`` of its folder or the folder above (an ``ehss
    train`` run); rl-zoo3's ``<folder>/EHSSTracking-v0/args.yml`` (its ``--env-kwargs``, else the config file's
    ``env_kwargs`` it recorded in ``config.yml`` beside it: what rl-zoo3 trained with, and what ``rl_zoo3.enjoy``
    replays).
    """
    stem = zip_path[:-4]
    folder = os.path.dirname(os.path.abspath(zip_path))
    for cand in (stem + ".json", os.path.join(folder, "config.json"),
                 os.path.join(os.path.dirname(folder), "config.json"), os.path.join(folder, ENV_ID, ZOO_ARGS)):
        if os.path.isfile(cand):
            kw = _read_record(cand)
            if kw is not None:
                return kw, cand
    return None, None


def _existing_model(p: str) -> str | None:
    """The model a candidate path names: an existing .zip, a safe-weights stem or the stem's .zip; else None."""
    if p.endswith(".zip"):
        return p if os.path.isfile(p) else None
    stem = p[:-5] if p.endswith(".json") else (p[:-12] if p.endswith(".safetensors") else p)
    if os.path.isfile(stem + ".json") and os.path.isfile(stem + ".safetensors"):
        return stem
    return stem + ".zip" if os.path.isfile(stem + ".zip") else None


def _model_files(pattern: str, spec_text: str) -> list[str]:
    """The model paths a PATH (or glob) names; PolicyError if none exists.

    A safe-weights stem is preferred over an SB3 .zip in the same folder (a training run keeps both). An rl-zoo3
    run folder (``logs/ppo/EHSSTracking-v0_1``) names its final model, ``EHSSTracking-v0.zip`` (its
    ``best_model.zip`` or a checkpoint is named by its path).
    """
    has_glob = any(c in pattern for c in "*?[")
    if not has_glob and os.path.isfile(os.path.join(pattern, ENV_ID, ZOO_ARGS)) \
            and os.path.isfile(os.path.join(pattern, ENV_ID + ".zip")):
        return [os.path.join(pattern, ENV_ID + ".zip")]  # an rl-zoo3 run folder: its final model, as rl_zoo3.enjoy
    if has_glob:
        cands = sorted(set(glob.glob(pattern)) | set(glob.glob(pattern + ".json")) | set(glob.glob(pattern + ".zip")))
    else:
        cands = [pattern]
    out = list(dict.fromkeys(p for p in map(_existing_model, cands) if p is not None))
    if has_glob:
        safe_dirs = {os.path.dirname(p) for p in out if not p.endswith(".zip")}
        out = [p for p in out if not (p.endswith(".zip") and os.path.dirname(p) in safe_dirs)]
    if not out:
        if has_glob:
            what = "no file matches the pattern"
        elif os.path.isdir(pattern):
            what = "is a folder, not a model (name the model inside it, e.g. a run's best/policy):"
        elif os.path.exists(pattern):
            what = "is not a model file:"
        else:
            what = "file not found"
        raise PolicyError(f"policy {spec_text!r}: {what} {pattern!r}; PATH must be an SB3 .zip or a safe-weights "
                          "stem with PATH.safetensors + PATH.json")
    return sorted(out)


def _zip_env_kwargs(path: str, kind: str, spec_text: str) -> tuple[dict, str | None]:
    """The env settings of an SB3 .zip from its saved env spec, and the file that holds them; without one, an error
    (``sb3:``) or the prefix's mode at the env's defaults with a :class:`PolicyWarning` (and no file)."""
    kw, src = saved_env_kwargs(path)
    if kw is not None:
        return kw, src
    if kind == "sb3":
        raise PolicyError(f"policy {spec_text!r}: no env spec saved with {path!r} (looked for {path[:-4]}.json, "
                          f"config.json and rl-zoo3's {ENV_ID}/{ZOO_ARGS}), so its mode and settings are unknown; "
                          f"save one (json.dump({{'env_kwargs': env_kwargs}}, ...) or env.unwrapped.spec.to_json() "
                          f"to {os.path.basename(path[:-4])}.json) or name the mode: residual-ppo:PATH or "
                          "ppo-direct:PATH")
    mode = "residual" if kind == "residual-ppo" else "direct"
    warnings.warn(f"policy {spec_text!r}: no env spec saved with {path!r}; scored in mode {mode!r} (from the "
                  f"{kind}: prefix) at the env's default settings. If it was trained otherwise its score is wrong: "
                  f"save its env settings to {os.path.basename(path[:-4])}.json and use sb3:PATH",
                  PolicyWarning, stacklevel=3)
    return {"mode": mode}, None


def _run_env_kwargs(path: str, kind: str, spec_text: str) -> dict:
    """The env kwargs a model was trained with, checked against the spec's mode (``sb3``: the saved mode)."""
    if path.endswith(".zip"):
        kw, src = _zip_env_kwargs(path, kind, spec_text)
        pinned = src is not None and os.path.basename(src) == "config.json"  # an ehss train run's record
    else:
        pinned = True  # safe weights
        pol = load_safe(path)
        if pol.env_id != ENV_ID:
            raise PolicyError(f"policy {spec_text!r}: model {path!r} was trained on {pol.env_id!r}, not {ENV_ID!r}")
        kw = dict(pol.env_kwargs)
    mode = kw.get("mode", "residual")
    if kind != "sb3":
        want_mode = "residual" if kind == "residual-ppo" else "direct"
        if mode != want_mode:
            raise PolicyError(f"policy {spec_text!r}: model {path!r} was trained with mode={mode!r}; name it "
                              f"{_kind_of_mode(mode)}:{path} (residual-ppo = mode 'residual', ppo-direct = mode "
                              "'direct'), or sb3:PATH (the mode read from the saved env spec)")
    kw["mode"] = mode
    if pinned:  # our run folders and safe weights pin every env setting: a missing one predates that setting
        kw = in_legacy_loop(kw)  # ... so the model acts in the loop it was trained in (LEGACY_LOOP)
    # a generic env spec (STEM.json, a Gymnasium EnvSpec, rl-zoo3's records) lists only the kwargs that were passed:
    # a missing setting is the env's current default, as it was in training
    for k in _NOT_ENV:
        kw.pop(k, None)
    return kw


def _path_label(path: str) -> str:
    """A readable name for a model path: its file stem, or the run folder for generic stems (policy, model)."""
    parts = os.path.normpath(os.path.abspath(path)).split(os.sep)
    stem = parts[-1].removesuffix(".zip")
    if stem not in _GENERIC:
        return stem
    for folder in reversed(parts[:-1]):
        if folder and folder not in _GENERIC:
            return folder
    return stem


def _learned_name(kind: str, paths: Sequence[str]) -> str:
    """The report name of a learned policy: its file stem, or the common stem of its training seeds."""
    labels = [_path_label(p) for p in paths]
    zip_tag = " (sb3 zip)" if all(p.endswith(".zip") for p in paths) else ""
    if len(labels) == 1:
        return f"{kind}:{labels[0]}{zip_tag}"
    common = os.path.commonprefix(labels).rstrip("-_")
    m = _SEED_RE.match(common) if common else None
    name = f"{kind}:{common or labels[0]}" if not m else f"{kind}:{m.group(1)}"
    return re.sub(r"[-_](?:seed|s)$", "", name) + zip_tag


def learned_spec(kind: str, pattern: str, spec_text: str | None = None, name: str | None = None) -> PolicySpec:
    """A learned policy from one model file or a glob of several training seeds.

    Args:
        kind: "residual-ppo" or "ppo-direct" (must match the mode the models were trained in), or "sb3" (any
            algorithm; the mode is read from the saved env spec).
        pattern: a model path (safe-weights stem or SB3 .zip) or a glob of several.
        spec_text: the ``--policies`` entry, for error messages (default ``kind:pattern``).
        name: report name (default: derived from the file names).

    Raises:
        PolicyError: no model file, a mode that does not match, no saved env spec for ``sb3``, or seeds trained
            with different settings.
    """
    spec_text = spec_text or f"{kind}:{pattern}"
    paths = _model_files(pattern, spec_text)
    kws = [_run_env_kwargs(p, kind, spec_text) for p in paths]
    first = kws[0]
    for p, kw in zip(paths[1:], kws[1:]):
        if kw != first:
            raise PolicyError(f"policy {spec_text!r}: the training seeds were trained with different env settings "
                              f"({paths[0]}: {first}; {p}: {kw}); evaluate them as separate policies")
    tasks = (first["task"],) if "task" in first else ("velocity",)
    if name is None:
        name = _learned_name(kind, paths)
        if kind == "sb3":  # the mode came from the saved spec: show it
            name = name.replace(" (sb3 zip)", "") + f" ({first['mode']})"
    return PolicySpec(name=name, kind=kind, runs=list(paths), env_kwargs=first,
                      tasks=tasks, source=", ".join(os.path.relpath(p) if not os.path.isabs(p) else p for p in paths))


def _shipped_kind(path: str) -> str:
    """The spec kind of a shipped safe-weights model (from the mode it was trained in)."""
    return _kind_of_mode(load_safe(path).env_kwargs.get("mode", "residual"))


def shipped_specs() -> list[PolicySpec]:
    """Every model in ``ehss_gym/models``, one spec per name with its ``-seed<k>`` files as training seeds.

    Raises:
        PolicyError: the seeds of one name were trained with different env settings.
    """
    groups: dict[str, list[str]] = {}
    for nm, path in shipped_models().items():
        m = _SEED_RE.match(nm)
        groups.setdefault(m.group(1) if m else nm, []).append(path)
    out = []
    for base, paths in sorted(groups.items()):
        kind = _shipped_kind(paths[0])
        spec = learned_spec(kind, paths[0], spec_text=base, name=base)
        if len(paths) > 1:
            kws = [_run_env_kwargs(p, kind, base) for p in paths]
            if any(kw != kws[0] for kw in kws):
                raise PolicyError(f"shipped model group {base!r}: seeds trained with different env settings")
            spec.runs = sorted(paths)
        spec.source = "shipped: " + ", ".join(os.path.basename(p) for p in spec.runs)
        out.append(spec)
    return out


def _scripted_name(text: str) -> bool:
    """True if ``text`` names a scripted CLF law (a malformed variant raises PolicyError with its reason)."""
    try:
        return parse_scripted(text) is not None
    except ValueError as exc:
        raise PolicyError(f"unknown policy {text!r}: {exc}") from exc


def _split_label(text: str) -> tuple[str | None, str]:
    """(label, spec) of a ``LABEL=SPEC`` entry, or (None, text): a label is what precedes the first '=' when that
    holds no ':' or path separator (so a PATH with '=' in it stays a PATH)."""
    head, sep, rest = text.partition("=")
    if not sep or any(c in head for c in ":/\\"):
        return None, text
    return head.strip(), rest.strip()


def _check_label(label: str, text: str) -> str:
    """``label`` if it can name a policy in the report; PolicyError saying why not."""
    if not label:
        raise PolicyError(f"policy {text!r}: the label before '=' is empty; write LABEL=SPEC, e.g. "
                          "final=residual-ppo:RUN/final/policy")
    if not LABEL_RE.match(label):
        raise PolicyError(f"policy label {label!r} in {text!r}: a label is 1-64 letters, digits, '_', '.', '+' or "
                          "'-', starting with a letter or digit (one label per policy: LABEL=SPEC)")
    try:
        names_a_policy = label == "pid" or parse_scripted(label) is not None or label in shipped_models()
    except ValueError:  # a malformed law variant is not a policy's name
        names_a_policy = False
    if names_a_policy:
        raise PolicyError(f"policy label {label!r} in {text!r} is the name of a policy (a scripted law or a shipped "
                          "model); choose another label")
    return label


def parse_policy(text: str) -> PolicySpec:
    """One ``--policies`` entry as a :class:`PolicySpec`: a form of :func:`valid_forms`, or ``LABEL=SPEC`` for
    the same under the report name LABEL (two models of one run, say, which would share their run's name).

    Raises:
        PolicyError: an entry that is none of the accepted forms, or a bad label; the message names what would fit.
    """
    text = text.strip()
    label, spec_text = _split_label(text)
    if label is not None:
        _check_label(label, text)
        second, _ = _split_label(spec_text)
        if second is not None:
            raise PolicyError(f"policy label {second!r} in {text!r}: one label per policy (LABEL=SPEC)")
        return replace(parse_policy(spec_text), name=label)
    if not text:
        raise PolicyError(f"empty policy name; valid: {valid_forms()}")
    if ":" in text:
        kind, _, path = text.partition(":")
        if kind not in LEARNED_KINDS:
            raise PolicyError(f"unknown policy kind {kind!r} in {text!r}; valid: {valid_forms()}")
        if not path:
            raise PolicyError(f"policy {text!r} needs a PATH after the colon; valid: {valid_forms()}")
        return learned_spec(kind, path, spec_text=text)
    if text == "pid" or _scripted_name(text):
        return scripted_spec(text)
    models = shipped_models()
    shipped = {s.name: s for s in shipped_specs()} if models else {}
    if text in shipped:
        return shipped[text]
    if text in models:  # one seed of a group, by its full name
        return learned_spec(_shipped_kind(models[text]), models[text], spec_text=text, name=text)
    raise PolicyError(f"unknown policy {text!r}; valid: {valid_forms()}")


def parse_policies(items: Sequence[str]) -> list[PolicySpec]:
    """``--policies`` entries (each may hold several, comma-separated) as specs.

    Raises:
        PolicyError: no entry at all, or one that :func:`parse_policy` refuses.
    """
    tokens = [t for item in items for t in item.split(",") if t.strip()]
    if not tokens:
        raise PolicyError(f"--policies needs at least one policy; valid: {valid_forms()}")
    specs = [parse_policy(t) for t in tokens]
    check_unique_names(specs)
    return specs


def check_unique_names(specs: Sequence[PolicySpec]) -> None:
    """PolicyError when two specs share a report name, saying how to label them apart."""
    names = [s.name for s in specs]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise PolicyError(f"policy name(s) {dup} given more than once (two models of one run share the run's name); "
                          "give each its own label with LABEL=SPEC, e.g. final=residual-ppo:RUN/final/policy "
                          "best=residual-ppo:RUN/best/policy")


def object_spec(name: str, policy, env_kwargs: dict | None = None, runs: Sequence | None = None) -> PolicySpec:
    """Any object (or list of objects, one per training seed) with SB3's ``predict`` as a policy.

    Args:
        name: report label.
        policy: an object with ``predict``; ignored when ``runs`` is given.
        env_kwargs: env settings it acts in (default: ``policy.env_kwargs`` if present, else the env's
            defaults); ``task`` restricts it to one task.
        runs: several objects, one per training seed.

    Raises:
        PolicyError: an object without ``predict``.
    """
    objs = list(runs) if runs is not None else [policy]
    for o in objs:
        if not callable(getattr(o, "predict", None)):
            raise PolicyError(f"policy {name!r}: {type(o).__name__} has no predict(obs, state, episode_start, "
                              "deterministic) method")
    kw = dict(env_kwargs if env_kwargs is not None else getattr(objs[0], "env_kwargs", None) or {})
    for k in _NOT_ENV:
        kw.pop(k, None)
    tasks = (kw["task"],) if "task" in kw else TASKS
    return PolicySpec(name=name, kind="object", runs=objs, env_kwargs=kw, tasks=tasks,
                      source=f"Python object {type(objs[0]).__name__}")


def scripted_specs(names=SCRIPTED_DEFAULT, tasks=TASKS, laws=None) -> list[PolicySpec]:
    """The scripted policies ``names`` (:func:`scripted_spec`) that act on at least one task of ``tasks``: a scripted
    compensator acts only on the tasks where its rule chose a compensation (on Table I ``dcomp-n2`` position,
    ``vinv-n2`` velocity; on another plant its law table ``laws`` says)."""
    return [s for s in (scripted_spec(n, laws=laws) for n in names) if set(s.tasks) & set(tasks)]


def default_specs(tasks=TASKS) -> list[PolicySpec]:
    """Every shipped policy that acts on at least one task of ``tasks``: the scripted CLF (n = 2, 4, 6), the CLF law
    with the disturbance observer or a compensator (n = 2) and PID, and the models in ehss_gym/models."""
    return scripted_specs(SCRIPTED_DEFAULT, tasks) + [s for s in shipped_specs() if set(s.tasks) & set(tasks)]


def controller_settings(env_kwargs: dict, task: str) -> dict:
    """The settings that shape the base law's closed loop (defaults resolved), for "same settings" checks.

    Args:
        env_kwargs: a spec's env kwargs (``mode`` is ignored).
        task: the task.
    """
    cfg = EnvConfig.from_kwargs({k: v for k, v in env_kwargs.items() if k != "mode"} | {"task": task})
    return {k: getattr(cfg, k) for k in CONTROLLER_KEYS}


def _fitting_observations(kw: dict) -> list[str]:
    """The observation shape of every task under env settings ``kw`` (what a policy could fit instead)."""
    fits = []
    for t in TASKS:
        try:
            e = make_env({**kw, "task": t})
            fits.append(f"task={t!r}: observation {tuple(e.observation_space.shape)}")
        except ValueError:
            pass
    return fits


def _action_shape(spec: PolicySpec, policy, want_obs: tuple) -> tuple | None:
    """The action shape a policy declares, or (a plain object) gives for a batch of one zero observation."""
    act_space = getattr(policy, "action_space", None)
    if act_space is not None:
        return tuple(act_space.shape)
    try:
        a, _ = policy.predict(np.zeros((1,) + want_obs, dtype=np.float32), state=None,
                              episode_start=np.ones(1, dtype=bool), deterministic=True)
        return tuple(np.asarray(a).shape[1:])
    except Exception as exc:  # any failure of foreign code is reported with its name
        raise PolicyError(f"policy {spec.name!r}: predict() on a batch of observations of shape "
                          f"(1, {want_obs[0]}) failed ({type(exc).__name__}: {exc})") from None


def check_fit(spec: PolicySpec, policy, task: str) -> None:
    """PolicyError unless the policy's observation/action shapes fit the env it will act in.

    Args:
        spec: the policy's spec (its env settings and name).
        policy: the loaded object with ``predict``.
        task: the task it will act on.
    """
    kw = spec.env_kwargs_for(task)
    try:
        env = make_env(kw)
    except ValueError as exc:
        raise PolicyError(f"policy {spec.name!r}: its env settings {kw} are not valid for {ENV_ID}: {exc}") from None
    want_obs = tuple(env.observation_space.shape)
    want_act = tuple(env.action_space.shape)
    obs_space = getattr(policy, "observation_space", None)
    got_obs = tuple(obs_space.shape) if obs_space is not None else None
    got_act = _action_shape(spec, policy, want_obs)
    if (got_obs is not None and got_obs != want_obs) or got_act != want_act:
        raise PolicyError(
            f"policy {spec.name!r} does not fit {ENV_ID}(task={task!r}, mode={kw.get('mode', 'residual')!r}): it "
            f"expects observations of shape {got_obs} and gives actions of shape {got_act}, the env has "
            f"observation shape {want_obs} and action shape {want_act}. What fits: "
            f"{'; '.join(_fitting_observations(kw))}; action {want_act} in [-1, 1].")


__all__ = ["REFERENCE_POLICY", "SCRIPTED_DEFAULT", "PolicySpec", "PolicyError", "PolicyWarning", "saved_env_kwargs",
           "valid_forms", "scripted_spec", "learned_spec", "shipped_specs", "parse_policy", "parse_policies",
           "check_unique_names", "object_spec", "default_specs",
           "controller_settings", "check_fit"]
