"""mvsformerpp: MVSFormer++ multi-view stereo on CPU and GPU.

``import mvsformerpp`` stays light: the network (and torch) load on first use of these names.
``reconstruct(INPUT, OUT, ReconstructConfig(...))`` is the ``mvsformerpp reconstruct`` command (same
defaults); ``load_default_model()`` the shipped weights, ``default_fusion_conf(method)`` the fusion
threshold calibrated for them, ``sample_scene_path()`` the bundled Middlebury temple.
"""

__version__ = "0.1.0"

_LAZY = {
    "build_model": "mvsformerpp.models",
    "load_checkpoint": "mvsformerpp.models",
    "save_checkpoint": "mvsformerpp.models",
    "load_model": "mvsformerpp.models",
    "MVSFormerPP": "mvsformerpp.models",
    "ModelConfig": "mvsformerpp.models",
    "Scene": "mvsformerpp.io.scene",
    "View": "mvsformerpp.io.scene",
    "load_scene": "mvsformerpp.io",
    "reconstruct": "mvsformerpp.pipelines.reconstruct",
    "ReconstructConfig": "mvsformerpp.pipelines.reconstruct",
    "fuse": "mvsformerpp.pipelines.fuse",
    # the shipped default weights and the bundled sample scene
    "load_default_model": ("mvsformerpp.models.shipped", "load_shipped"),
    "default_weights_path": ("mvsformerpp.models.shipped", "shipped_weights_path"),
    "default_fusion_conf": ("mvsformerpp.models.shipped", "calibrated_conf"),
    "sample_scene_path": ("mvsformerpp.io.middlebury", "temple_dir"),
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name] if isinstance(_LAZY[name], tuple) else (_LAZY[name], name)
        return getattr(importlib.import_module(module), attr)
    raise AttributeError(f"module 'mvsformerpp' has no attribute {name!r}")
