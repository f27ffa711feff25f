"""Number and table formatting shared by every report (one convention: NaN is "n/a", inf is "never")."""

from __future__ import annotations

import math


def fmt_num(x, fmt: str = ".3g") -> str:
    """A number in format ``fmt``; None/NaN as "n/a", inf as "never" (a recovery that never happens)."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "n/a"
    if isinstance(x, float) and math.isinf(x):
        return "never"
    return format(x, fmt)


def fmt_axis(v) -> str:
    """A sweep axis value: None as "none", large floats as 1e5, others as %g."""
    if v is None:
        return "none"
    if isinstance(v, str):
        return v
    if isinstance(v, float) and v >= 1e3:
        return f"{v:.0e}".replace("e+0", "e").replace("e+", "e")
    return f"{v:g}"


def fmt_range(vals, fmt: str = ".2g") -> str:
    """'min..max' of the finite values (one value if they agree to the format); "n/a" if none."""
    vals = [v for v in vals if v is not None and math.isfinite(v)]
    if not vals:
        return "n/a"
    lo, hi = f"{min(vals):{fmt}}", f"{max(vals):{fmt}}"
    return lo if lo == hi else f"{lo}..{hi}"


def md_table(header, rows) -> str:
    """A GitHub-flavoured markdown table."""
    out = ["| " + " | ".join(str(h) for h in header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)
