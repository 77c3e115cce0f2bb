"""The `mvsformerpp evaluate` subcommands end to end on small files."""

import json

import numpy as np
import scipy.io

from mvsformerpp.cli import main
from mvsformerpp.evaluation.tnt_submission import write_log
from mvsformerpp.io.pfm import write_pfm
from mvsformerpp.io.ply import read_ply, write_ply


def plane(n=30, step=0.01, z=0.0):
    xs = np.arange(n) * step
    x, y = np.meshgrid(xs, xs, indexing="ij")
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], axis=1)


def test_cloud_json_and_error_ply(tmp_path, capsys):
    write_ply(tmp_path / "gt.ply", plane())
    write_ply(tmp_path / "pred.ply", plane(z=0.002)[:450])
    rc = main(["evaluate", "cloud", str(tmp_path / "pred.ply"), str(tmp_path / "gt.ply"), "--threshold", "0.005",
               "--json", str(tmp_path / "m.json"), "--error-ply", str(tmp_path / "err.ply")])
    assert rc == 0
    out = capsys.readouterr().out
    assert "precision" in out and "f_score" in out
    m = json.loads((tmp_path / "m.json").read_text())
    assert {"precision", "recall", "f_score", "accuracy", "completeness"} <= set(m)
    assert m["precision"] == 1.0 and m["recall"] == 0.5
    assert abs(m["accuracy"] - 0.002) < 1e-6
    assert len(read_ply(tmp_path / "err_precision.ply")["error"]) == 450
    assert len(read_ply(tmp_path / "err_recall.ply")["error"]) == 900


def test_errors_are_one_line(tmp_path, capsys):
    rc = main(["evaluate", "cloud", str(tmp_path / "no.ply"), str(tmp_path / "gt.ply"), "--threshold", "1"])
    assert rc == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and "does not exist" in err and err.count("\n") == 1


def test_dtu_folder_and_depth_and_eth3d(tmp_path, capsys):
    root = tmp_path / "dtu"
    (root / "ObsMask").mkdir(parents=True)
    (root / "Points" / "stl").mkdir(parents=True)
    gt = plane(41, 0.5)
    scipy.io.savemat(root / "ObsMask" / "ObsMask1_10.mat",
                     {"ObsMask": np.ones((30, 30, 10), bool), "BB": np.array([[-5.0, -5, -5], [25, 25, 5]]),
                      "Res": 1.0})
    scipy.io.savemat(root / "ObsMask" / "Plane1.mat", {"P": np.array([[0.0], [0], [1], [1]])})
    write_ply(root / "Points" / "stl" / "stl001_total.ply", gt)
    (tmp_path / "preds").mkdir()
    write_ply(tmp_path / "preds" / "mvsnet001_l3.ply", gt + [0, 0, 0.5])
    rc = main(["evaluate", "dtu", str(tmp_path / "preds"), "--dtu-root", str(root), "--scans", "1",
               "--json", str(tmp_path / "dtu.json"), "--error-ply-dir", str(tmp_path / "err")])
    assert rc == 0
    res = json.loads((tmp_path / "dtu.json").read_text())
    assert abs(res["mean"]["overall"] - 0.5) < 1e-6
    acc_cloud = read_ply(tmp_path / "err" / "scan1_accuracy.ply")
    assert len(acc_cloud["x"]) == res["scans"][0]["num_pred_used"]
    np.testing.assert_allclose(acc_cloud["error"], 0.5, rtol=1e-6)
    write_ply(tmp_path / "preds" / "mvsnet002_l3.ply", gt)
    rc = main(["evaluate", "dtu", str(tmp_path / "preds"), "--dtu-root", str(root), "--scans", "2"])
    assert rc == 2 and "scan 2 has no ground truth" in capsys.readouterr().err
    rc = main(["evaluate", "dtu", str(tmp_path / "preds"), "--dtu-root", str(root), "--scans", "1", "3", "4"])
    err = capsys.readouterr().err
    assert rc == 2 and "no prediction for 2 scan(s): mvsnet003_l3.ply, mvsnet004_l3.ply" in err
    rc = main(["evaluate", "dtu", str(tmp_path / "preds"), "--dtu-root", str(root), "--pattern", "{n}.ply"])
    assert rc == 2 and "bad --pattern" in capsys.readouterr().err

    (tmp_path / "p").mkdir()
    (tmp_path / "g").mkdir()
    write_pfm(tmp_path / "g" / "0.pfm", np.full((3, 3), 100.0, np.float32))
    write_pfm(tmp_path / "p" / "0.pfm", np.full((3, 3), 103.0, np.float32))
    rc = main(["evaluate", "depth", str(tmp_path / "p"), str(tmp_path / "g"), "--json", str(tmp_path / "d.json")])
    d = json.loads((tmp_path / "d.json").read_text())
    assert rc == 0 and abs(d["overall"]["mae"] - 3.0) < 1e-6 and d["overall"]["acc@4"] == 1.0

    write_ply(tmp_path / "g.ply", plane())
    write_ply(tmp_path / "p.ply", plane(z=0.03))
    assert main(["evaluate", "eth3d", str(tmp_path / "p.ply"), str(tmp_path / "g.ply")]) == 0
    assert "50.0" in capsys.readouterr().out


def test_tnt_and_submission(tmp_path, capsys):
    write_ply(tmp_path / "gt.ply", plane())
    write_ply(tmp_path / "pred.ply", plane())
    rc = main(["evaluate", "tnt", str(tmp_path / "pred.ply"), str(tmp_path / "gt.ply"), "--scene", "Barn",
               "--json", str(tmp_path / "t.json")])
    assert rc == 0 and json.loads((tmp_path / "t.json").read_text())["f_score"] == 1.0
    write_log(tmp_path / "Barn.log", np.eye(4)[None].repeat(2, 0))
    rc = main(["evaluate", "tnt-submit", str(tmp_path / "sub"), "Barn", str(tmp_path / "pred.ply"),
               str(tmp_path / "Barn.log")])
    assert rc == 0 and (tmp_path / "sub" / "Barn.log").is_file() and (tmp_path / "sub" / "Barn.ply").is_file()


def test_cloud_plot_option(tmp_path):
    import pytest

    pytest.importorskip("matplotlib")
    write_ply(tmp_path / "gt.ply", plane())
    write_ply(tmp_path / "pred.ply", plane(z=0.002))
    rc = main(["evaluate", "cloud", str(tmp_path / "pred.ply"), str(tmp_path / "gt.ply"), "--threshold", "0.005",
               "--plot", str(tmp_path / "curve.png")])
    assert rc == 0 and (tmp_path / "curve.png").read_bytes()[:4] == b"\x89PNG"


def test_alias_flags_and_bad_submission_items(tmp_path, capsys):
    write_ply(tmp_path / "gt.ply", plane())
    write_ply(tmp_path / "pred.ply", plane(z=0.001))
    np.savetxt(tmp_path / "T.txt", np.eye(4))
    rc = main(["evaluate", "tnt", str(tmp_path / "pred.ply"), str(tmp_path / "gt.ply"), "--threshold", "0.005",
               "--transform", str(tmp_path / "T.txt"), "--error-cloud", str(tmp_path / "e.ply")])
    assert rc == 0 and (tmp_path / "e_precision.ply").is_file()
    rc = main(["evaluate", "tnt-package", str(tmp_path / "sub"), "Barn", str(tmp_path / "pred.ply")])
    assert rc == 2 and "triples" in capsys.readouterr().err


def test_package_from_reconstruct_folder(tmp_path):
    import pytest

    mvsnet = pytest.importorskip("mvsformerpp.io.mvsnet")
    from mvsformerpp.evaluation.tnt_submission import scene_poses

    rec = tmp_path / "rec"
    (rec / "cams").mkdir(parents=True)
    (rec / "images").mkdir()
    from PIL import Image

    for i in range(2):
        Image.new("RGB", (8, 6)).save(rec / "images" / f"{i:08d}.jpg")
        ext = np.eye(4)
        ext[:3, 3] = [i, 0.5, 2.0]
        (rec / "cams" / f"{i:08d}_cam.txt").write_text(
            "extrinsic\n" + "\n".join(" ".join(map(str, r)) for r in ext)
            + "\n\nintrinsic\n4 0 4\n0 4 3\n0 0 1\n\n1 0.1 64 7.4\n")
    (rec / "pair.txt").write_text("2\n0\n1 1 1.0\n1\n1 0 1.0\n")
    write_ply(rec / "fused.ply", plane())
    assert main(["evaluate", "tnt-package", str(tmp_path / "sub"), f"Barn={rec}"]) == 0
    scene = mvsnet.load_mvsnet_scene(rec)
    from mvsformerpp.evaluation import read_log

    np.testing.assert_allclose(read_log(tmp_path / "sub" / "Barn.log"), scene_poses(scene), atol=1e-8)
    assert read_log(tmp_path / "sub" / "Barn.log")[1][0, 3] == -1.0  # camera centre = -R^T t
