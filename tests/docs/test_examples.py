"""Every example the README and the site mark runnable runs as written (tests/docs/examples.py says how)."""

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
import examples as ex  # noqa: E402

PAGES = {str(p.relative_to(ex.ROOT)): ex.examples(p) for p in ex.pages()}
DEFAULT = [page for page, blocks in PAGES.items() if any(b.run and b.tier == "default" for b in blocks)]
SLOW = [page for page, blocks in PAGES.items() if any(b.run and b.tier != "default" for b in blocks)]


@pytest.fixture(scope="session")
def inputs_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("example_inputs")


def run_page(page: str, tiers: set[str], folder: Path, cache: Path) -> int:
    """Run the page's examples of ``tiers`` in order in ``folder``; how many ran."""
    namespace: dict = {"__name__": "__docs_example__"}
    ran = 0
    for block in PAGES[page]:
        if not block.run or block.tier not in tiers:
            continue
        ex.provide(block.inputs, folder, cache)
        if "serve" in block.flags:
            ex.run_server(block, folder)
        elif block.language == "bash":
            ex.run_shell(block, folder)
        else:
            ex.run_python(block, folder, namespace)
        ran += 1
    return ran


@pytest.mark.parametrize("page", DEFAULT)
def test_the_examples_of_a_page_run(page, tmp_path, inputs_cache):
    assert run_page(page, {"default"}, tmp_path, inputs_cache) > 0


@pytest.mark.slow
@pytest.mark.parametrize("page", SLOW)
def test_all_examples_of_a_page_run_in_order(page, tmp_path, inputs_cache):
    tiers = {"default", "slow"} | ({"cuda"} if torch.cuda.is_available() else set())
    if not any(b.run and b.tier in tiers - {"default"} for b in PAGES[page]):
        pytest.skip("its other examples need CUDA")
    run_page(page, tiers, tmp_path, inputs_cache)


def test_every_readme_example_is_marked():
    """The README's commands all run as written: each block is an example (or says why it is not run)."""
    readme = ex.ROOT / "README.md"
    assert ex.unmarked_blocks(readme) == []
    blocks = PAGES["README.md"]
    assert [b.code for b in blocks if not b.run] == [
        b.code for b in blocks if not b.run and ("make install" in b.code or "make test" in b.code)]
    assert "make test" in (ex.ROOT / ".ci" / "run").read_text()  # the blocks not run are what CI runs


def test_markers_parse(tmp_path):
    page = tmp_path / "p.md"
    page.write_text("<!-- run slow with my_photos my_scene -->\n```bash\nls\n```\n\n<!-- not run: why -->\n"
                    "```python\nx = 1\n```\n```bash\nunmarked\n```\n")
    blocks = ex.examples(page)
    assert [(b.run, b.tier, b.inputs, b.line) for b in blocks] == [
        (True, "slow", ("my_photos", "my_scene"), 2), (False, "default", (), 7)]
    assert ex.unmarked_blocks(page) == [10]
    page.write_text("<!-- run_view_set.py -->\n```python\nx = 1\n```\n")  # a comment of the page's own
    assert ex.examples(page) == [] and ex.unmarked_blocks(page) == [2]
    for bad in ("<!-- run fast -->\n```bash\nls\n```\n", "<!-- run with nothing_known -->\n```bash\nls\n```\n",
                "<!-- run -->\n\n```bash\nls\n```\n", "<!-- run -->\n```text\nls\n```\n"):
        page.write_text(bad)
        with pytest.raises(ValueError):
            ex.examples(page)


def test_the_examples_are_counted():
    """The numbers the documentation reports (tests/docs/examples.py); every page's markers parse."""
    counts = {t: sum(b.run and b.tier == t for blocks in PAGES.values() for b in blocks)
              for t in ("default", "slow", "cuda")}
    assert counts["default"] >= 10 and counts["slow"] >= 5, counts
