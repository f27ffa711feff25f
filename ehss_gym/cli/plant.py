"""``ehss plant FILE``: a plant file read, checked and printed as the model's parameters (:mod:`ehss_gym.core.rig`).
Its options: :func:`ehss_gym.cli.options.add_plant_command` (a bad file is refused while the arguments are parsed)."""

from __future__ import annotations

from ehss_gym.core.params import FIELDS
from ehss_gym.core.rig import Rig


def parameter_rows(rig: Rig) -> list[tuple[str, str, str, str]]:
    """(field, value, unit, where it came from) per parameter of the plant (and of the model where it differs)."""
    how = {d.field: d.formula for d in rig.derived}
    rows = []
    for f in FIELDS:
        v, m = getattr(rig.plant, f.name), getattr(rig.controller_model, f.name)
        src = how.get(f.name, "numerical constant (Table I's)" if rig.derived else "given")
        rows.append((f.name, f"{v:.6g}" + ("" if m == v else f" (model: {m:.6g})"), f.unit, src))
    return rows


def run(args) -> int:
    """Print the rig's summary and its parameters."""
    rig: Rig = args.file
    print(rig.summary())
    if rig.about:
        print(f"about: {rig.about}")
    rows = parameter_rows(rig)
    width = [max(len(r[i]) for r in rows) for i in range(3)]
    for name, value, unit, src in rows:
        print(f"  {name:<{width[0]}}  {value:>{width[1]}}  {unit:<{width[2]}}  {src}")
    return 0


__all__ = ["run", "parameter_rows"]
