"""mkdocs hooks: the README as the home page; docstrings' Sphinx roles shown as plain code.

One source for the front page: the README is what a user of the repository reads first, and
the same text opens the site.
"""

from __future__ import annotations

import re
from pathlib import Path

from mkdocs.structure.files import File

README = Path(__file__).resolve().parents[2] / "README.md"


def on_files(files, config):
    text = README.read_text(encoding="utf-8")
    text = re.sub(r"\]\(docs/", "](", text)  # [x](docs/page.md) -> [x](page.md)
    files.append(File.generated(config, "index.md", content=text))
    return files


_ROLE = re.compile(r":(?:class|func|mod|meth|attr|data|exc|obj|ref):<code>(~?)([^<]*)</code>")


def _role(match: re.Match) -> str:
    short, target = match.groups()
    return f"<code>{target.rsplit('.', 1)[-1] if short else target}</code>"


def on_page_content(html, page, config, files):
    """Docstrings use Sphinx roles (``:class:`~a.B` ``); show them as the code they name."""
    return _ROLE.sub(_role, html)
