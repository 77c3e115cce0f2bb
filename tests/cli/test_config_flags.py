"""Every flag of reconstruct, demo and fuse comes from one config field: its type, default and docstring."""

import argparse
import dataclasses
from typing import Literal

import pytest

from mvsformerpp.cli import build_parser
from mvsformerpp.fusion.config import FusionConfig
from mvsformerpp.pipelines.reconstruct_config import FUSION_CHOICES, ReconstructConfig, config_flag
from mvsformerpp.pipelines.sfm import SfMConfig
from mvsformerpp.utils.config_flags import add_config_flags, config_from_args, field_docs, flag_name, plain_text


def subparser(name: str) -> argparse.ArgumentParser:
    parser = build_parser()
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[name]


def test_no_flags_give_the_library_defaults():
    """The command line's defaults are the Python API's: parsing nothing gives ReconstructConfig()."""
    from mvsformerpp.cli.reconstruct import config_from_args as reconstruct_config

    args = subparser("reconstruct").parse_args(["INPUT", "-o", "OUT"])
    assert reconstruct_config(args) == ReconstructConfig()


def test_each_field_is_one_flag_with_its_docstring_as_help():
    actions = {a.dest: a for a in subparser("reconstruct")._actions}
    for cls in (ReconstructConfig, SfMConfig):
        docs = field_docs(cls)
        for f in dataclasses.fields(cls):
            if f.metadata.get("nested") or f.metadata.get("flag", "") is None:
                assert f.name not in actions or cls is SfMConfig and f.name == "overlap"
                continue
            action = actions[f.name]
            assert flag_name(cls, f.name) in action.option_strings
            assert action.help.startswith(plain_text(docs[f.name])[:40].replace("%", "%%")), f.name
            if not isinstance(f.default, tuple):
                assert action.default == f.default, f.name
    assert tuple(actions["fusion"].choices) == FUSION_CHOICES + ("none",)
    assert actions["temperatures"].nargs == 4 and actions["depth_range"].nargs == 2
    assert actions["single_camera"].const is True  # a switch


def test_flags_parse_into_the_config():
    args = subparser("reconstruct").parse_args(
        ["IN", "-o", "OUT", "--views", "4", "--conf", "0.3", "--depth-range", "1", "2", "--temperatures", "4", "4",
         "3", "1", "--single-camera", "--sfm-max-size", "1000", "--fusion", "dtu", "--max-size", "512"])
    from mvsformerpp.cli.reconstruct import config_from_args as reconstruct_config

    cfg = reconstruct_config(args)
    assert (cfg.num_views, cfg.fusion_conf, cfg.depth_range, cfg.temperatures, cfg.fusion, cfg.max_size) == \
        (4, 0.3, (1.0, 2.0), (4.0, 4.0, 3.0, 1.0), "dtu", 512)
    assert cfg.sfm == SfMConfig(single_camera=True, max_image_size=1000)


def test_messages_name_the_flag_the_parser_has():
    flags = set(subparser("reconstruct")._option_string_actions)
    for f in dataclasses.fields(ReconstructConfig):
        name = config_flag(f.name)
        if not name.endswith("(a ReconstructConfig field)"):
            assert all(part in flags for part in name.split("/")), (f.name, name)
    with pytest.raises(Exception, match="^--views must be at least 2"):
        ReconstructConfig(num_views=1)
    with pytest.raises(Exception, match="^--sfm-max-size must be at least 64"):
        SfMConfig(max_image_size=8)
    with pytest.raises(Exception, match="^--disp must be positive"):
        FusionConfig(disp_threshold=0)


def test_fuse_shares_the_flags_of_reconstruct_and_preset_means_the_network():
    """--fusion, --conf, --disp, --num-consistent, --num-src-views, --mask-dir, --device, --memory-gb are the
    same settings in fuse and reconstruct; --preset is the network preset wherever it exists, so fuse has none."""
    fuse, recon = subparser("fuse"), subparser("reconstruct")
    for flag in ("--fusion", "--conf", "--disp", "--num-consistent", "--num-src-views", "--mask-dir", "--device",
                 "--memory-gb"):
        a, b = fuse._option_string_actions[flag], recon._option_string_actions[flag]
        assert (a.dest, a.help, a.choices, a.default) == (b.dest, b.help, b.choices, b.default)
    assert "--preset" not in fuse._option_string_actions
    for name in ("reconstruct", "demo", "train"):
        assert set(subparser(name)._option_string_actions["--preset"].choices) >= {"lite", "paper"}
    assert fuse._option_string_actions["--disp"].default is None  # the preset decides
    assert "(default: the preset's)" in fuse._option_string_actions["--disp"].help


def test_fusion_choices_are_the_fusion_presets():
    from mvsformerpp.fusion.config import PRESETS

    assert set(FUSION_CHOICES) == set(PRESETS)


def test_derived_flags_of_a_small_config():
    """The rules on a dataclass of every kind of field: switch, choices, optional, pair, nested."""

    @dataclasses.dataclass(frozen=True)
    class Inner:
        level: int = dataclasses.field(default=3, metadata={"flag": "--inner-level"})
        """How deep (``levels``, see :func:`mvsformerpp.x.y`)."""

    @dataclasses.dataclass(frozen=True)
    class Outer:
        mode: Literal["a", "b"] = "a"
        """Which mode; 100% sure."""
        fast: bool = False
        """Go fast."""
        size: float | None = None
        """A size."""
        pair: tuple[int, int] = (1, 2)
        """Two numbers."""
        inner: Inner = dataclasses.field(default=Inner(), metadata={"nested": True})
        hidden: int = dataclasses.field(default=7, metadata={"flag": None})

    p = argparse.ArgumentParser()
    add_config_flags(p, Outer)
    helps = {a.dest: a.help for a in p._actions}
    assert helps["level"] == "How deep (levels, see mvsformerpp.x.y). (default: 3)"
    assert helps["mode"] == "Which mode; 100%% sure. (default: a)"
    assert "hidden" not in helps
    got = config_from_args(Outer, p.parse_args(["--mode", "b", "--fast", "--size", "2.5", "--pair", "3", "4",
                                                "--inner-level", "5"]))
    assert got == Outer(mode="b", fast=True, size=2.5, pair=(3, 4), inner=Inner(level=5))
    assert config_from_args(Outer, p.parse_args([])) == Outer()
    with pytest.raises(SystemExit):
        p.parse_args(["--mode", "c"])
