"""Fixtures shared by the pipeline tests."""

import shutil

import pytest

from mvsformerpp.pipelines.demo import temple_dir


@pytest.fixture
def photos(tmp_path):
    """The bundled temple photos copied into a plain folder (no cameras): the structure-from-motion input."""
    d = tmp_path / "photos"
    d.mkdir()
    for p in sorted(temple_dir().glob("*.png")):
        shutil.copy(p, d / p.name)
    return d
