"""The shared autocast helper: fp32 and auto run plain, bf16 autocasts, unknown names are refused."""

from __future__ import annotations

import pytest
import torch

from mvsformerpp.utils.precision import PRECISIONS, autocast, check_precision


def test_autocast_dtypes():
    a = torch.ones(4, 4)
    with autocast("cpu", "fp32"):
        assert (a @ a).dtype == torch.float32
    with autocast(torch.device("cpu"), "bf16"):
        assert (a @ a).dtype == torch.bfloat16
    with autocast("cpu", "auto"):  # fp32 under no autocast; only the stage-1 attention may take bf16
        assert (a @ a).dtype == torch.float32
    assert sorted(PRECISIONS) == ["auto", "bf16", "fp16", "fp32"]


def test_unknown_precision_refused():
    with pytest.raises(ValueError, match="precision must be one of"):
        check_precision("fp8")
    with pytest.raises(ValueError, match="fp64"):
        autocast("cpu", "fp64")
