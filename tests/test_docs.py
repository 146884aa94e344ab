"""The documentation site's code runs: every ```python block of the pages below, in order, one
namespace per page (a page is a script cut into pieces).

A block preceded by ``<!-- requires: NAME ... -->`` runs only when every NAME exists (a module,
or an attribute path such as ``liefi.from_sympy``); otherwise it and the rest of its page are
skipped, and the test says which name is missing. Every other block must run.
"""

from __future__ import annotations

import importlib
import pathlib
import re

import pytest

DOCS = pathlib.Path(__file__).resolve().parent.parent / "docs"
PAGES = ["getting-started.md", "concepts.md", "choosing-a-method.md", "rolling_bodies.md", "gradients.md", "inputs.md", *sorted(p.relative_to(DOCS).as_posix() for p in (DOCS / "tutorials").glob("*.md"))]

_BLOCK = re.compile(r"(?:<!--\s*requires:\s*(?P<req>[^>]*?)\s*-->\s*\n)?```python\n(?P<code>.*?)\n```", re.S)


def blocks(page):
    """``[(requirements, code), ...]`` of a page's python blocks."""
    text = (DOCS / page).read_text()
    return [((m.group("req") or "").split(), m.group("code")) for m in _BLOCK.finditer(text)]


def missing(name):
    """None if ``name`` (module or dotted attribute path) exists, else the part that does not."""
    parts = name.split(".")
    try:
        obj = importlib.import_module(parts[0])
    except ImportError:
        return parts[0]
    for i, attr in enumerate(parts[1:], 1):
        if not hasattr(obj, attr):
            return ".".join(parts[: i + 1])
        obj = getattr(obj, attr)
    return None


def test_pages_have_code():
    assert set(PAGES) >= {"getting-started.md", "tutorials/system-from-data.md", "tutorials/own-group.md"}
    for page in PAGES:
        assert blocks(page), page


@pytest.mark.parametrize("page", PAGES)
def test_page_code_runs(page, capsys):
    ns = {"__name__": f"docs_{page}"}
    for i, (req, code) in enumerate(blocks(page)):
        absent = [m for m in map(missing, req) if m]
        if absent:
            pytest.skip(f"{page}: block {i + 1} and after need {', '.join(absent)} (not on this branch)")
        exec(compile(code, f"{page}[block {i + 1}]", "exec"), ns)  # noqa: S102 -- the docs' own code


def test_readme_lists_every_registered_scene():
    """The README's scene list (the paragraph ``Scenes: ...``) names every scene of ``liefi.scenes``."""
    from liefi import scenes

    readme = (DOCS.parent / "README.md").read_text()
    listed = re.search(r"^Scenes: (.*?)\n\n", readme, re.S | re.M)
    assert listed, "the README has a paragraph starting 'Scenes: '"
    named = set(re.findall(r"`([a-z0-9-]+)`", listed.group(1)))
    assert set(scenes.REGISTRY) - named == set()
