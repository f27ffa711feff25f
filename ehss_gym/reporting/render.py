"""Report prose lives in Jinja2 templates (``ehss_gym/reporting/templates``); code passes them numbers and tables."""

from __future__ import annotations

import functools
import os

import jinja2

from ehss_gym.core.fmt import fmt_axis, fmt_num, fmt_range, md_table

TEMPLATES = os.path.join(os.path.dirname(__file__), "templates")


@functools.lru_cache(maxsize=1)
def environment() -> jinja2.Environment:
    """The templates' environment: undefined names are errors, blocks do not leave blank lines."""
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(TEMPLATES), undefined=jinja2.StrictUndefined,
                             trim_blocks=True, lstrip_blocks=True, keep_trailing_newline=True, autoescape=False)
    env.filters.update(num=fmt_num, axis=fmt_axis, rng=fmt_range, pct=lambda v, d=1: f"{v:.{d}%}",
                       g=lambda v: f"{v:g}")
    env.globals.update(table=md_table)
    return env


def render(template: str, **context) -> str:
    """Render ``template`` (a file name under templates/) with ``context``."""
    text = environment().get_template(template).render(**context)
    while "\n\n\n" in text:  # conditional blocks may leave runs of blank lines
        text = text.replace("\n\n\n", "\n\n")
    return text
