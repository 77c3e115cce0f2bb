"""Meshes of exact synthetic depth maps lie on the true surface (precision and recall against GT points)."""

import numpy as np
import pytest

from mvsformerpp.cli import main
from mvsformerpp.errors import InputError
from mvsformerpp.evaluation.cloud import evaluate_clouds
from mvsformerpp.io.mvsnet import load_mvsnet_scene
from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.io.ply import ply_colors, ply_points, read_ply, read_ply_faces

pytest.importorskip("skimage", reason="the mesh extra (scikit-image) is not installed")


@pytest.fixture
def exact_run(exact_synth_run):
    return exact_synth_run


def surface_samples(vertices, faces, n, seed=0):
    """Area-weighted random points on the triangles."""
    a, b, c = (vertices[faces[:, k]].astype(np.float64) for k in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(faces), n, p=area / area.sum())
    r1, r2 = rng.random((2, n, 1))
    s = np.sqrt(r1)
    return (1 - s) * a[pick] + s * (1 - r2) * b[pick] + s * r2 * c[pick]


def scene_depth(run):
    return float(np.median(np.concatenate([read_pfm(p)[read_pfm(p) > 0] for p in (run / "depth_est").glob("*.pfm")])))


def mesh_quality(run, ply):
    verts = ply_points(read_ply(ply))
    faces = read_ply_faces(ply)
    gt = ply_points(read_ply(run.parent / "scene" / "gt_surface.ply"))
    pred = surface_samples(verts, faces, 100_000)
    return evaluate_clouds(pred, gt, 0.01 * scene_depth(run)), verts, faces


def test_tsdf_mesh_lies_on_the_true_surface(exact_run, tmp_path):
    out = tmp_path / "tsdf.ply"
    assert main(["mesh", str(exact_run), "-o", str(out), "--resolution", "200", "--quiet"]) == 0
    m, verts, faces = mesh_quality(exact_run, out)
    assert m.precision >= 0.9 and m.recall >= 0.9, m
    # faces turn their front to the cameras (marching cubes winding: towards free space)
    a, b, c = (verts[faces[:, k]] for k in range(3))
    n = np.cross(b - a, c - a)
    centres = np.stack([v.center for v in load_mvsnet_scene(exact_run).views])
    assert ((n * (centres.mean(0) - (a + b + c) / 3)).sum(1) > 0).mean() > 0.9
    colors = ply_colors(read_ply(out))
    assert colors is not None and colors.std() > 10


def test_poisson_watertight_closed_object():
    pytest.importorskip("pymeshlab", reason="the mesh extra (pymeshlab) is not installed")
    from mvsformerpp.meshing.poisson import PoissonConfig, screened_poisson

    rng = np.random.default_rng(0)
    n = rng.normal(size=(20_000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    centre = np.array([1.0, -2.0, 5.0])
    mesh = screened_poisson(centre + 2 * n, n, None, PoissonConfig(depth=6, watertight=True))
    edges = np.sort(np.concatenate([mesh.faces[:, [0, 1]], mesh.faces[:, [1, 2]], mesh.faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert len(mesh.faces) > 1000 and (counts == 2).all()  # every edge between two triangles: closed
    radius = np.linalg.norm(mesh.vertices - centre, axis=1)
    assert np.abs(radius - 2).max() < 0.02 * 2


def test_poisson_merges_samples_far_denser_than_its_cells_and_leaves_far_floaters_out():
    pytest.importorskip("pymeshlab", reason="the mesh extra (pymeshlab) is not installed")
    from mvsformerpp.meshing.poisson import PoissonConfig, plan_poisson, screened_poisson

    rng = np.random.default_rng(1)
    n = rng.normal(size=(200_000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    xyz = np.concatenate([2 * n, [[300.0, 0.0, 0.0]] * 50])  # a far cluster would stretch the octree 75 times
    nrm = np.concatenate([n, [[1.0, 0.0, 0.0]] * 50])
    config = PoissonConfig(depth=6, watertight=True)
    plan = plan_poisson(xyz, nrm, config)
    assert not plan.inside[-50:].any() and plan.inside[:-50].all()
    assert plan.thin == pytest.approx(plan.cell / 2) and plan.points < 200_000 / 3
    assert plan.cell == pytest.approx(1.1 * 4 / 2**6, rel=0.01)
    mesh = screened_poisson(xyz, nrm, None, config, plan=plan)
    radius = np.linalg.norm(mesh.vertices, axis=1)
    assert np.abs(radius - 2).max() < plan.cell


def test_poisson_cuts_the_lid_it_invents_over_an_open_bowl_and_the_blobs_around_floaters():
    """An open surface, unevenly sampled and noisy, with clusters of floaters, as fused clouds are: the closed
    Poisson surface adds a lid over the bowl and blobs; the default cut keeps the bowl (every sample
    still has the surface next to it) and nothing else, where a density percentile leaves part of the lid."""
    pytest.importorskip("pymeshlab", reason="the mesh extra (pymeshlab) is not installed")
    from scipy.spatial import cKDTree

    from mvsformerpp.meshing.poisson import PoissonConfig, screened_poisson

    rng = np.random.default_rng(0)
    d = rng.normal(size=(40_000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d[d[:, 2] < 0]  # the lower half of the unit sphere, its normals facing inwards (seen from above)
    d = d[rng.random(len(d)) < np.exp(2.5 * d[:, 2])]  # sparser at the bottom than at the rim
    bowl, normals = d + rng.normal(0, 0.004, d.shape), -d
    centres = rng.uniform(-1.2, 1.2, (40, 3))
    centres = centres[np.abs(np.linalg.norm(centres, axis=1) - 1) > 0.1]
    floaters = (centres[:, None] + rng.normal(0, 0.01, (len(centres), 8, 3))).reshape(-1, 3)
    floater_normals = rng.normal(size=floaters.shape)
    floater_normals /= np.linalg.norm(floater_normals, axis=1, keepdims=True)
    xyz, nrm = np.concatenate([bowl, floaters]), np.concatenate([normals, floater_normals])

    def invented(config):
        mesh = screened_poisson(xyz, nrm, None, config)
        v = mesh.vertices.astype(np.float64)
        off = (np.abs(np.linalg.norm(v, axis=1) - 1) > 0.05) | (v[:, 2] > 0.05)
        recall = float((cKDTree(v).query(bowl)[0] < 0.03).mean())
        return float(off.mean()), recall

    closed, _ = invented(PoissonConfig(depth=7, watertight=True))
    by_density, _ = invented(PoissonConfig(depth=7, max_distance=0, trim=10, min_fragment=0))
    cut, recall = invented(PoissonConfig(depth=7))
    assert closed > 0.05 and by_density > 0.01, (closed, by_density)  # the lid is there to cut
    assert cut < 0.001 and recall > 0.99, (cut, recall)


def test_poisson_mesh_lies_on_the_true_surface(exact_run, tmp_path):
    pytest.importorskip("pymeshlab", reason="the mesh extra (pymeshlab) is not installed")
    out = tmp_path / "poisson.ply"
    assert main(["mesh", str(exact_run), "-o", str(out), "--method", "poisson", "--depth", "8", "--quiet"]) == 0
    m, _, _ = mesh_quality(exact_run, out)
    assert m.precision >= 0.9 and m.recall >= 0.9, m


def test_folders_without_depth_maps_or_cloud(tmp_path, exact_run, capsys):
    from mvsformerpp.pipelines.mesh import make_mesh

    with pytest.raises(InputError, match="mvsformerpp reconstruct INPUT -o OUT"):
        make_mesh(tmp_path, tmp_path / "m.ply")
    assert main(["mesh", str(tmp_path), "-o", str(tmp_path / "m.ply"), "--method", "poisson"]) == 2
    assert "mvsformerpp fuse OUT" in capsys.readouterr().err
    assert not (tmp_path / "m.ply").exists()


def test_a_grid_larger_than_free_memory_is_refused_before_meshing(synth_run, tmp_path, capsys, monkeypatch):
    import mvsformerpp.inference.resolution as resolution

    monkeypatch.setattr(resolution, "available_memory_bytes", lambda device: 2.0 * 2**30)
    assert main(["mesh", str(synth_run), "-o", str(tmp_path / "m.ply"), "--resolution", "1024", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "needs up to 16.0 GB" in err and "2.0 GB free" in err and "at most --resolution 512" in err
    assert not (tmp_path / "m.ply").exists()


def test_poisson_states_its_memory_and_refuses_more_than_is_free(exact_run, tmp_path, capsys, monkeypatch):
    pytest.importorskip("pymeshlab", reason="the mesh extra (pymeshlab) is not installed")
    import mvsformerpp.inference.resolution as resolution

    monkeypatch.setattr(resolution, "available_memory_bytes", lambda device: 0.05 * 2**30)
    out = tmp_path / "m.ply"
    assert main(["mesh", str(exact_run), "-o", str(out), "--method", "poisson", "--depth", "7"]) == 2
    err = capsys.readouterr().err
    assert "needs about" in err and "0.1 GB free" in err and "smaller --depth" in err
    assert not out.exists()
    monkeypatch.setattr(resolution, "available_memory_bytes", lambda device: 8.0 * 2**30)
    assert main(["mesh", str(exact_run), "-o", str(out), "--method", "poisson", "--depth", "7"]) == 0
    said = capsys.readouterr().out
    assert "octree depth 7" in said and "GB" in said.split("octree depth 7")[1].splitlines()[0]


def test_the_default_grid_follows_the_sampling_and_ignores_floaters(exact_run, tmp_path, capsys):
    """Without --voxel/--resolution: voxels of 1.5 pixel footprints over the fused cloud's box, said before
    the integration starts; stray far depths (floaters, sky) neither stretch the box nor end in the mesh's
    extent, and the mesh still lies on the surface."""
    import shutil

    from mvsformerpp.io.pfm import write_pfm
    from mvsformerpp.meshing.tsdf import PIXELS_PER_VOXEL

    shutil.copytree(exact_run.parent, tmp_path / "copy", symlinks=True)  # the run and its scene beside it
    run = tmp_path / "copy" / exact_run.name
    scene = load_mvsnet_scene(run)
    footprints = []
    for i, view in enumerate(scene.views):  # a few far floaters in every depth map
        path = run / "depth_est" / f"{i:08d}.pfm"
        depth = read_pfm(path)
        footprints.append(depth[depth > 0][::8] / (view.K[0, 0] * depth.shape[1] / view.width))
        depth[::7, ::7] = 40.0 * depth.max()  # 2 % of the pixels: more than a robust percentile drops
        write_pfm(path, depth)
    out = tmp_path / "m.ply"
    assert main(["mesh", str(run), "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    line = next(x for x in printed.splitlines() if x.startswith("TSDF: ") and "voxels of" in x)
    voxel = float(line.split("voxels of ")[1].split()[0])
    assert voxel == pytest.approx(PIXELS_PER_VOXEL * np.median(np.concatenate(footprints)), rel=0.05)
    assert "box from the fused cloud" in line and "GB" in line
    m, verts, _ = mesh_quality(run, out)
    gt = ply_points(read_ply(run.parent / "scene" / "gt_surface.ply"))
    assert m.precision >= 0.85 and m.recall >= 0.85, m
    assert (np.ptp(verts, 0) <= 1.2 * np.ptp(gt, 0) + 10 * voxel).all()  # the floaters are outside the grid
