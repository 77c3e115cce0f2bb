"""Every bad input of ``bad_inputs.CASES``: exit code 2, one clear ``error:`` line, the table in the docs."""

import re
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
import bad_inputs  # noqa: E402


def _doc_rows() -> dict[str, str]:
    rows = {}
    if bad_inputs.DOC.is_file():
        for line in bad_inputs.DOC.read_text().splitlines():
            m = re.match(r"\| `([^`]+)` \|", line)
            if m:
                rows[m.group(1)] = line
    return rows


@pytest.mark.parametrize("case", bad_inputs.CASES, ids=[c.id for c in bad_inputs.CASES])
def test_bad_input_gets_one_clear_line(case, tmp_path):
    if case.needs_no_cuda and torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    rc, err, tb = bad_inputs.run_case(case, tmp_path)
    assert not tb, tb
    assert rc == 2, err
    assert err.startswith("error: ") and err.count("\n") == 1, err
    assert "Traceback" not in err
    message = bad_inputs.normalise(err, tmp_path)
    assert re.search(case.expect, message), message
    assert _doc_rows().get(case.id) == bad_inputs.row(case, message), (
        "docs/bad-inputs.md is out of date: run python tests/cli/bad_inputs.py --write docs/bad-inputs.md")


def test_the_table_lists_every_case_and_only_those():
    ids = [c.id for c in bad_inputs.CASES]
    assert len(ids) == len(set(ids)) >= 40
    assert list(_doc_rows()) == ids
    assert "docs/bad-inputs.md" in (bad_inputs.ROOT / "README.md").read_text()


def test_an_os_error_the_user_can_fix_is_one_line(monkeypatch, capsys, tmp_path):
    import errno

    from mvsformerpp.cli import main

    def denied(*a, **kw):
        raise PermissionError(errno.EACCES, "Permission denied", str(tmp_path / "g.ply"))

    monkeypatch.setattr("mvsformerpp.evaluation.distances.load_cloud", denied)
    assert main(["evaluate", "cloud", "a.ply", "b.ply", "--threshold", "1"]) == 2
    err = capsys.readouterr().err
    assert err == f"error: {tmp_path / 'g.ply'}: Permission denied; check the path and its permissions " \
                  "(finished outputs are kept)\n"
