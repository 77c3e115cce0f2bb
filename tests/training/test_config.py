"""Training config: recipes, YAML round trip, --set overrides, resume differences."""

import dataclasses

import pytest
import yaml

from mvsformerpp.errors import InputError
from mvsformerpp.training.config import (
    DTU_RESOLUTIONS,
    RECIPES,
    TrainConfig,
    config_differences,
    dump_config,
    load_config,
    parse_overrides,
)


def test_every_field_has_a_docstring():
    import inspect

    src = inspect.getsource(TrainConfig)
    for f in dataclasses.fields(TrainConfig):
        line = next(i for i, s in enumerate(src.splitlines()) if s.strip().startswith(f"{f.name}:"))
        assert src.splitlines()[line + 1].strip().startswith('"""'), f.name


def test_recipes_follow_the_reference():
    dtu = RECIPES["dtu"]
    assert (dtu.lr, dtu.warmup_steps, dtu.min_lr_ratio, dtu.epochs, dtu.batch_size) == (1e-3, 500, 0.01, 15, 16)
    assert (dtu.num_views, dtu.num_depth, dtu.interval_scale, dtu.weight_decay) == (5, 192, 1.06, 0.0)
    assert len(DTU_RESOLUTIONS) == 25 and DTU_RESOLUTIONS[0] == (512, 640) and DTU_RESOLUTIONS[-1] == (1024, 1280)
    # the mean token count of the 25 scales is the n_train of adaptive attention scaling
    assert sum((h // 8) * (w // 8) for h, w in DTU_RESOLUTIONS) / 25 == pytest.approx(12185.6)
    ft = RECIPES["blended_finetune"]
    assert (ft.lr, ft.min_lr_ratio, ft.epochs, ft.preset) == (1e-4, 0.005, 10, "paper_finetune")


def test_yaml_round_trip_and_overrides(tmp_path):
    cfg = load_config("synthetic", parse_overrides(["lr=1e-4", "loss_weights=[0,0,0,1]", "resolutions=[[64,96]]",
                                                    "max_steps=7", "init_checkpoint=null"]))
    assert cfg.lr == 1e-4 and cfg.loss_weights == (0.0, 0.0, 0.0, 1.0) and cfg.resolutions == ((64, 96),)
    assert cfg.max_steps == 7 and cfg.init_checkpoint is None
    path = tmp_path / "run.yaml"
    path.write_text(dump_config(cfg))
    assert load_config(str(path)) == cfg
    path.write_text(yaml.safe_dump({"recipe": "dtu", "lr": 0.5}))
    loaded = load_config(str(path))
    assert loaded.lr == 0.5 and loaded.batch_size == RECIPES["dtu"].batch_size


def test_random_placement_reaches_stage_1s_transformer():
    """``cvt_random_placement`` (a YAML boolean) switches the training model's stage-1 transformer to
    random token-grid placements; by default it trains as the reference."""
    from mvsformerpp.training.trainer import build_training_model

    cfg = load_config("synthetic", parse_overrides(["cvt_random_placement=true", "xavier_init=false"]))
    assert cfg.cvt_random_placement is True
    assert build_training_model(cfg).fusions[0].cost_reg.random_placement is True
    cfg = load_config("synthetic", parse_overrides(["xavier_init=false"]))
    assert build_training_model(cfg).fusions[0].cost_reg.random_placement is False


def test_placement_average_reaches_stage_1s_transformer_and_excludes_random_placement():
    """``cvt_train_shifts`` makes the training model's stage-1 transformer average the preset's placements
    (the lite preset's two); asking for random placements as well is refused."""
    from mvsformerpp.training.trainer import build_training_model

    cfg = load_config("synthetic", parse_overrides(["cvt_train_shifts=true", "xavier_init=false"]))
    cvt = build_training_model(cfg).fusions[0].cost_reg
    assert cvt.average_in_training is True and cvt.shifts == 2
    cfg = load_config("synthetic", parse_overrides(["xavier_init=false"]))
    assert build_training_model(cfg).fusions[0].cost_reg.average_in_training is False
    with pytest.raises(InputError, match="set at most one of them true"):
        load_config("synthetic", parse_overrides(["cvt_train_shifts=true", "cvt_random_placement=true"]))


@pytest.mark.parametrize("item,match", [("nosuchfield=1", "unknown training config keys"),
                                        ("lr=fast", "needs a number"), ("precision=fp8", "must be one of"),
                                        ("loss_weights=[1,2]", "needs 4 values"), ("lr", "key=value")])
def test_bad_overrides_say_what_is_wrong(item, match):
    with pytest.raises(InputError, match=match):
        load_config("synthetic", parse_overrides([item]))


def test_differences_ignore_fields_that_do_not_change_the_trajectory():
    a = RECIPES["synthetic"]
    b = dataclasses.replace(a, lr=0.5, num_workers=3, save_every=9)
    assert config_differences(a, b) == ["lr: 0.001 -> 0.5"]


def test_finetune_preset_and_recipe_loss_weights():
    from mvsformerpp.models.presets import get_config

    assert get_config("paper").loss_weights == (1.0, 1.0, 1.0, 1.0)
    assert get_config("paper_finetune").loss_weights == (0.0, 0.0, 0.0, 1.0)  # the reference's fine-tune loss
    assert RECIPES["blended_finetune"].loss_weights == (1.0, 1.0, 1.0, 1.0)
    assert load_config("blended_finetune", {"loss_weights": None}).loss_weights is None  # -> the preset's


def test_micro_batch_by_height():
    from mvsformerpp.training.trainer import micro_batch_for

    dtu = RECIPES["dtu"]
    assert micro_batch_for(dtu, 704, 4) == 4 and micro_batch_for(dtu, 768, 4) == 2
    assert micro_batch_for(RECIPES["synthetic"], 128, 4) == 4


@pytest.mark.parametrize("over,match", [({"height": 64, "width": 80}, r"64x80 \(height/width\) must be .*64x96"),
                                        ({"resolutions": [[64, 96], [100, 128]]}, "100x128"),
                                        ({"num_views": 1}, "num_views"), ({"save_every": 0}, "save_every")])
def test_unusable_values_are_rejected(over, match):
    with pytest.raises(InputError, match=match):
        load_config("synthetic", over)


def test_train_refuses_a_users_folder_its_own_recipe_and_a_busy_run(tmp_path, capsys):
    from mvsformerpp.cli import main
    from mvsformerpp.utils.output_guard import folder_lock

    exp = tmp_path / "exp"
    exp.mkdir()
    recipe = exp / "config.yaml"
    recipe.write_text("# my recipe\nrecipe: synthetic\nheight: 64\nwidth: 96\n")
    (exp / "notes.txt").write_text("mine\n")
    assert main(["train", str(recipe), "-o", str(exp), "--max-steps", "1"]) == 2
    assert "holds the input" in capsys.readouterr().err
    assert recipe.read_text().startswith("# my recipe") and (exp / "notes.txt").read_text() == "mine\n"
    assert main(["train", "synthetic", "-o", str(exp), "--max-steps", "1"]) == 2
    assert "not empty" in capsys.readouterr().err
    busy = tmp_path / "busy"
    busy.mkdir()
    with folder_lock(busy):
        assert main(["train", "synthetic", "-o", str(busy), "--max-steps", "1"]) == 2
    assert "another mvsformerpp run" in capsys.readouterr().err


def test_every_recipe_trains_on_the_best_device_present(capsys):
    """No recipe fails on a machine without CUDA: the default device is auto, and it says what it chose."""
    import torch

    from mvsformerpp.training.distributed import init_distributed

    assert {r.device for r in RECIPES.values()} == {"auto"} and TrainConfig().device == "auto"
    info = init_distributed("auto")
    expect = "cuda" if torch.cuda.is_available() else "cpu"
    assert info.device.type == expect
    assert f"train: device {expect} (--device auto" in capsys.readouterr().out
