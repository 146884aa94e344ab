"""mkdocs hook: ship MathJax with the site, so that the maths renders offline.

The MathJax 3 browser bundle comes from a PyPI package (``django-static-mathjax``:
MathJax's own ``es5`` build as package data, with no dependency; installed by
``pip install -e ".[docs]"``).  After each build (``mkdocs build`` and ``mkdocs
serve``) its ``tex-chtml.js`` and the components it loads on demand (TeX extensions,
fonts, menu, accessibility) are copied to ``javascripts/mathjax/`` in the site, where
``mkdocs.yml``'s ``extra_javascript`` loads it.  No page asks a CDN for anything.
"""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

#: where the site loads MathJax from (relative to the site root, as in mkdocs.yml)
TARGET = Path("javascripts") / "mathjax"
BUNDLE = "tex-chtml.js"


def mathjax_es5() -> Path:
    """The ``es5`` folder of the installed MathJax package, or a clear error."""
    spec = importlib.util.find_spec("mathjax")
    roots = list(spec.submodule_search_locations or []) if spec is not None else []
    for root in roots:
        es5 = Path(root) / "static" / "mathjax" / "es5"
        if (es5 / BUNDLE).is_file():
            return es5
    raise RuntimeError(
        "docs: MathJax's assets are missing (the 'django-static-mathjax' package ships them); "
        "install the docs extra with: pip install -e \".[docs]\""
    )


def copy_mathjax(site_dir) -> Path:
    """Copy MathJax's bundle and its on-demand components into ``site_dir``; the target folder."""
    es5 = mathjax_es5()
    target = Path(site_dir) / TARGET
    target.mkdir(parents=True, exist_ok=True)
    shutil.copy2(es5 / BUNDLE, target / BUNDLE)
    # the components tex-chtml.js loads at run time; the other combined bundles are not needed
    for sub in ("input", "output", "ui", "a11y", "adaptors", "sre"):
        shutil.copytree(es5 / sub, target / sub, dirs_exist_ok=True)
    return target


def on_post_build(config, **kwargs):  # noqa: ARG001
    copy_mathjax(config["site_dir"])
