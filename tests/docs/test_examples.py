"""The examples of the README, the tutorial and the guides run against the shipped data.

The convention is in tests/docs/examples.py: ```console blocks are one command and its
output, an HTML comment ``<!-- check: … -->`` before a block says which lines are compared.
Each page runs in its own temporary copy of studies/, data/ and examples/.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.docs.examples import REPO, matches, parse_page

PAGES = sorted(
    [REPO / "README.md", *(p for p in (REPO / "docs").rglob("*.md") if "_gen" not in p.parts)]
)


def _param(path: Path) -> object:
    marks = [pytest.mark.docs]
    if parse_page(path).slow:
        marks.append(pytest.mark.slow)
    return pytest.param(path, id=str(path.relative_to(REPO)), marks=marks)


@pytest.mark.parametrize("page", [_param(p) for p in PAGES if parse_page(p).blocks])
def test_the_examples_of_a_page_give_the_output_it_shows(page: Path, tmp_path: Path) -> None:
    from tests.docs.examples import check_page

    assert check_page(page, tmp_path) > 0


def test_the_tutorial_and_the_readme_have_checked_examples() -> None:
    """The pages the issue names are checked: not a page left out by a typo in a fence."""
    for name in ("README.md", "docs/tutorial/identify.md", "docs/tutorial/measurements.md"):
        blocks = parse_page(REPO / name).blocks
        assert sum(b.language == "console" and not b.skip for b in blocks) >= 3, name


def test_a_key_line_matches_with_numbers_within_the_tolerance() -> None:
    assert matches("F60 = 10.02 N", "verified: F60 = 10.02 N is within 1 %", 0.02)
    assert matches("RMSE 1.029 N", "base: RMSE   1.0295 N over", 0.02)
    assert not matches("RMSE 1.029 N", "base: RMSE 1.2 N over", 0.02)
    assert not matches("target met", "target missed", 0.02)
    assert matches("ΔBIC -5461", "ΔBIC -5461.4", 0.02)


def test_a_changed_output_fails_its_page(tmp_path: Path) -> None:
    """What a stale example does: the output it shows is no longer the command's."""
    from tests.docs.examples import check_page

    page = tmp_path / "page.md"
    page.write_text(
        "```console\n$ surrogate simulate --ecoat 1 --scoat 0.2 --tcoat 0.012\nF60 = 11.5 N\n```\n",
        encoding="utf-8",
    )
    with pytest.raises(AssertionError, match=r"F60 = 11\.5 N"):
        check_page(page, tmp_path / "work")
    page.write_text(page.read_text().replace("11.5", "9.958"), encoding="utf-8")
    assert check_page(page, tmp_path / "work2") == 1


def test_a_changed_python_result_fails_its_page(tmp_path: Path) -> None:
    from tests.docs.examples import check_page

    page = tmp_path / "page.md"
    page.write_text(
        "```pycon\n>>> import surrogate\n>>> round(surrogate.simulate(1, 0.2, 0.012).f60_n, 2)\n"
        "9.5\n```\n",
        encoding="utf-8",
    )
    with pytest.raises(AssertionError, match="Expected:"):
        check_page(page, tmp_path / "work")
