"""The documentation site builds strictly and holds what it promises.

`mkdocs build --strict` (mkdocs.yml: mkdocs-material, mkdocstrings, mkdocs-jupyter) fails on a
broken link, anchor or API reference. The built site then has: every guide page (one per
concept), the getting-started, benchmarks and theory pages, every notebook rendered, and one API
page per public package documenting every name of that package's `__all__` (as listed in
`tests/public_api.txt`). No page — and neither the README nor mkdocs.yml — points to the
project's working copies of the papers (`shared/`, `papers/`, their file names): the works are
cited by authors, title, venue and year on the theory page.

`make test` builds the site once before the suite and names it in `BSJAX_DOCS_SITE`; this test
checks that build when it is newer than every source of the site, and builds its own otherwise.
"""

from __future__ import annotations

import collections
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

GUIDE = (
    "architecture",  # how bsjax is built
    "surfaces",  # surfaces and blending
    "curves",  # curves and construction
    "sketching",
    "sculpting",  # sculpting and grammar
    "collision",
    "merging",
    "physics",
    "interaction",
    "haptics",
    "files",  # files and CAD
    "batches",  # batches and optimisation
    "reliability",
)
PAGES = ("index.html", "getting-started/index.html", "benchmarks/index.html", "theory/index.html")
# packages whose API is not a library's: the command line and the case studies
NOT_LIBRARY = ("bsjax.cli", "bsjax.examples")
# a path or file name of the papers' working copies
PAPER_PATH = re.compile(r"shared/|papers/|\b00[0-9]_[0-9a-f]{16}\b", re.IGNORECASE)
# a reference by the working copies' numbers instead of a citation (checked in the written pages;
# the notebooks and docstrings rendered from elsewhere are checked for paths only)
PAPER_NUMBER = re.compile(r"\bpaper 00[0-9]\b", re.IGNORECASE)


def _public_names() -> dict[str, list[str]]:
    names: dict[str, list[str]] = collections.defaultdict(list)
    for line in (ROOT / "tests" / "public_api.txt").read_text().splitlines():
        if line.strip():
            module, _, name = line.split()[0].partition(":")
            if not module.startswith(NOT_LIBRARY):
                names[module].append(name)
    return names


def _sources() -> list[Path]:
    return [
        ROOT / "mkdocs.yml",
        *DOCS.rglob("*"),
        *(ROOT / "bsjax").rglob("*.py"),
        *(ROOT / "notebooks").glob("*"),
    ]


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    built = os.environ.get("BSJAX_DOCS_SITE")
    if built and (Path(built) / "index.html").is_file():
        stamp = (Path(built) / "index.html").stat().st_mtime
        if all(p.stat().st_mtime <= stamp for p in _sources() if p.is_file()):
            return Path(built)
    out = tmp_path_factory.mktemp("site")
    run = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "-d", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    assert run.returncode == 0, run.stdout + run.stderr
    return out


def test_every_guide_page_and_the_main_pages_exist(site):
    for name in GUIDE:
        page = site / "guide" / name / "index.html"
        assert page.is_file(), name
        assert "<h1" in page.read_text(), name
    for page in PAGES:
        assert (site / page).is_file(), page
    assert (site / "sketch_understanding" / "index.html").is_file()  # the measured page, kept and linked
    pages = "".join(page.read_text() for page in site.rglob("*.html"))
    for image in DOCS.glob("*.png"):  # every picture is shown on some page
        assert image.name in pages and (site / image.name).is_file(), image.name


def test_every_notebook_is_rendered(site):
    notebooks = sorted(p.stem for p in (ROOT / "notebooks").glob("*.ipynb"))
    assert notebooks
    for stem in notebooks:
        assert (DOCS / "examples" / f"{stem}.ipynb").exists(), f"docs/examples/{stem}.ipynb missing"
        page = site / "examples" / stem / "index.html"
        assert page.is_file(), stem
        assert "jp-Notebook" in page.read_text() or "jupyter-wrapper" in page.read_text(), stem


def test_one_api_page_per_package_with_every_public_name(site):
    names = _public_names()
    assert {"bsjax", "bsjax.basis", "bsjax.collide", "bsjax.merge", "bsjax.mss"} <= set(names)
    for module, members in names.items():
        sub = module.removeprefix("bsjax").lstrip(".").replace(".", "/")
        page = site / "api" / sub / "index.html" if sub else site / "api" / "index.html"
        assert page.is_file(), module
        html = page.read_text()
        missing = [name for name in members if f'id="{module}.{name}"' not in html]
        assert not missing, (module, missing)


def test_no_page_points_to_the_papers_working_copies(site):
    offending = []
    for path in [*site.rglob("*.html"), ROOT / "README.md", ROOT / "mkdocs.yml", *DOCS.rglob("*.md")]:
        for match in PAPER_PATH.finditer(path.read_text(errors="replace")):
            offending.append((str(path), match.group(0)))
    for path in [ROOT / "README.md", *DOCS.rglob("*.md")]:
        for match in PAPER_NUMBER.finditer(path.read_text()):
            offending.append((str(path), match.group(0)))
    assert not offending, offending[:20]
    theory = " ".join((site / "theory" / "index.html").read_text().split())
    for author, title, venue, year in (
        (
            "Pungotra",
            "Collision detection and merging of deformable B-spline surfaces",
            "Western Ontario",
            "2010",
        ),
        (
            "Knopf",
            "An alternative methodology to represent B-spline surface",
            "Computer-Aided Design",
            "2013",
        ),
        ("Gibson", "Haptic B-spline surface sculpting with a shaped tool", "Computer-Aided Design", "2005"),
        ("De Amicis", "Interactive shape modeling and dynamic deformation", "University of Trento", "2007"),
    ):
        for text in (author, title, venue, year):
            assert text in theory, text
