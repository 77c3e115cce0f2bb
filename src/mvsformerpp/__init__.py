"""mvsformerpp: MVSFormer++ multi-view stereo on CPU and GPU.

``import mvsformerpp`` stays light: the network (and torch) load on first use of these names.
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
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'mvsformerpp' has no attribute {name!r}")
