"""Training and validation data: one dataset base, data sources (synthetic, DTU, BlendedMVS),
multi-scale batch sampling and the training transforms."""

from mvsformerpp.data.base import MVSDataset, SampleKey, ViewData, ViewSet
from mvsformerpp.data.samplers import MultiScaleBatchSampler
from mvsformerpp.data.synthetic import SyntheticDataset
from mvsformerpp.data.transforms import PhotometricAugment, ResizeCrop

__all__ = ["MVSDataset", "MultiScaleBatchSampler", "PhotometricAugment", "ResizeCrop", "SampleKey",
           "SyntheticDataset", "ViewData", "ViewSet"]
