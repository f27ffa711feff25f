"""Report prose lives in Jinja2 templates (``ehss_gym/reporting/templates``); code passes them numbers and tables."""

from __future__ import annotations

import functools
import os

import jinja2

from ehss_gym.infra.fmt import fmt_axis, fmt_num, fmt_range, md_table

TEMPLATES = os.path.join(os.path.dirname(__file__), "templates")


def _sci(v: float) -> str:
    """A power of ten in short scientific notation: 1e5, 1e-4."""
    mantissa, exponent = f"{v:.0e}".split("e")
    return f"{mantissa}e{int(exponent)}"


@functools.cache
def environment(folder: str = TEMPLATES) -> jinja2.Environment:
    """The environment of the templates in ``folder``: undefined names are errors, blocks do not leave blank lines.

    Args:
        folder: the templates' folder; the package's own by default (the source tree's benchmarks pass theirs,
            so their report follows the same rules and filters).
    """
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(folder), undefined=jinja2.StrictUndefined,
                             trim_blocks=True, lstrip_blocks=True, keep_trailing_newline=True, autoescape=False)
    env.filters.update(num=fmt_num, axis=fmt_axis, rng=fmt_range, pct=lambda v, d=1: f"{v:.{d}%}",
                       g=lambda v: f"{v:g}", sci=_sci)
    env.globals.update(table=md_table)
    return env


def render(template: str, **context) -> str:
    """Render ``template`` (a file name under templates/) with ``context``."""
    return render_in(environment(), template, **context)


def render_in(env: jinja2.Environment, template: str, **context) -> str:
    """Render ``template`` of the environment ``env`` with ``context``, runs of blank lines collapsed to one."""
    text = env.get_template(template).render(**context)
    while "\n\n\n" in text:  # conditional blocks may leave runs of blank lines
        text = text.replace("\n\n\n", "\n\n")
    return text
