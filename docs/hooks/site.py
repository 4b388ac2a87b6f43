"""mkdocs hooks: the README as the home page, under the expert GIFs; docstrings' Sphinx roles shown
as plain code.

One source for the front page: the README is what a user of the repository reads first, and
the same text opens the site, its title followed by each task's scripted expert (the GIFs of
``docs/img/``, written by ``scripts/docs_pictures.py``).
"""

from __future__ import annotations

import re
from pathlib import Path

from mkdocs.structure.files import File

README = Path(__file__).resolve().parents[2] / "README.md"
IMG = Path(__file__).resolve().parents[1] / "img"


def home_page(readme: str, gifs: list[Path]) -> str:
    """The README as the site's home page: its links made relative to docs/, each GIF (a task's
    scripted expert) under its first line, the title."""
    text = re.sub(r"\]\(docs/", "](", readme)  # [x](docs/page.md) -> [x](page.md)
    title, _, rest = text.partition("\n")
    strip = " ".join(f"![{g.stem}: the scripted expert](img/{g.name})" for g in gifs)
    return f"{title}\n\n{strip}\n{rest}" if gifs else text


def on_files(files, config):
    text = home_page(README.read_text(encoding="utf-8"), sorted(IMG.glob("*.gif")))
    files.append(File.generated(config, "index.md", content=text))
    return files


_ROLE = re.compile(r":(?:class|func|mod|meth|attr|data|exc|obj|ref):<code>(~?)([^<]*)</code>")


def _role(match: re.Match) -> str:
    short, target = match.groups()
    return f"<code>{target.rsplit('.', 1)[-1] if short else target}</code>"


def on_page_content(html, page, config, files):
    """Docstrings use Sphinx roles (``:class:`~a.B` ``); show them as the code they name."""
    return _ROLE.sub(_role, html)
