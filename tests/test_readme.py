"""The README: short, η1 defined where it first appears, a two-minute start near the top, links that resolve, and
its results table the one `uqdrive headline` prints from metrics/summary.json (so it cannot drift from the run)."""

import re
from pathlib import Path

import yaml

from uqdrive.report.headline import headline_table, read_summary

ROOT = Path(__file__).resolve().parents[1]
PARAMS = yaml.safe_load((ROOT / "params.yaml").read_text())


def test_the_readme_table_is_the_one_generated_from_the_summary():
    headline = read_summary(ROOT / "metrics/summary.json")
    table = headline_table(headline, PARAMS)
    readme = (ROOT / "README.md").read_text()
    assert table in readme, "README's results table is stale: paste `uqdrive headline` into it"
    assert table.splitlines()[2].count("1.00 [0.16, 1.00]") == len(PARAMS["methods"])  # what the cells gave


def test_the_readme_is_short_defines_eta1_first_and_links_only_files_that_exist():
    readme = (ROOT / "README.md").read_text()
    lines = readme.splitlines()
    assert len(lines) <= 300
    first = next(i for i, line in enumerate(lines) if "η1" in line)
    assert "**η1** is the probability" in " ".join(lines[first : first + 3])
    assert readme.index("## Try it in three minutes") < readme.index("## Results of the committed run")
    for target in re.findall(r"\]\((docs/[^)#]+)", readme):
        assert (ROOT / target).exists(), target


def _anchor(heading: str) -> str:
    """GitHub's anchor of a markdown heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_every_link_of_the_readme_and_docs_points_at_a_file_and_heading_that_exist():
    broken = []
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
            if target.startswith(("http://", "https://", "mailto:")):
                continue
            path, _, anchor = target.partition("#")
            found = page.parent / path if path else page
            markdown = found.suffix == ".md" and found.exists()
            headings = re.findall(r"^#+\s+(.*)$", found.read_text(), re.M) if markdown else []
            if not found.exists() or (anchor and anchor not in {_anchor(h) for h in headings}):
                broken.append(f"{page.relative_to(ROOT)}: {target}")
    assert not broken, broken
