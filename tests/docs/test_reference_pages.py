"""The generated reference pages hold every command, flag and training field, and are current; nothing the long
README and model card stated is lost."""

import argparse
import dataclasses
import importlib.util
import subprocess
from pathlib import Path

import pytest

from mvsformerpp.cli import build_parser
from mvsformerpp.training.config import RECIPES, TrainConfig

ROOT = Path(__file__).resolve().parents[2]


def _tool(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "tools" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


hooks = _tool("docs_hooks")


def _parsers(parser: argparse.ArgumentParser, name: str = "mvsformerpp"):
    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub_name, sub in action.choices.items():
                yield from _parsers(sub, f"{name} {sub_name}")


def test_the_cli_page_holds_every_command_and_flag():
    page = hooks.cli_reference()
    commands = list(_parsers(build_parser()))
    assert len(commands) >= 17
    for name, parser in commands[1:]:
        assert f"# {name.removeprefix('mvsformerpp ')}\n" in page, name
        for action in parser._actions:
            for flag in action.option_strings:
                if flag not in ("-h", "--help"):
                    assert f"`{flag}`" in page, (name, flag)


def test_the_train_config_page_holds_every_field_and_recipe():
    page = hooks.train_config_reference()
    for f in dataclasses.fields(TrainConfig):
        assert f"| `{f.name}` |" in page, f.name
    assert all(f"`{r}`" in page for r in RECIPES)
    rows = [line for line in page.splitlines() if line.startswith("| `")]
    assert all(line.replace("\\|", "").count("|") == 4 + len(RECIPES) for line in rows)  # no stray pipe splits a row


def test_the_committed_pages_are_current():
    assert hooks.stale_pages() == [], "run python tools/docs_hooks.py --write"


def test_a_stale_page_is_found(tmp_path):
    (tmp_path / "reference").mkdir()
    (tmp_path / "reference" / "cli.md").write_text(hooks.cli_reference())
    assert hooks.stale_pages(tmp_path) == ["reference/train-config.md"]


def test_the_notes_are_listed_newest_first(tmp_path):
    (tmp_path / "2026-01-02-b.md").write_text("# Second\n\ntext\n")
    (tmp_path / "2026-01-01-a.md").write_text("intro\n# First\n")
    (tmp_path / "index.md").write_text("# Notes\n")
    (tmp_path / "draft.md").write_text("# not dated\n")
    assert hooks.notes_list(tmp_path) == ["- 2026-01-02: [Second](2026-01-02-b.md)",
                                          "- 2026-01-01: [First](2026-01-01-a.md)"]


def test_nothing_the_long_readme_and_model_card_stated_is_lost():
    lost = _tool("docs_nothing_lost")
    if subprocess.run(["git", "cat-file", "-e", f"{lost.BASE}^{{commit}}"], cwd=ROOT,
                      capture_output=True).returncode != 0:
        pytest.skip(f"this checkout has no commit {lost.BASE} (a shallow clone)")
    checked, missing = lost.missing_lines()
    assert checked > 1500
    assert missing == [], "\n".join(f"{p}:{k}: {line}" for p, k, line in missing)


def test_numbers_are_matched_within_one_block():
    lost = _tool("docs_nothing_lost")
    text = "a 1.5 and 269,570\nsame block 7\n\nother 42\n```\ncode 3\n\nstill code 4\n```\n"
    assert lost.numbers("269,570 points, 1e-4, 640x480") == ["269570", "1e-4", "640", "480"]
    assert lost.blocks(text) == [{"1.5", "269570", "7"}, {"42"}, {"3", "4"}]
