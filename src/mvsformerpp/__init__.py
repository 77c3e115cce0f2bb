"""mvsformerpp: MVSFormer++ multi-view stereo on CPU and GPU."""

__version__ = "0.1.0"
