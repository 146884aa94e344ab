"""The documentation site: built strictly, complete, and rendered offline in a real browser.

The site is built once (``mkdocs build --strict``) into a temporary folder.  The static
checks read its HTML and its object inventory: no raw Sphinx role reaches a page, every
public name has an entry, nothing is loaded from outside the site.  The browser checks
serve the site on 127.0.0.1 and render the getting-started page and an API page in
headless Chromium (Debian's ``chromium`` package; skipped when it is absent): the maths
must be typeset by the MathJax shipped with the site, the console must stay silent, and
a screenshot of each page is kept in the test's temporary folder.
"""

from __future__ import annotations

import functools
import http.server
import importlib
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import threading
import zlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

for _mod in ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python"):
    if importlib.util.find_spec(_mod.split(".")[0]) is None:
        pytest.skip(f"the docs extra is not installed ({_mod}): pip install -e '.[docs]'", allow_module_level=True)


def _load_hook(name):
    spec = importlib.util.spec_from_file_location(f"_docs_hook_{name}", ROOT / "docs" / "hooks" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


# a raw role as it reaches a page: its backticks kept, or turned into <code> by Markdown
ROLE_RE = re.compile(r":(?:py:)?(?:class|meth|func|attr|data|mod|exc|obj|const|math|ref):(?:`|<code>)")
CODE_RE = re.compile(r"<code>.*?</code>", re.DOTALL)
PRE_RE = re.compile(r"<pre\b.*?</pre>", re.DOTALL)


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    try:
        _load_hook("mathjax").mathjax_es5()
    except RuntimeError as exc:
        pytest.skip(str(exc))
    out = tmp_path_factory.mktemp("site")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return out, proc.stdout + proc.stderr


def _pages(out):
    return sorted(out.rglob("*.html"))


def _inventory(out):
    raw = (out / "objects.inv").read_bytes()
    body = zlib.decompress(raw.split(b"\n", 4)[4]).decode()
    return {line.split()[0] for line in body.splitlines() if line.strip()}


# --- the role translation, on its own -------------------------------------------------


def test_math_directive_and_role_become_arithmatex_source():
    roles = _load_hook("sphinx_roles")
    text = "Intro :math:`x_1`.\n\n.. math:: a = b\n          + c\n\nAfter.\n"
    out = roles._math_blocks(text)
    assert "$$\na = b\n+ c\n$$" in out
    assert out.rstrip().endswith("After.")
    assert roles.MATH_ROLE.sub(lambda m: f"\\({m[1]}\\)", "see :math:`x_1`") == "see \\(x_1\\)"


# --- the built site, read as files ---------------------------------------------------


def test_every_page_is_in_the_navigation(site):
    _, log = site
    assert "not included in the \"nav\"" not in log, log


def test_no_raw_sphinx_role_on_any_page(site):
    out, _ = site
    found = {}
    for page in _pages(out):
        text = PRE_RE.sub("", page.read_text(encoding="utf-8"))  # code blocks may show roles
        n = len(ROLE_RE.findall(text)) + CODE_RE.sub("", text).count(".. math::")
        if n:
            found[str(page.relative_to(out))] = n
    assert found == {}


# raw markup as it reaches a page when a docstring or page is not rendered as meant: an
# unresolved <autoref> tag (escaped or not), reST's doubled backticks, a Sphinx role, an
# unresolved Markdown reference ``[title][]``; in text and in attributes (a tooltip)
RAW_MARKUP = {
    "<autoref": re.compile(r"<autoref\b|&lt;autoref\b"),
    "``": re.compile(r"``"),
    "role": ROLE_RE,
    "[...][]": re.compile(r"\]\[[\w.:-]*\]"),
}


def raw_markup(html_text):
    """``{kind: count}`` of the raw markup (:data:`RAW_MARKUP`) in a page, outside its code blocks."""
    text = PRE_RE.sub("", html_text)
    prose = CODE_RE.sub("", text)  # ``a[i][j]`` in code is no reference
    return {kind: n for kind, rx in RAW_MARKUP.items()
            if (n := len(rx.findall(prose if kind == "[...][]" else text)))}


def test_raw_markup_is_found():
    """The check below sees what the API pages showed: autoref tags kept as text, ``x``."""
    assert raw_markup('<td><span title="a &lt;autoref identifier=&#34;x&#34;&gt;">``y``</span></td>') == {
        "<autoref": 1, "``": 2}
    assert raw_markup("<p>see :func:`f` and [liefi.run][]</p>") == {"role": 1, "[...][]": 1}
    assert raw_markup("<pre><code>``kept``</code></pre><p><code>a[i][j]</code> <code>x</code></p>") == {}


def test_no_raw_markup_on_any_page(site):
    out, _ = site
    found = {str(page.relative_to(out)): n for page in _pages(out)
             if (n := raw_markup(page.read_text(encoding="utf-8")))}
    assert found == {}


def _member_headings(page, cls):
    """The member entries of ``cls`` on ``page``, in the page's order."""
    return re.findall(rf'<h\d id="{re.escape(cls)}\.(\w+)" class="doc doc-heading"', page)


def test_feedback_integrator_run_first_with_its_parameters(site):
    """``run`` leads the class's entries and has a Parameters table; every public member is listed."""
    out, _ = site
    page = (out / "api" / "feedback" / "index.html").read_text(encoding="utf-8")
    members = _member_headings(page, "liefi.FeedbackIntegrator")
    assert members[0] == "run", members
    from liefi import FeedbackIntegrator

    public = {name for name in vars(FeedbackIntegrator) if not name.startswith("_")}
    assert public <= set(members), public - set(members)
    run = page.split('id="liefi.FeedbackIntegrator.run"', 1)[1].split(f'id="liefi.FeedbackIntegrator.{members[1]}"')[0]
    params = re.split(r'<span class="doc-section-title">', run)
    table = next(part for part in params if part.startswith("Parameters:"))
    for name in ("t_span", "dt", "scheme", "t_eval", "rtol"):
        assert f"<code>{name}</code>" in table, name


def test_attribute_entries_show_no_source_expression(site):
    """An attribute's heading names it, without the expression that computes it (``X = f(Y)``)."""
    out, _ = site
    heading = re.compile(r'<h\d id="([\w.]+)" class="doc doc-heading">(.*?)</h\d>', re.DOTALL)
    shown = []
    for page in (out / "api").rglob("*.html"):
        for ident, body in heading.findall(page.read_text(encoding="utf-8")):
            text = re.sub(r"<[^>]+>", "", body)
            if "-attribute" in text and "=" in text.split("-attribute")[0]:
                shown.append(ident)
    assert shown == []


def test_cross_references_resolve_to_the_documented_entries(site):
    out, _ = site
    feedback = (out / "api" / "feedback" / "index.html").read_text(encoding="utf-8")
    # :class:`~liefi.schemes.Solution` in FeedbackIntegrator.run's docstring
    assert 'href="../results/#liefi.Solution"' in feedback
    # a short :meth:`...` resolved against its class
    groups = (out / "api" / "groups" / "index.html").read_text(encoding="utf-8")
    assert re.search(r'<a class="autorefs autorefs-internal"[^>]*href="#liefi\.groups\.LieGroup\.\w+"', groups)


def test_every_public_name_has_an_entry(site):
    out, _ = site
    inventory = _inventory(out)
    tails = {name.rsplit(".", 1)[-1] for name in inventory if name.startswith("liefi.")}

    import liefi

    missing = []
    for name in liefi.__all__:  # not dir(liefi): submodules that other tests imported would show up there
        value = getattr(liefi, name)
        if isinstance(value, type(liefi)):  # a module: documented if any of its names is
            if not any(entry.startswith(f"{value.__name__}.") or entry == value.__name__ for entry in inventory):
                missing.append(f"liefi.{name}")
        elif name not in tails:
            missing.append(f"liefi.{name}")
    for sub in ("groups", "reduction", "schemes", "scenes", "engine", "sympy_input", "gains", "stability"):
        mod = importlib.import_module(f"liefi.{sub}")
        names = getattr(mod, "__all__", None)
        if names is None:  # no __all__: the module's own public functions and classes
            names = [n for n, v in vars(mod).items() if not n.startswith("_")
                     and getattr(v, "__module__", None) == mod.__name__]
        missing += [f"{mod.__name__}.{n}" for n in names if f"{mod.__name__}.{n}" not in inventory and n not in tails]
    for name in ("liefi.from_sympy", "liefi.Solution", "liefi.IntegrationError",
                 "liefi.stability.StabilityError", "liefi.gains", "liefi.scenes"):
        # a name users write (liefi.stability is liefi.integrator.stability under its old flat name) has the
        # entry of the object it names: a module's own name, a class's or function's module and qualified name
        head, _, tail = name.rpartition(".")
        obj = getattr(importlib.import_module(head), tail)
        canonical = obj.__name__ if isinstance(obj, type(liefi)) else f"{obj.__module__}.{obj.__qualname__}"
        assert any(n in inventory or any(e.startswith(n + ".") for e in inventory) for n in (name, canonical)), name
    assert missing == []


def test_nothing_is_loaded_from_outside_the_site(site):
    out, _ = site
    assert (out / "javascripts" / "mathjax" / "tex-chtml.js").is_file()
    assert (out / "javascripts" / "mathjax" / "output" / "chtml" / "fonts" / "woff-v2").is_dir()
    external = re.compile(r'<(?:script|link)\b[^>]*(?:src|href)="(?:https?:)?//', re.IGNORECASE)
    offenders = [str(p.relative_to(out)) for p in _pages(out) if external.search(p.read_text(encoding="utf-8"))]
    assert offenders == []


def test_code_blocks_wrap(site):
    out, _ = site
    page = (out / "getting-started" / "index.html").read_text(encoding="utf-8")
    assert "stylesheets/code.css" in page
    css = (out / "stylesheets" / "code.css").read_text(encoding="utf-8")
    assert "pre-wrap" in css


# --- the site in headless Chromium ----------------------------------------------------


def _chromium():
    for candidate in ("/usr/bin/chromium", shutil.which("chromium"), shutil.which("chromium-browser")):
        if candidate and os.access(candidate, os.X_OK):
            return candidate
    return None


@pytest.fixture(scope="module")
def served(site):
    out, _ = site
    log = []

    class Handler(http.server.SimpleHTTPRequestHandler):
        def log_message(self, fmt, *args):  # record, do not print
            log.append((self.path, args[1] if len(args) > 1 else ""))

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Handler, directory=str(out)))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}", log
    finally:
        server.shutdown()
        server.server_close()


CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--enable-logging=stderr", "--v=0", "--virtual-time-budget=8000",
]


def _render(chromium, url, tmp_path, what):
    """``(dom, console lines)`` of ``url`` after MathJax had time to typeset; a screenshot beside."""
    shot = tmp_path / f"{what}.png"
    proc = subprocess.run(
        [chromium, *CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'profile'}", "--window-size=1280,2000",
         "--hide-scrollbars", f"--screenshot={shot}", "--dump-dom", url],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert shot.is_file() and shot.stat().st_size > 10_000, f"no screenshot of {url}"
    console = [line for line in proc.stderr.splitlines() if ":CONSOLE" in line]
    return proc.stdout, console


@pytest.mark.parametrize("page", ["getting-started/", "api/gains/"])
def test_page_renders_typeset_maths_with_a_silent_console(served, page, tmp_path):
    chromium = _chromium()
    if chromium is None:
        pytest.skip("headless Chromium is not installed (Debian: apt-get install -y chromium)")
    base, log = served
    dom, console = _render(chromium, f"{base}/{page}", tmp_path, page.strip("/").replace("/", "-"))
    # typeset: MathJax replaced every \( ... \) and \[ ... \] of the page
    assert dom.count("<mjx-container") >= 3, "the maths is not typeset"
    body = dom.split("<body", 1)[1]
    leftovers = [m for m in re.findall(r"\\\(|\\\[", PRE_RE.sub("", body))]
    assert leftovers == [], f"raw maths left on the page: {len(leftovers)}"
    assert console == [], "\n".join(console)
    # everything came from the site itself, and nothing was missing
    failed = [(path, code) for path, code in log if not str(code).startswith(("2", "3"))]
    assert failed == []
    assert any("mathjax/tex-chtml.js" in path for path, _ in log)
