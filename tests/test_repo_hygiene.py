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
