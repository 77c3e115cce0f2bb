"""Error colours and the optional plotting dependency."""

import sys

import numpy as np
import pytest

from mvsformerpp.errors import MissingDependencyError
from mvsformerpp.evaluation import error_colors, plot_pr_curves, write_error_ply
from mvsformerpp.io.ply import ply_colors, read_ply


def test_error_colors_ramp_and_ply(tmp_path):
    c = error_colors(np.array([0.0, 0.5, 1.0, 7.0, 0.125]), 1.0)
    np.testing.assert_array_equal(c[:4], [[0, 0, 255], [0, 255, 0], [255, 0, 0], [255, 0, 0]])
    np.testing.assert_array_equal(c[4], [0, 128, 255])  # halfway blue -> cyan
    pts = np.arange(15, dtype=float).reshape(5, 3)
    write_error_ply(tmp_path / "e.ply", pts, np.array([0.0, 0.5, 1.0, 7.0, 0.125]), 1.0)
    v = read_ply(tmp_path / "e.ply")
    np.testing.assert_array_equal(ply_colors(v), c)
    np.testing.assert_allclose(v["error"], [0.0, 0.5, 1.0, 7.0, 0.125])


def test_plot_without_matplotlib_names_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import now fails as if not installed
    curve = {k: np.array([0.5]) for k in ("thresholds", "precision", "recall", "f_score")}
    with pytest.raises(MissingDependencyError, match=r"mvsformerpp\[plot\]"):
        plot_pr_curves(tmp_path / "c.png", curve)
    assert not (tmp_path / "c.png").exists()


def test_plots_are_written_when_matplotlib_is_present(tmp_path):
    pytest.importorskip("matplotlib")
    from mvsformerpp.evaluation import plot_per_scan

    curve = {"thresholds": np.linspace(0.1, 1, 5), "precision": np.linspace(0, 1, 5),
             "recall": np.linspace(0, 0.5, 5), "f_score": np.linspace(0, 0.6, 5)}
    plot_pr_curves(tmp_path / "c.png", curve, threshold=0.5)
    plot_per_scan(tmp_path / "b.png", ["1", "4"], {"accuracy": [0.3, 0.4], "overall": [0.3, 0.35]})
    assert (tmp_path / "c.png").read_bytes()[:4] == b"\x89PNG"
    assert (tmp_path / "b.png").stat().st_size > 1000
