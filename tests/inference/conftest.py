import importlib.util
import sys
from pathlib import Path

import pytest


def load_fake_model():
    """The fake network module (tests only), loaded by path: tests are not a package."""
    name = "recon_fake_model"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name("fake_model.py"))
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


@pytest.fixture
def fake_model_cls():
    return load_fake_model().FakeMVSModel
