"""mkdocs hook: the committed reports (reports/**) become pages and files of the docs site.

The reports live outside docs/ (commands write them there), so this adds them to the site as they are, and
rewrites the two kinds of links that cross between the folders: ``../reports/...`` in a docs page
(``../../reports/...`` one folder down) and ``../../docs/...`` in a report. Only files the build already copies are
linked, so a broken reference still fails ``mkdocs build --strict``.
"""

from __future__ import annotations

import os

from mkdocs.structure.files import File

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
KINDS = (".md", ".png", ".csv", ".json")


def on_files(files, config):
    """Add every report file (markdown, figures, tables) under ``reports/`` of the site."""
    for folder, _, names in os.walk(os.path.join(ROOT, "reports")):
        for name in sorted(names):
            if name.endswith(KINDS) and not name.startswith(".tmp-"):
                rel = os.path.relpath(os.path.join(folder, name), ROOT).replace(os.sep, "/")
                files.append(File(rel, ROOT, config["site_dir"], config["use_directory_urls"]))
    return files


def on_page_markdown(markdown, page, config, files):
    """Point the links that cross between docs/ and reports/ at the site's copies.

    The pages link as the repository lays the files out (so the links work on GitHub and in a checkout): a page
    ``depth`` folders below docs/ reaches a report through ``depth + 1`` parent folders, its copy on the site through
    ``depth``.
    """
    if page.file.src_uri.startswith("reports/"):
        return markdown.replace("](../../docs/", "](../../")
    depth = page.file.src_uri.count("/")
    return markdown.replace("](" + "../" * (depth + 1) + "reports/", "](" + "../" * depth + "reports/")
