"""A tiny synthetic training config shared by the training tests."""

from mvsformerpp.training.config import load_config


def tiny_config(**kw):
    base = dict(height=32, width=64, num_views=3, batch_size=1, max_steps=2, tensorboard=False, progress=False,
                val_samples=1, synthetic_views_per_scene=3, synthetic_train_scenes=4, synthetic_val_scenes=1,
                warmup_steps=1, save_every=1, log_every=1, synthetic_render_scale=1.0)
    base.update(kw)
    return load_config("synthetic", base)
