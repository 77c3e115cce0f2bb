"""The one reader of RANK / LOCAL_RANK / WORLD_SIZE."""

from __future__ import annotations

import pytest

from mvsformerpp.errors import InputError
from mvsformerpp.utils.distributed import ProcessRank, env_rank


def test_one_process_without_torchrun(monkeypatch):
    for k in ("RANK", "LOCAL_RANK", "WORLD_SIZE"):
        monkeypatch.delenv(k, raising=False)
    r = env_rank()
    assert r == ProcessRank(0, 1, 0) and r.is_main and not r.distributed


def test_a_rank_of_a_job(monkeypatch):
    monkeypatch.setenv("WORLD_SIZE", "4")
    monkeypatch.setenv("RANK", "3")
    monkeypatch.setenv("LOCAL_RANK", "1")
    r = env_rank()
    assert (r.rank, r.world_size, r.local_rank) == (3, 4, 1) and r.distributed and not r.is_main


def test_a_job_without_rank_is_refused(monkeypatch):
    monkeypatch.setenv("WORLD_SIZE", "2")
    monkeypatch.delenv("RANK", raising=False)
    with pytest.raises(InputError, match="RANK is not set"):
        env_rank()
