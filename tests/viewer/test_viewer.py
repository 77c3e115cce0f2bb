"""The browser viewer, driven in headless Chromium: the cloud renders, the cameras are counted."""

import shutil
import socket

import numpy as np
import pytest
from PIL import Image

from mvsformerpp.errors import InputError
from mvsformerpp.io.ply import read_ply

pytest.importorskip("viser", reason="the viewer extra (viser) is not installed")

from mvsformerpp.viewer.app import ViewerConfig, start_viewer  # noqa: E402


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_viewer_in_headless_chromium(synth_run, tmp_path, browser_page):
    taken = socket.socket()
    taken.bind(("127.0.0.1", free_port()))
    taken.listen()
    port = taken.getsockname()[1]
    viewer = start_viewer(synth_run, ViewerConfig(port=port, host="127.0.0.1", max_points=20_000))
    try:
        assert viewer.port != port  # the port was taken: the viewer moved on
        total = len(read_ply(synth_run / "fused.ply")["x"])
        assert viewer.cloud.total == total and len(viewer.cloud.xyz) == 20_000
        browser_page.call("Page.navigate", url=viewer.url)
        text = browser_page.wait_for_text("5 cameras")
        assert f"20,000 of {total:,} points shown" in text
        import time

        time.sleep(3)  # let WebGL draw the cloud
        shot = np.asarray(Image.open(browser_page.screenshot(tmp_path / "viewer.png")).convert("RGB")).astype(int)
        assert shot.std() > 15  # not blank
        # the live confidence filter: a stricter threshold shows fewer points, in the page too
        shown = viewer.set_threshold(0.8)
        expected = int((viewer.cloud.confidence >= 0.8).sum())
        assert shown == expected < 20_000
        browser_page.wait_for_text(f"{expected:,} of {total:,} points shown")
    finally:
        viewer.stop()
        taken.close()


def test_viewer_needs_a_cloud(synth_run, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(synth_run, out, ignore=shutil.ignore_patterns("fused.ply"))
    with pytest.raises(InputError, match="mvsformerpp fuse OUT"):
        start_viewer(out, ViewerConfig(port=free_port(), host="127.0.0.1"))


@pytest.mark.parametrize("host, match", [("999.1.1.1", "not an address or a name"),
                                         ("192.0.2.77", "cannot listen on --host '192.0.2.77'")])
def test_an_address_it_cannot_listen_on_is_refused_at_once(synth_run, host, match):
    """Instead of a server that waits forever: one error naming the address (192.0.2.0/24 is reserved for
    documentation, so no machine has it)."""
    with pytest.raises(InputError, match=match):
        start_viewer(synth_run, ViewerConfig(port=free_port(), host=host))


def test_the_depth_panel_shows_what_fusion_keeps_with_a_colour_bar(synth_run):
    """The panel greys the pixels below the run's fusion threshold and carries its colour scale."""
    from mvsformerpp.io.output_folder import open_run
    from mvsformerpp.utils.colormap import turbo
    from mvsformerpp.viewer.app import view_panels
    from mvsformerpp.viewer.report import fusion_threshold

    run = open_run(synth_run)
    threshold = fusion_threshold(run)
    plain = view_panels(run.views[0], 200)["depth"]
    shown = view_panels(run.views[0], 200, threshold)["depth"]
    assert shown.shape == plain.shape and shown.shape[0] > 27  # image, gap, bar and labels
    bar = shown[-24 + 3:-14]  # the gradient strip
    assert np.abs(bar[0, 0].astype(int) - turbo(np.zeros(1))[0]).max() <= 5
    assert np.abs(bar[0, -1].astype(int) - turbo(np.ones(1))[0]).max() <= 5
    # the run's confidence falls from 0.95 at the left to 0.35 at the right: the right is grey
    img = shown[:-27].astype(int)
    right = img[:, -img.shape[1] // 6:]
    grey = (np.abs(right[..., 0] - right[..., 1]) <= 1) & (np.abs(right[..., 1] - right[..., 2]) <= 1)
    assert grey.mean() > 0.9
    left = img[:, : img.shape[1] // 6]
    assert ((left.max(-1) - left.min(-1)) > 60).mean() > 0.5  # coloured
