"""Griffe extension: the docstrings' Sphinx roles as the site's cross-references and maths.

liefi's docstrings follow numpydoc and cross-reference with Sphinx roles, as numpy and
scipy do (``:class:`~liefi.schemes.Solution```, ``:meth:`run```, ``:math:`x```,
``.. math::``).  mkdocstrings renders Markdown, so this extension translates the roles
once, when griffe has loaded the package, before any docstring is parsed:

- ``:class:`~a.b.C``` (and ``:meth:``, ``:func:``, ``:attr:``, ``:data:``, ``:mod:``,
  ``:exc:``, ``:obj:``, ``:const:``) becomes a link to the object's entry in the API
  reference.  The target is resolved as Sphinx resolves it: relative to the current
  class, then to the enclosing modules, then as written.  A leading ``~`` shows only the
  last component, ``title <target>`` shows the title.  A target the reference does not
  render (a private helper, numpy) stays as code, without a broken link.
- an attribute documented by a ``#:`` comment (above it, or at the end of its line, as
  Sphinx's autodoc reads them) gets that comment as its docstring.
- ``:math:`x``` becomes inline maths and ``.. math:: x`` (with its indented
  continuation lines) a displayed equation, both typeset by MathJax.
"""

from __future__ import annotations

import html
import re

import griffe

ROLE = re.compile(r":(?:py:)?(class|meth|func|attr|data|mod|exc|obj|const):`([^`]+)`")
MATH_ROLE = re.compile(r":math:`([^`]+)`")
MATH_DIRECTIVE = re.compile(r"^(?P<indent>[ \t]*)\.\. math::[ \t]*(?P<first>.*)$")
TITLED = re.compile(r"^(?P<title>.+?)\s*<(?P<target>[^>]+)>$")


def _lookup(collection, path):
    """The object at ``path`` (aliases followed), or None."""
    try:
        found = collection[path]
    except Exception:  # noqa: BLE001 - griffe raises KeyError or alias-resolution errors
        return None
    try:
        return found.final_target if found.is_alias else found
    except Exception:  # noqa: BLE001 - an alias to something griffe did not load (numpy, ...)
        return None


def _scopes(obj):
    """The paths a short name is resolved against, innermost first (Sphinx's order)."""
    node = obj if obj.is_class or obj.is_module else obj.parent
    while node is not None:
        yield node.path
        node = node.parent


def resolve(obj, target):
    """The documented object that ``target`` (as written in ``obj``'s docstring) names, or None."""
    collection = obj.modules_collection
    target = target.lstrip(".")
    if target.startswith("liefi"):
        found = _lookup(collection, target)
        if found is not None:
            return found
    for scope in _scopes(obj):
        found = _lookup(collection, f"{scope}.{target}")
        if found is not None:
            return found
    return None


def _title(written, found):
    if written.startswith("~"):
        return written[1:].rsplit(".", 1)[-1]
    return written.lstrip(".")


def translate_role(obj, written):
    """HTML for one role's text: a link if the target is documented, code otherwise."""
    m = TITLED.match(written)
    if m:
        title, target = m["title"], m["target"]
    else:
        target = written
        title = None
    bare = target.lstrip("~")
    found = resolve(obj, bare)
    if title is None:
        title = _title(target, found)
    code = f"<code>{html.escape(title)}</code>"
    if found is None:
        return code
    # the canonical path: mkdocstrings registers it for every rendered object, whether
    # the page renders it as liefi.X or as liefi.module.X
    return f'<autoref identifier="{html.escape(found.path)}" optional>{code}</autoref>'


def _math_blocks(text):
    """``.. math::`` directives as ``$$ ... $$`` blocks (with their indented continuation)."""
    lines = text.split("\n")
    out = []
    i = 0
    while i < len(lines):
        m = MATH_DIRECTIVE.match(lines[i])
        if not m:
            out.append(lines[i])
            i += 1
            continue
        indent = m["indent"]
        body = [m["first"].strip()] if m["first"].strip() else []
        i += 1
        while i < len(lines) and (not lines[i].strip() or len(lines[i]) - len(lines[i].lstrip()) > len(indent)):
            if lines[i].strip():
                body.append(lines[i].strip())
            elif body and i + 1 < len(lines) and len(lines[i + 1]) - len(lines[i + 1].lstrip()) <= len(indent):
                break
            i += 1
        out.extend(["", f"{indent}$$", *(f"{indent}{b}" for b in body), f"{indent}$$", ""])
    return "\n".join(out)


def translate(obj, text):
    """A docstring with its Sphinx roles and maths in the site's Markdown."""
    text = _math_blocks(text)
    text = MATH_ROLE.sub(lambda m: f"\\({m[1]}\\)", text)
    return ROLE.sub(lambda m: translate_role(obj, m[2]), text)


COMMENT = re.compile(r"#:\s?(?P<text>.*)$")


def comment_docstring(obj):
    """The ``#:`` comment documenting attribute ``obj`` (trailing, else the lines above), or None."""
    if not obj.is_attribute or obj.lineno is None or obj.filepath is None:
        return None
    try:
        lines = obj.lines_collection[obj.filepath]
    except Exception:  # noqa: BLE001 - no source (a compiled or dynamic module)
        return None
    i = obj.lineno - 1
    if i >= len(lines):
        return None
    trailing = re.search(r"#:\s?(.*)$", lines[i])
    if trailing and "#:" not in lines[i].split("=", 1)[0]:
        return trailing[1].strip()
    above = []
    j = i - 1
    while j >= 0 and (m := COMMENT.match(lines[j].strip())):
        above.insert(0, m["text"])
        j -= 1
    return "\n".join(above).strip() or None


class SphinxRoles(griffe.Extension):
    """Translate every docstring once the package is loaded (so that every target resolves)."""

    def on_package(self, *, pkg, **kwargs):  # noqa: ARG002
        self._walk(pkg, set())

    def _walk(self, obj, seen):
        if obj.is_alias or obj.path in seen:
            return
        seen.add(obj.path)
        if obj.docstring is None and (text := comment_docstring(obj)):
            obj.docstring = griffe.Docstring(text, lineno=obj.lineno, parent=obj)
        if obj.docstring is not None:
            obj.docstring.value = translate(obj, obj.docstring.value)
        for member in list(obj.members.values()):
            self._walk(member, seen)
