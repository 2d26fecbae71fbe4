"""The example of docs/api/observables.md runs as written and prints what it says."""

import re
from pathlib import Path

import numpy as np
import pytest

PAGE = Path(__file__).parents[2] / "docs" / "api" / "observables.md"


@pytest.mark.slow
def test_docs_example_runs(capsys):
    """(~25 s: it compiles reverse mode through the adaptive solve, as written.)"""
    blocks = re.findall(r"```python\n(.*?)```", PAGE.read_text(), flags=re.S)
    assert len(blocks) == 1
    exec(compile(blocks[0], str(PAGE), "exec"), {})
    lines = capsys.readouterr().out.strip().splitlines()
    numbers = [np.array(re.findall(r"-?\d+\.\d+(?:e-?\d+)?", line), float) for line in lines]
    t_flip, t_closed = numbers[0]
    np.testing.assert_allclose(t_flip, t_closed, atol=1e-6)
    np.testing.assert_allclose(t_flip, 14.1005, atol=1e-4)
    np.testing.assert_allclose(numbers[1], numbers[2], rtol=1e-3)
    np.testing.assert_allclose(numbers[1], [378, -11.8, -423], rtol=5e-3)
