"""Checkpoint loading: official layouts, pickled foreign objects, DINOv2 backbone files, safetensors."""

import contextlib
import os
import pickle
import struct
import subprocess
import sys
import textwrap
import zipfile

import pytest
import torch

import mvsformerpp
from mvsformerpp.errors import InputError
from mvsformerpp.models import build_model, load_checkpoint, load_model, save_checkpoint
from mvsformerpp.models.checkpoint import convert_state_dict


@pytest.fixture(scope="module")
def lite():
    torch.manual_seed(0)
    return build_model("lite")


def _perturbed(model):
    return {k: (v + 1 if v.is_floating_point() else v) for k, v in model.state_dict().items()}


def test_convert_state_dict_handles_official_wrappers():
    t = torch.zeros(2)
    official = {"state_dict": {"module.encoder.x": t, "module.FMT_module.FMT.pos_encoding.pe_dict.8-10": t},
                "epoch": 3}
    assert list(convert_state_dict(official)) == ["encoder.x"]
    assert list(convert_state_dict({"blocks.0.norm1.weight": t, "pos_embed": t})) == [
        "vit.blocks.0.norm1.weight", "vit.pos_embed"]
    with pytest.raises(ValueError):
        convert_state_dict({"state_dict": {"a": 1}})


def test_official_checkpoint_with_ddp_prefix_and_pickled_config(tmp_path, lite):
    """The reference trainer pickles its config object; it must load without that class being importable."""
    target = _perturbed(lite)
    moddir = tmp_path / "mods"
    moddir.mkdir()
    (moddir / "parse_config.py").write_text(textwrap.dedent("""
        import logging
        from collections import OrderedDict
        from pathlib import Path

        class ConfigParser:  # the attributes the reference trainer's ConfigParser pickles
            def __init__(self):
                self._config = OrderedDict(arch=OrderedDict(args={"ndepths": [32, 16, 8, 4]}))
                self.resume = Path("saved/models/model_best.pth")
                self._save_dir = Path("saved/models/mvsformer++")
                self.log_levels = {0: logging.WARNING, 1: logging.INFO}
    """))
    path = tmp_path / "model_best.pth"
    script = textwrap.dedent(f"""
        import sys, torch
        sys.path.insert(0, {str(moddir)!r})
        from parse_config import ConfigParser
        sd = torch.load({str(tmp_path / 'sd.pt')!r})
        import numpy as np
        ckpt = {{"arch": "DINOv2MVSNet", "epoch": 9, "config": ConfigParser(), "monitor_best": np.float64(0.25),
                 "state_dict": {{"module." + k: v for k, v in sd.items()}}}}
        ckpt["state_dict"]["module.FMT_module.FMT.pos_encoding.pe_dict.8-10"] = torch.zeros(1)
        torch.save(ckpt, {str(path)!r})
    """)
    torch.save(target, tmp_path / "sd.pt")
    subprocess.run([sys.executable, "-c", script], check=True)
    model = build_model("lite")
    load_checkpoint(model, path)
    for k, v in model.state_dict().items():
        assert torch.equal(v, target[k]), k
    assert "parse_config" not in sys.modules  # nothing foreign was imported


def test_dinov2_backbone_file_loads_into_vit_only(tmp_path, lite):
    model = build_model("lite")
    before = {k: v.clone() for k, v in model.state_dict().items()}
    backbone = {k[len("vit."):]: v + 2 for k, v in lite.state_dict().items() if k.startswith("vit.")}
    torch.save(backbone, tmp_path / "dinov2.pth")
    load_checkpoint(model, tmp_path / "dinov2.pth")
    for k, v in model.state_dict().items():
        if k.startswith("vit."):
            assert torch.equal(v, backbone[k[4:]])
        else:
            assert torch.equal(v, before[k])


def test_safetensors_round_trip_with_config(tmp_path, lite):
    path = save_checkpoint(lite, tmp_path / "w.safetensors")
    again = load_model(path)
    assert again.config == lite.config
    for k, v in lite.state_dict().items():
        assert torch.equal(again.state_dict()[k], v)
    fresh = load_checkpoint(build_model("lite"), path)
    key = "encoder.conv00.conv.weight"
    assert torch.equal(fresh.state_dict()[key], lite.state_dict()[key])


def test_mismatched_checkpoint_lists_keys(tmp_path, lite):
    save_checkpoint(lite, tmp_path / "lite.safetensors")
    with pytest.raises(InputError, match="does not match.*shape mismatches.*vit"):
        load_checkpoint(build_model("lite", vit_dim=96, vit_heads=2, sva_heads=2), tmp_path / "lite.safetensors")
    sd = lite.state_dict()
    sd.pop("encoder.conv00.conv.weight")
    sd["extra.weight"] = torch.zeros(1)
    torch.save(sd, tmp_path / "bad.pth")
    with pytest.raises(InputError, match="missing keys: encoder.conv00.conv.weight.*unexpected keys: extra.weight"):
        load_checkpoint(build_model("lite"), tmp_path / "bad.pth")
    (tmp_path / "junk.pth").write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="cannot read"):
        load_checkpoint(build_model("lite"), tmp_path / "junk.pth")
    with pytest.raises(InputError, match="not found"):
        load_checkpoint(build_model("lite"), tmp_path / "none.pth")


def test_package_exports_are_lazy():
    code = "import sys, mvsformerpp; assert 'torch' not in sys.modules; mvsformerpp.build_model; print('ok')"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.stdout.strip() == "ok", out.stderr
    assert mvsformerpp.build_model is build_model


# ------------------------------------------------------------------------ crafted checkpoints
# Each payload creates a marker file when unpickled by a loader that resolves what it names; the
# test first proves the payload is live (plain pickle / torch.load(weights_only=False) in a child
# process), then that load_checkpoint refuses it, naming the file, without running it.

def _unicode(text: str) -> bytes:
    data = text.encode()
    return pickle.BINUNICODE + struct.pack("<I", len(data)) + data


def _dotted_global_pickle(code: str, stack_global: bool) -> bytes:
    """Protocol 4: ``torch._utils`` + ``_rebuild_tensor_v2.__builtins__.get`` walks to ``eval``."""
    module, name = "torch._utils", "_rebuild_tensor_v2.__builtins__.get"
    head = (_unicode(module) + _unicode(name) + pickle.STACK_GLOBAL if stack_global
            else pickle.GLOBAL + f"{module}\n{name}\n".encode())
    return (pickle.PROTO + b"\x04" + head + _unicode("eval") + pickle.TUPLE1 + pickle.REDUCE
            + _unicode(code) + pickle.TUPLE1 + pickle.REDUCE + pickle.STOP)


def _torch_zip_with_pickle(path, data_pkl: bytes) -> None:
    """A real torch zip checkpoint whose data.pkl is replaced by ``data_pkl``."""
    torch.save({"state_dict": {"w": torch.zeros(2)}}, path)
    with zipfile.ZipFile(path) as z:
        entries = {info.filename: z.read(info) for info in z.infolist()}
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as z:
        for name, data in entries.items():
            z.writestr(name, data_pkl if name.endswith("/data.pkl") else data)


class _System:
    def __init__(self, command):
        self.command = command

    def __reduce__(self):
        return os.system, (self.command,)


def _crafted(kind: str, path, marker) -> None:
    code = f"open({str(marker)!r}, 'w').close()"
    if kind == "reduce":  # a plain pickle calling os.system
        path.write_bytes(pickle.dumps(_System(f"touch '{marker}'"), protocol=2))
    elif kind == "reduce_in_official_layout":  # valid weights plus a pickled os.system call as 'config'
        torch.save({"state_dict": {"w": torch.zeros(2)}, "config": _System(f"touch '{marker}'")}, path)
    elif kind == "zip_stack_global_dotted":
        _torch_zip_with_pickle(path, _dotted_global_pickle(code, stack_global=True))
    elif kind == "zip_global_dotted":
        _torch_zip_with_pickle(path, _dotted_global_pickle(code, stack_global=False))
    elif kind == "raw_dotted":
        path.write_bytes(_dotted_global_pickle(code, stack_global=True))
    elif kind == "config_name_dotted":  # an allowed record name with an attribute path appended
        data = (pickle.PROTO + b"\x02" + pickle.GLOBAL + b"parse_config.ConfigParser.__init__.__builtins__.get\n"
                + _unicode("eval") + pickle.TUPLE1 + pickle.REDUCE + _unicode(code) + pickle.TUPLE1
                + pickle.REDUCE + pickle.STOP)
        _torch_zip_with_pickle(path, data)


CRAFTED = ["reduce", "reduce_in_official_layout", "zip_stack_global_dotted", "zip_global_dotted", "raw_dotted",
           "config_name_dotted"]


@pytest.mark.parametrize("kind", CRAFTED)
def test_crafted_checkpoint_never_runs_code(tmp_path, kind):
    path, marker = tmp_path / f"{kind}.pth", tmp_path / "pwned"
    _crafted(kind, path, marker)
    if kind != "config_name_dotted":  # the payload is live: an unrestricted load runs it (it only creates marker)
        try:
            torch.load(path, weights_only=False)
        except Exception:
            with open(path, "rb") as f, contextlib.suppress(Exception):
                pickle.load(f)
        assert marker.exists(), "the crafted payload did not run even unrestricted"
        marker.unlink()
    with pytest.raises(InputError) as err:
        load_checkpoint(build_model("lite"), path)
    assert not marker.exists()
    msg = str(err.value)
    assert msg.startswith(str(path)) and "\n" not in msg
    assert "refusing to load" in msg or "cannot read" in msg


def test_safetensors_files_are_byte_identical_for_equal_content(tmp_path):
    """Same tensors and metadata, any insertion order, any process: the same bytes, readable by safetensors."""
    import subprocess
    import sys

    from safetensors import safe_open

    from mvsformerpp.models.checkpoint import safetensors_bytes

    g = torch.Generator().manual_seed(0)
    tensors = {"w": torch.randn(3, 4, generator=g), "b16": torch.randn(5, generator=g).bfloat16(),
               "h": torch.randn(2, 2, generator=g).half(), "n": torch.arange(7), "flag": torch.tensor([True, False]),
               "empty": torch.zeros(0, 3), "scalar": torch.tensor(2.5, dtype=torch.float64),
               "u": torch.arange(4).byte()}
    meta = {f"key{i}": str(i) for i in range(12)}
    data = safetensors_bytes(tensors, meta)
    assert data == safetensors_bytes(dict(reversed(tensors.items())), dict(reversed(meta.items())))
    (tmp_path / "a.safetensors").write_bytes(data)
    with safe_open(str(tmp_path / "a.safetensors"), framework="pt") as f:
        assert f.metadata() == meta and set(f.keys()) == set(tensors)
        for k, v in tensors.items():
            assert f.get_tensor(k).dtype == v.dtype and torch.equal(f.get_tensor(k), v), k
    code = ("import sys, torch; from mvsformerpp.models.checkpoint import safetensors_bytes; "
            "sys.stdout.buffer.write(safetensors_bytes({'a': torch.ones(3)}, {f'k{i}': 'v' for i in range(9)}))")
    runs = [subprocess.run([sys.executable, "-c", code], capture_output=True, check=True).stdout for _ in range(2)]
    assert runs[0] == runs[1] == safetensors_bytes({"a": torch.ones(3)}, {f"k{i}": "v" for i in range(9)})
