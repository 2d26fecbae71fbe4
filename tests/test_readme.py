"""The README's Python example runs as written, and the docs repeat it verbatim."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]


def _python_blocks(path: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(), flags=re.S)


@pytest.mark.slow  # compile-heavy: runs with the slow tests
def test_readme_example_runs(capsys):
    blocks = _python_blocks(ROOT / "README.md")
    assert blocks, "README has no python example"
    scope = {}
    for code in blocks:
        exec(compile(code, "README.md", "exec"), scope)
    out = capsys.readouterr().out
    assert "3.14159" in out  # log at π is exact
    assert "17.72" in out  # the first tennis-racket flip of I = (1, 2, 2.5), closed form
    # the flip as an event: the closed form to the solver's tolerance, not the 0.1 s grid's
    assert abs(float(scope["flip"].event_t) - float(scope["t_flip"])) < 1e-8


def test_docs_repeat_the_readme_example():
    assert _python_blocks(ROOT / "docs" / "getting-started.md") == _python_blocks(
        ROOT / "README.md"
    )
