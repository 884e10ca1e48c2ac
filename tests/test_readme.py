"""The README's Python code runs as printed.

Every ```python block of README.md is run in a fresh interpreter from the repository root.
The only change: training budgets (``.learn(N)``) are cut to a few hundred steps, so that a
block that trains shows that it runs, not how well it learns.
"""

from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
BLOCKS = re.findall(r"^```python\n(.*?)^```", (ROOT / "README.md").read_text(), flags=re.S | re.M)
LEARN = re.compile(r"\.learn\(\s*[\d_]+\s*\)")


def _needs(code: str) -> list[str]:
    """Third-party modules a block imports that are optional extras."""
    optional = ("sb3_contrib", "rl_zoo3", "ray")
    return [m for m in optional if re.search(rf"^\s*(from|import) {m}\b", code, flags=re.M)]


def test_the_readme_has_python_blocks():
    assert len(BLOCKS) >= 4
    assert all("import" in b for b in BLOCKS)


@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_readme_block_runs_as_printed(index):
    code = BLOCKS[index]
    for module in _needs(code):
        if importlib.util.find_spec(module) is None:
            pytest.skip(f"needs the optional {module}")
    code = LEARN.sub(".learn(256)", code)
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, f"README block {index + 1}:\n{code}\n{res.stderr[-3000:]}"
