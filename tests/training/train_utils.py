"""A tiny synthetic training config shared by the training tests."""

from mvsformerpp.training.config import load_config


def tiny_config(**kw):
    base = dict(height=32, width=64, num_views=3, batch_size=1, max_steps=2, tensorboard=False, progress=False,
                val_samples=1, synthetic_views_per_scene=3, synthetic_train_scenes=4, synthetic_val_scenes=1,
                warmup_steps=1, save_every=1, log_every=1, synthetic_render_scale=1.0)
    base.update(kw)
    return load_config("synthetic", base)


def rendered_views(seed: int, n: int, h: int, w: int):
    """(scene, [(image, depth, K, E world-to-camera 4x4)]) of a synthetic scene rendered at h x w."""
    import numpy as np

    from mvsformerpp.synth import random_scene, render_view

    scene = random_scene(seed, n, h, w)
    out = []
    for cam in scene.cameras:
        image, depth, _ = render_view(scene, cam)
        E = np.eye(4)
        E[:3, :3], E[:3, 3] = cam.R, cam.t
        out.append((image, depth, cam.K.copy(), E))
    return scene, out
