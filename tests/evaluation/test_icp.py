"""The toolbox's ICP refinement recovers a known similarity misalignment."""

import numpy as np
import pytest

from mvsformerpp.evaluation import evaluate_tnt_points
from mvsformerpp.evaluation.icp import TOOLBOX_SCHEDULE, icp_refine, similarity


def rigid(axis, angle, t):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    T[:3, 3] = t
    return T


def bumpy_blob(n, seed):
    """Points on a bumpy ellipsoid (about 2 x 1.4 x 1): every rotation, shift and scale is observable."""
    u = np.random.default_rng(seed).normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    r = 1 + 0.1 * np.sin(5 * u[:, 0]) * np.cos(4 * u[:, 1]) + 0.05 * np.sin(7 * u[:, 2])
    return u * r[:, None] * np.array([1.0, 0.7, 0.5])


def similarity_transform(axis, angle, t, scale):
    T = rigid(axis, angle, t)
    T[:3, :3] *= scale
    return T


def test_closed_form_similarity_recovers_an_exact_transform():
    src = np.random.default_rng(0).normal(size=(50, 3))
    for scale in (1.0, 0.7, 1.3):
        T = similarity_transform([1, 2, 3], 0.7, [1, -2, 0.5], scale)
        np.testing.assert_allclose(similarity(src, src @ T[:3, :3].T + T[:3, 3]), T, atol=1e-12)
    T = rigid([1, 2, 3], 0.7, [1, -2, 0.5])
    np.testing.assert_allclose(similarity(src, 1.3 * (src @ T[:3, :3].T + T[:3, 3]), with_scale=False)[3], [0, 0, 0, 1])


def test_toolbox_refinement_undoes_a_similarity_misalignment_and_lifts_f_score():
    """A prediction 2% too large, rotated and shifted (as a reconstruction in its own scale would be)
    is brought back by the toolbox's three ICP rounds, scale included."""
    gt = bumpy_blob(40000, 1)
    T_err = similarity_transform([0.3, 1, 0.2], 0.02, [0.01, -0.008, 0.006], 1.02)
    pred = bumpy_blob(30000, 2) @ T_err[:3, :3].T + T_err[:3, 3]
    tau = 0.02
    T = icp_refine(pred, gt, tau)
    np.testing.assert_allclose(T @ T_err, np.eye(4), atol=2e-3)
    assert np.cbrt(np.linalg.det(T[:3, :3])) == pytest.approx(1 / 1.02, abs=1e-3)
    plain = evaluate_tnt_points(pred, gt, tau)
    refined = evaluate_tnt_points(pred, gt, tau, refine=True)
    ideal = evaluate_tnt_points(bumpy_blob(30000, 2), gt, tau)  # the same samples, never misaligned
    assert plain.metrics.f_score < ideal.metrics.f_score - 0.2
    assert refined.metrics.f_score == pytest.approx(ideal.metrics.f_score, abs=0.03)


def test_the_schedule_is_the_toolbox_one():
    assert [(r.voxel, r.max_corr, r.iterations) for r in TOOLBOX_SCHEDULE] == [(1.0, 80.0, 20), (0.5, 20.0, 20),
                                                                                (None, 2.0, 20)]
