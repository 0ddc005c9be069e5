"""MkDocs hooks: the user guide from README.md and the gallery from analyses/.

* ``<!-- README -->`` in a page is replaced by README.md (its title dropped, its
  links into ``docs/`` made relative to the site);
* ``<!-- GALLERY -->`` by one section per script of ``analyses/``: the first line
  of its docstring as the title, the rest of the docstring, the command that runs
  it and its figures from ``docs/gallery/`` (``docs/make_gallery.py`` draws them).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GALLERY = ROOT / "docs" / "gallery"
#: Analyses that print tables but draw no figure (as in docs/make_gallery.py).
NO_FIGURE = ("fig2_two_level_gibbs", "ml_global_check")


def readme() -> str:
    """README.md without its first-level title, links into docs/ made site-relative."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    text = re.sub(r"\A# .*\n", "# User guide\n", text)
    return re.sub(r"\]\(docs/([^)]+)\)", r"](\1)", text)


def _docstring(path: Path) -> str:
    return ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or path.stem


def _escape(text: str) -> str:
    """A docstring shown as text: reST double backticks as Markdown code."""
    return text.replace("``", "`")


def gallery() -> str:
    """One section per analysis script: summary, command, figures."""
    parts = []
    for script in sorted((ROOT / "analyses").glob("*.py")):
        if script.name.startswith("_"):
            continue
        doc = _docstring(script)
        title, _, body = doc.partition("\n")
        parts.append(f"## {script.stem}\n\n**{_escape(title.strip())}**\n")
        parts.append(f"`python analyses/{script.name}` (quick sizes; `--help` for the "
                     "options)\n")
        figures = sorted(GALLERY.glob(f"{script.stem}.png")) + sorted(
            GALLERY.glob(f"{script.stem}-*.png"))
        for fig in figures:
            parts.append(f"![{script.stem}](gallery/{fig.name})\n")
        if not figures and script.stem in NO_FIGURE:
            parts.append("*(prints tables; no figure)*\n")
        elif not figures:
            parts.append(f"*(figure not in the gallery: `python docs/make_gallery.py "
                         f"{script.stem}` draws it)*\n")
        parts.append("```text\n" + body.strip() + "\n```\n")
    return "\n".join(parts)


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ARG001 - mkdocs API
    """Fill the README and GALLERY markers of a page."""
    if "<!-- README -->" in markdown:
        markdown = markdown.replace("<!-- README -->", readme())
    if "<!-- GALLERY -->" in markdown:
        markdown = markdown.replace("<!-- GALLERY -->", gallery())
    return markdown
