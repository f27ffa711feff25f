"""What several commands do with their parsed options: the execution layer's backend and store, the output folder."""

from __future__ import annotations

import os
import sys

from ehss_gym.core.rig import TABLE_I
from ehss_gym.infra.execution import DEFAULT_STORE, Backend, Store
from ehss_gym.infra.util import report_folder


def backend_from_args(args, workers: int | None = None) -> Backend:
    """A validated :class:`~ehss_gym.infra.execution.Backend` from ``--backend``, ``--address`` and ``workers``."""
    return Backend(name=args.backend, address=args.address, workers=workers).validate()


def store_from_args(args) -> Store | None:
    """The :class:`~ehss_gym.infra.execution.Store` of ``--store`` (default runs/jobs), or None with ``--no-store``."""
    return None if args.no_store else Store(args.store or DEFAULT_STORE)


def plant_out_folder(out: str | None, quick: bool, shipped: str, plant) -> str:
    """A report command's output folder (:func:`ehss_gym.infra.util.report_folder`), but on another plant than Table
    I without ``--out``: ``runs/<plant's file stem>/<report>`` (``runs/quick/...`` for a quick run), so a run on
    another plant never writes into the committed Table I reports."""
    if out is not None or plant is None:
        return report_folder(out, quick, shipped)
    stem = os.path.splitext(os.path.basename(plant.source))[0] if plant.source else plant.hash
    return os.path.join("runs", *(("quick",) if quick else ()), stem, os.path.basename(os.path.normpath(shipped)))


def plant_note(prog: str, plant, law_settings) -> None:
    """A note on stderr when the scripted laws' settings were not tuned for ``plant`` (Table I's on another rig, or
    a law-settings file tuned on another plant): the env's :class:`~ehss_gym.envs.config.PlantWarning`, said once."""
    rig = plant or TABLE_I
    if law_settings is None and not rig.is_table_i:
        print(f"{prog}: note: the CLF law's settings are those tuned for Table I, and the plant is {rig.label}; tune "
              "them with `ehss baselines --plant FILE` and pass --law-settings law_settings.json", file=sys.stderr)
    elif law_settings is not None and law_settings.plant_hash and law_settings.plant_hash != rig.hash:
        print(f"{prog}: note: {law_settings.describe()}, and the plant is {rig.label}", file=sys.stderr)


def check_out_folder(prog: str, out: str) -> bool:
    """False (with a message naming ``--out``) unless ``out`` is a non-empty path that is not a file."""
    if not out or not str(out).strip():
        print(f"{prog}: error: --out must be a non-empty folder path", file=sys.stderr)
        return False
    if os.path.exists(out) and not os.path.isdir(out):
        print(f"{prog}: error: --out must be a folder, {out!r} is a file", file=sys.stderr)
        return False
    return True


__all__ = ["backend_from_args", "store_from_args", "check_out_folder", "plant_out_folder", "plant_note"]
