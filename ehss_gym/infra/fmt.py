"""Number and table formatting shared by every report and benchmark.

One convention for a missing value: an empty table cell is "-" (:func:`fmt_cell`), a number missing from a
sentence is "n/a" (:func:`fmt_num`); a recovery that never happens is "never". The reports differ only in
how many digits a table shows (the arguments of :func:`fmt_cell`), never in how they mark a missing value.
"""

from __future__ import annotations

import math

import numpy as np


def fmt_num(x, fmt: str = ".3g") -> str:
    """A number in format ``fmt``; None/NaN as "n/a", inf as "never" (a recovery that never happens)."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "n/a"
    if isinstance(x, float) and math.isinf(x):
        return "never"
    return format(x, fmt)


def fmt_cell(x, digits: int = 3, *, sci_from: float = 1e4, grouped_from: float | None = None,
             decimals: bool = False) -> str:
    """A table cell.

    Args:
        x: a number, bool, string or None.
        digits: significant digits (or, with ``decimals``, digits after the point).
        sci_from: magnitudes from this value on, and below 1e-3, in scientific notation.
        grouped_from: magnitudes from this value up to ``sci_from`` as a whole number with thousands
            separators (e.g. 12,345); None: no grouping.
        decimals: ``digits`` decimals instead of significant digits in [1e-2, ``sci_from``) (scores and
            ratios around 1 line up); below 1e-2 significant digits.

    Returns:
        "-" for None, NaN or ""; "yes"/"no" for booleans; "inf"/"-inf"; "0"; the number otherwise.
    """
    if x is None or (isinstance(x, str) and not x):
        return "-"
    if isinstance(x, str):
        return x
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    x = float(x)
    if math.isnan(x):
        return "-"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    if x == 0:
        return "0"
    a = abs(x)
    if decimals:
        return f"{x:.{digits}g}" if a < 1e-2 or a >= sci_from else f"{x:.{digits}f}"
    if a >= sci_from or a < 1e-3:
        return f"{x:.{digits - 1}e}"
    if grouped_from is not None and a >= grouped_from:
        return f"{x:,.0f}"
    return f"{x:.{digits}g}"


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
