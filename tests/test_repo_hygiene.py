"""The repository ignores what liefi's own commands write by default."""

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("path", ["liefi-out/summary.md", "liefi-out/figures/suslov.png", "site/index.html"])
def test_default_outputs_are_ignored(path):
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    proc = subprocess.run(["git", "check-ignore", "-q", path], cwd=ROOT, capture_output=True)
    assert proc.returncode == 0, f"{path} is not ignored by .gitignore"


def test_listed_slow_cases_exist():
    """Every long case of ``tests/slow_tests.txt`` names a test that exists (a renamed test would
    silently come back into the default suite)."""
    import re

    from conftest import slow_node_ids

    ids = slow_node_ids()
    assert len(ids) > 100
    for nid in ids:
        path, name = nid.split("::")[0], re.split(r"::|\[", nid)[-2 if "[" in nid else -1]
        assert (ROOT / path).is_file(), nid
        assert re.search(rf"def {re.escape(name)}\(", (ROOT / path).read_text()), nid
