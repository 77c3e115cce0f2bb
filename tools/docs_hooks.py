"""The generated reference pages, and the MkDocs hooks that keep them and the notes list current.

``docs/reference/cli.md`` is written from the parser the ``mvsformerpp`` command builds (``cli.build_parser``):
every subcommand, its usage line and every argument with its value, choices and help, exactly as
``--help`` holds them (the config dataclasses' fields become most of those flags through
``utils.config_flags``). ``docs/reference/train-config.md`` is written from ``training.config.TrainConfig``:
every field that a training YAML or ``train --set key=value`` may set, with its type, its docstring and
its value in each recipe. Both are committed (so they read on the repository's web pages too); building
the site fails while either differs from what the code generates now, and so does a test. The notes
page gains, when the site is built, the list of the lab notes in ``docs/notes/`` (date and title of each),
so a new note is one file.

    python tools/docs_hooks.py --write    # regenerate docs/reference/cli.md and train-config.md
    python tools/docs_hooks.py --check    # exit 1 if either is out of date
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import logging
import os
import re
import sys
import typing
from pathlib import Path

from mvsformerpp.cli import build_parser
from mvsformerpp.training.config import RECIPES, TrainConfig
from mvsformerpp.utils.config_flags import field_docs

DOCS = Path(__file__).resolve().parents[1] / "docs"
GENERATED = {"reference/cli.md": "cli_reference", "reference/train-config.md": "train_config_reference"}
NOTE_NAME = re.compile(r"(\d{4}-\d{2}-\d{2})-[a-z0-9-]+\.md$")


# ---- the command line ---------------------------------------------------------------------------------------


def _subcommands(parser: argparse.ArgumentParser) -> list[tuple[str, argparse.ArgumentParser, str]]:
    """(name, parser, one-line help) of each subcommand of ``parser``, in the order ``--help`` lists them."""
    out = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            out.extend((name, sub, helps.get(name, "")) for name, sub in action.choices.items())
    return out


def _value(action: argparse.Action) -> str:
    """What follows the flag: its choices or metavar, repeated as its nargs says (empty for a switch)."""
    if action.nargs == 0:
        return ""
    if action.choices is not None and not isinstance(action, argparse._SubParsersAction):
        one = "{" + ",".join(str(c) for c in action.choices) + "}"
    elif isinstance(action.metavar, tuple):
        return " ".join(action.metavar)
    else:
        one = action.metavar or (action.dest.upper() if action.option_strings else action.dest)
    if isinstance(action.nargs, int):
        return " ".join([one] * action.nargs)
    return {"?": f"[{one}]", "*": f"[{one} ...]", "+": f"{one} [{one} ...]"}.get(action.nargs, one)


def _help(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    """The argument's help as ``--help`` prints it, with a default it does not state added."""
    text = parser._get_formatter()._expand_help(action) if action.help else ""
    default = action.default
    if (action.option_strings and action.nargs != 0 and default not in (None, argparse.SUPPRESS, [], ())
            and "default" not in text):
        shown = " ".join(map(str, default)) if isinstance(default, (list, tuple)) else default
        text = f"{text} (default: {shown})".strip()
    return " ".join(text.split())


def _cell(text: str) -> str:
    """Text for a table cell: its pipes escaped (a code span in a cell must hold none: GitHub and MkDocs read an
    escaped pipe inside one differently)."""
    return text.replace("|", "\\|")


def _arguments_table(parser: argparse.ArgumentParser) -> list[str]:
    lines = []
    for group in parser._action_groups:
        actions = [a for a in group._group_actions
                   if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))]
        if not actions:
            continue
        title = {"positional arguments": "arguments", "optional arguments": "options"}.get(group.title, group.title)
        lines += ["", f"*{title}*", "", "| argument | value | what it does |", "|---|---|---|"]
        for a in actions:
            name = ", ".join(f"`{s}`" for s in a.option_strings) or f"`{a.metavar or a.dest}`"
            value = _value(a) if a.option_strings else ""
            lines.append(f"| {name} | {_cell(f'`{value}`') if value else ''} | {_cell(_help(parser, a))} |")
    return lines


def _command_section(name: str, parser: argparse.ArgumentParser, summary: str, level: int) -> list[str]:
    lines = ["", f"{'#' * level} {name}", ""]
    if summary:
        lines += [f"{summary[0].upper()}{summary[1:]}.", ""]
    lines += ["```text", parser.format_usage().strip(), "```"]
    if parser.description:
        lines += ["", " ".join(parser.description.split())]
    subs = _subcommands(parser)
    lines += _arguments_table(parser)
    for sub_name, sub, sub_help in subs:
        lines += _command_section(f"{name} {sub_name}", sub, sub_help, level + 1)
    return lines


def cli_reference() -> str:
    """The CLI reference page, from the parser ``mvsformerpp`` builds."""
    columns = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"  # a fixed width for the usage lines, whatever the terminal
    try:
        parser = build_parser()
        lines = ["# Command-line reference", "",
                 "<!-- generated by tools/docs_hooks.py --write: edit the parser or the config dataclasses -->", "",
                 "Generated from the parser the `mvsformerpp` command itself builds, so it matches "
                 "`mvsformerpp COMMAND --help` (most flags come from the fields of the configuration dataclasses: "
                 "their type, default and docstring; the site does not build while this page is out of date). "
                 "Training settings that have no flag of their own are set with `train --set key=value` or in a "
                 "recipe file: [TrainConfig](train-config.md).",
                 "", "```text", parser.format_usage().strip(), "```"]
        lines += [f"- [`{name}`](#{name.replace(' ', '-')}): {summary}" for name, _, summary in _subcommands(parser)]
        for name, sub, summary in _subcommands(parser):
            lines += _command_section(name, sub, summary, 2)
    finally:
        if columns is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = columns
    return "\n".join(lines) + "\n"


# ---- the training configuration ----------------------------------------------------------------------------


def _type_name(tp) -> str:
    if typing.get_origin(tp) is typing.Literal:
        return " or ".join(f"`{a}`" for a in typing.get_args(tp))
    text = str(tp).replace("typing.", "")
    text = re.sub(r"<class '([\w.]+)'>", r"\1", text)
    return f"`{text.replace('NoneType', 'None').replace(' | ', ' or ')}`"


def _yaml_value(value) -> str:
    if isinstance(value, tuple):
        return "[" + ", ".join(_yaml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_yaml_value(v)}" for k, v in value.items()) + "}"
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    return str(value)


def _sections(cls: type) -> dict[str, str]:
    """The ``# ---- title`` comment above each field of ``cls``'s source, by the first field under it."""
    out, title = {}, None
    for line in inspect.getsource(cls).splitlines():
        m = re.match(r"\s+# ---- (.+)$", line)
        if m:
            title = m.group(1).strip()
            continue
        m = re.match(r"\s+(\w+): ", line)
        if m and title:
            out[m.group(1)] = title
            title = None
    return out


def train_config_reference() -> str:
    """The TrainConfig page: every field, its type, what it does and its value in each recipe."""
    docs, hints, sections = field_docs(TrainConfig), typing.get_type_hints(TrainConfig), _sections(TrainConfig)
    recipes = list(RECIPES)
    lines = ["# Training configuration (`TrainConfig`)", "",
             "<!-- generated by tools/docs_hooks.py --write: edit mvsformerpp/training/config.py -->", "",
             "Generated from `mvsformerpp.training.config.TrainConfig`. A training run is "
             "one of these: a recipe (`mvsformerpp train synthetic|dtu|blended_finetune`), or a YAML file with any "
             "of the fields below (`recipe: NAME` picks the base), then the command's flags and any number of "
             "`--set key=value` (the value in YAML). The resolved config is saved as `RUN_DIR/config.yaml`. "
             "The columns on the right give each recipe's value.", ""]
    header = "| field | type | what it does | " + " | ".join(f"`{r}`" for r in recipes) + " |"
    rule = "|---|---|---|" + "---|" * len(recipes)
    for f in dataclasses.fields(TrainConfig):
        if f.name in sections:
            lines += ["", f"## {sections[f.name][0].upper()}{sections[f.name][1:]}", "", header, rule]
        doc = " ".join(docs.get(f.name, "").split())
        doc = re.sub(r":\w+:`~?([^`]+)`", r"`\1`", doc).replace("``", "`")
        values = " | ".join(_cell(f"`{_yaml_value(getattr(RECIPES[r], f.name))}`") for r in recipes)
        lines.append(f"| `{f.name}` | {_cell(_type_name(hints[f.name]))} | {_cell(doc)} | {values} |")
    return "\n".join(lines) + "\n"


# ---- lab notes ----------------------------------------------------------------------------------------------


def notes_list(notes_dir: Path) -> list[str]:
    """One line per lab note of ``notes_dir`` (``YYYY-MM-DD-name.md``), newest first: date and title."""
    rows = []
    for path in sorted(notes_dir.glob("*.md"), reverse=True):
        m = NOTE_NAME.match(path.name)
        if not m:
            continue
        title = next((line[2:].strip() for line in path.read_text().splitlines() if line.startswith("# ")),
                     path.stem)
        rows.append(f"- {m.group(1)}: [{title}]({path.name})")
    return rows


# ---- writing and checking ----------------------------------------------------------------------------------


def stale_pages(docs: Path = DOCS) -> list[str]:
    """The generated pages under ``docs`` whose text differs from what the code generates now."""
    return [uri for uri, fn in GENERATED.items()
            if not (docs / uri).is_file() or (docs / uri).read_text() != globals()[fn]()]


def write_pages(docs: Path = DOCS) -> None:
    for uri, fn in GENERATED.items():
        (docs / uri).parent.mkdir(parents=True, exist_ok=True)
        (docs / uri).write_text(globals()[fn]())
        print(f"wrote docs/{uri}")


# ---- the MkDocs events --------------------------------------------------------------------------------------


def on_files(files, config):
    """A warning (an error under --strict) for each generated page that is out of date."""
    for uri in stale_pages(Path(config["docs_dir"])):
        logging.getLogger("mkdocs.hooks.docs_hooks").warning(
            f"docs/{uri} is out of date with the code: run python tools/docs_hooks.py --write")
    return files


def on_page_markdown(markdown, page, config, files):
    """The notes index gains the list of every note, where its text says ``<!-- notes -->``."""
    if page.file.src_uri == "notes/index.md":
        listing = "\n".join(notes_list(Path(config["docs_dir"]) / "notes"))
        markdown = markdown.replace("<!-- notes -->", listing)
    return markdown


if __name__ == "__main__":
    if sys.argv[1:] == ["--write"]:
        write_pages()
    elif sys.argv[1:] == ["--check"]:
        stale = stale_pages()
        for uri in stale:
            print(f"docs/{uri} is out of date: run python tools/docs_hooks.py --write")
        sys.exit(1 if stale else 0)
    else:
        sys.exit(__doc__)
