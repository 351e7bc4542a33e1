"""The README's Python example runs as written: the first ```python block after the heading
"## From Python" is executed, and its own asserts (the plan's shape, the box nearer its goal)
must hold."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def python_example(text: str) -> str:
    """The first ```python block after the "## From Python" heading of ``text``."""
    start = re.search(r"^## From Python\s*$", text, flags=re.M)
    assert start, 'README.md has no "## From Python" heading'
    block = re.search(r"^```python\n(.*?)^```", text[start.end() :], flags=re.M | re.S)
    assert block, 'no ```python block after "## From Python"'
    return block.group(1)


def test_the_example_is_found_and_checks_something() -> None:
    code = python_example(README.read_text(encoding="utf-8"))
    assert "planner.plan(" in code and "world.step(" in code
    assert "assert " in code


def test_the_readme_python_example_runs() -> None:
    code = python_example(README.read_text(encoding="utf-8"))
    namespace: dict = {"__name__": "readme_example"}
    exec(compile(code, f"{README}:From Python", "exec"), namespace)
    start, error = namespace["start"], namespace["error"]
    assert error[0] < start[0], "the push did not bring the box nearer its goal"
    assert namespace["action"].shape == (2,)
