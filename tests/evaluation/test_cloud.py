"""Generic cloud metrics against analytic values on a sampled plane, and brute force."""

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.evaluation import cloud_distances, evaluate_cloud_files, evaluate_clouds, load_cloud, nearest_distances
from mvsformerpp.evaluation.cloud import f_score
from mvsformerpp.io.ply import write_ply


def grid(n: int, step: float, z: float = 0.0) -> np.ndarray:
    """[n*n,3] points of the plane z=const on a square grid; column index = x / step."""
    xs = np.arange(n) * step
    x, y = np.meshgrid(xs, xs, indexing="ij")
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], axis=1)


def test_nearest_distances_match_brute_force():
    rng = np.random.default_rng(0)
    q, r = rng.normal(size=(300, 3)), rng.normal(size=(200, 3))
    brute = cdist(q, r).min(axis=1)
    np.testing.assert_allclose(nearest_distances(q, r, chunk=37), brute, rtol=1e-12)
    np.testing.assert_allclose(nearest_distances(q, r, max_dist=0.2, chunk=50), np.minimum(brute, 0.2), rtol=1e-12)


def test_offset_outliers_and_hole_match_analytic_values():
    n, step, delta, tau = 60, 0.01, 0.004, 0.005
    gt = grid(n, step)
    # Prediction: the plane lifted by delta, with the columns x >= 40*step cut away (a hole), plus outliers.
    pred = grid(n, step, z=delta)
    cols = np.round(pred[:, 0] / step).astype(int)
    pred = pred[cols < 40]
    outliers = grid(10, step, z=1.0)  # 100 points, exactly 1.0 above a GT point
    pred = np.concatenate([pred, outliers])
    m = evaluate_clouds(pred, gt, tau)

    n_in = 40 * n
    assert m.precision == pytest.approx(n_in / (n_in + 100))
    assert m.accuracy == pytest.approx((n_in * delta + 100 * 1.0) / (n_in + 100))
    # Each GT point in column c >= 40 is sqrt(((c-39) step)^2 + delta^2) from the prediction's last column.
    c = np.arange(n)
    d_col = np.where(c < 40, delta, np.sqrt(((c - 39) * step) ** 2 + delta**2))
    assert m.completeness == pytest.approx(d_col.mean())
    assert m.recall == pytest.approx(np.mean(d_col < tau))
    assert m.recall == pytest.approx(40 / n)  # delta < tau but the hole's first column is 0.0108 away
    assert m.f_score == pytest.approx(f_score(m.precision, m.recall))
    assert (m.num_pred, m.num_gt) == (n_in + 100, n * n)


def test_offset_beyond_threshold_gives_zero():
    gt = grid(20, 0.01)
    m = evaluate_clouds(grid(20, 0.01, z=0.02), gt, 0.01)
    assert (m.precision, m.recall, m.f_score) == (0.0, 0.0, 0.0)
    assert m.accuracy == pytest.approx(0.02)


def test_curve_agrees_with_metrics():
    rng = np.random.default_rng(1)
    dist = cloud_distances(rng.normal(size=(500, 3)), rng.normal(size=(400, 3)))
    ts = np.array([0.05, 0.1, 0.3])
    curve = dist.curve(ts)
    for i, t in enumerate(ts):
        m = dist.metrics(t)
        assert curve["precision"][i] == pytest.approx(m.precision)
        assert curve["recall"][i] == pytest.approx(m.recall)
        assert curve["f_score"][i] == pytest.approx(m.f_score)


def test_files_and_bad_input(tmp_path):
    gt = grid(10, 0.1)
    write_ply(tmp_path / "gt.ply", gt)
    write_ply(tmp_path / "pred.ply", gt + [0, 0, 0.01])
    m = evaluate_cloud_files(tmp_path / "pred.ply", tmp_path / "gt.ply", 0.05)
    assert m.precision == 1.0 and m.accuracy == pytest.approx(0.01, rel=1e-5)

    with pytest.raises(InputError, match="does not exist"):
        load_cloud(tmp_path / "missing.ply")
    write_ply(tmp_path / "empty.ply", np.zeros((0, 3)))
    with pytest.raises(InputError, match="empty"):
        load_cloud(tmp_path / "empty.ply")
    bad = gt.copy()
    bad[3, 1] = np.nan
    write_ply(tmp_path / "nan.ply", bad)
    with pytest.raises(InputError, match="NaN"):
        load_cloud(tmp_path / "nan.ply", "prediction")
    (tmp_path / "noxyz.ply").write_bytes(
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float a\nend_header\n1\n")
    with pytest.raises(FormatError, match="x, y, z"):
        load_cloud(tmp_path / "noxyz.ply")
    with pytest.raises(InputError, match=r"\[N,3\]"):
        evaluate_clouds(np.zeros((4, 2)), gt, 0.1)


def test_gaussian_noise_matches_half_normal_statistics():
    """Noise along the normal only: each distance is exactly |noise|; the means follow the half-normal law."""
    from scipy.stats import norm

    sigma, tau, step = 0.002, 0.003, 0.01  # noise << grid step, so the nearest GT point is straight below
    gt = grid(100, step)
    noise = np.random.default_rng(7).normal(scale=sigma, size=len(gt))
    pred = gt + np.stack([np.zeros_like(noise), np.zeros_like(noise), noise], axis=1)
    m = evaluate_clouds(pred, gt, tau)
    assert m.accuracy == pytest.approx(np.abs(noise).mean(), rel=1e-9)
    assert m.precision == pytest.approx(np.mean(np.abs(noise) < tau))
    assert m.accuracy == pytest.approx(sigma * np.sqrt(2 / np.pi), rel=0.03)  # E|n| of N(0, sigma^2)
    assert m.precision == pytest.approx(2 * norm.cdf(tau / sigma) - 1, abs=0.02)
    assert m.recall == m.precision  # the same pairs, seen from the other side


def test_f_beta_is_the_weighted_harmonic_mean():
    """1/F_beta = (1/P + beta^2/R) / (1 + beta^2): beta 1 is the plain harmonic mean, small beta tends to
    the precision, large beta to the recall, and zero stays zero."""
    p, r = 0.9, 0.3
    assert f_score(p, r) == pytest.approx(2 / (1 / p + 1 / r))
    for beta in (0.25, 0.5, 2.0):
        assert f_score(p, r, beta) == pytest.approx((1 + beta**2) / (1 / p + beta**2 / r))
    assert f_score(p, r, 1e-4) == pytest.approx(p, rel=1e-6)
    assert f_score(p, r, 1e4) == pytest.approx(r, rel=1e-6)
    assert f_score(p, r, 0.5) > f_score(p, r) > f_score(p, r, 2.0)  # precision is the larger here
    assert f_score(0.0, 0.0, 0.5) == 0.0
