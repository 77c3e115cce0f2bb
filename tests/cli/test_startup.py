"""The command line answers --help and argument errors without loading torch, scipy or the network."""

import subprocess
import sys


def test_building_the_parser_imports_neither_torch_nor_scipy():
    code = ("import sys, mvsformerpp.cli as c; c.build_parser(); "
            "print(sorted(m for m in ('torch', 'scipy') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_the_lazy_fusion_names_resolve_and_unknown_ones_fail():
    import mvsformerpp.fusion as fusion
    from mvsformerpp.fusion.core import fuse_views
    from mvsformerpp.fusion.views import make_view

    assert fusion.fuse_views is fuse_views and fusion.make_view is make_view
    assert set(fusion.__all__) <= set(dir(fusion))
    try:
        fusion.no_such_name  # noqa: B018
    except AttributeError as e:
        assert "no_such_name" in str(e)
    else:
        raise AssertionError("an unknown name resolved")
