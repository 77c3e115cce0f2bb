"""``demo``: reconstruct the bundled Middlebury temple (16 views, 640x480) end to end.

The data (``mvsformerpp/assets/templeSparseRing``; README.txt there holds the attribution: Seitz,
Diebel, Scharstein, Curless, Szeliski, the Middlebury multi-view stereo benchmark) ships with the
package. The Middlebury reader takes each view's depth range from the bounding box in that README.
"""

from __future__ import annotations

from pathlib import Path

from mvsformerpp.io.middlebury import temple_dir
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig

# The lite network at the photos' own size (640x480; about a minute on a 2-core CPU), five views per depth map,
# dynamic fusion at the confidence threshold calibrated for the shipped weights (docs/model-card.md).
DEMO_CONFIG = ReconstructConfig(preset="lite", max_size=640, num_views=5, fusion="dynamic")


def run_demo(out_dir: str | Path, config: ReconstructConfig = DEMO_CONFIG, quiet: bool = False) -> dict:
    """Reconstruct the bundled temple into ``out_dir``; return the summary (see ``reconstruct``)."""
    from mvsformerpp.pipelines.reconstruct import reconstruct  # needs torch; the command line's parser does not

    return reconstruct(temple_dir(), out_dir, config, quiet=quiet)
