"""Every ```python block of the README runs as written, in order, in an empty folder."""

import os
import re
from pathlib import Path

README = Path(__file__).resolve().parents[2] / "README.md"


def python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)


def test_readme_python_blocks_run_in_order(tmp_path, capsys):
    blocks = python_blocks(README.read_text())
    assert len(blocks) >= 3
    namespace: dict = {"__name__": "__readme__"}
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        for k, block in enumerate(blocks):
            exec(compile(block, f"README.md python block {k + 1}", "exec"), namespace)
    finally:
        os.chdir(cwd)
    printed = capsys.readouterr().out
    assert "points in temple_out/fused.ply" in printed
    assert (tmp_path / "temple_out" / "fused.ply").is_file() and (tmp_path / "temple_out" / "dynamic.ply").is_file()
    assert namespace["out"]["depth"].shape[-2:] == namespace["imgs"].shape[-2:]
    assert len(namespace["xyz"]) > 0


def test_python_blocks_are_found():
    text = "a\n```python\nx = 1\n```\n```\nnot python\n```\n```python\ny = 2\n```\n"
    assert python_blocks(text) == ["x = 1\n", "y = 2\n"]
