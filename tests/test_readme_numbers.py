"""No hand-typed result in the README (#35): every measured number its results section quotes
appears in a generated file (docs/RESULTS.md, docs/learners/*.md, docs/marl_benchmark/results.md)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: A result as the tables print it: a decimal with at least three digits after the point.
NUMBER = re.compile(r"(?<![\w.])[-+]?\d+\.\d{3,}(?![\d])")


def _results_section(readme: str) -> str:
    start = readme.index("\n## Results")
    end = readme.index("\n## ", start + 1)
    return readme[start:end]


def _generated() -> str:
    files = [ROOT / "docs" / "RESULTS.md", ROOT / "docs" / "marl_benchmark" / "results.md"]
    files += sorted((ROOT / "docs" / "learners").glob("*.md"))
    return "\n".join(f.read_text(encoding="utf-8") for f in files)


def test_every_number_of_the_readme_results_is_in_a_generated_file() -> None:
    section = _results_section((ROOT / "README.md").read_text(encoding="utf-8"))
    generated = _generated()
    quoted = sorted(set(NUMBER.findall(section)))
    assert quoted, "the results section quotes no number: the test would check nothing"
    missing = [n for n in quoted if n.lstrip("+") not in generated]
    assert not missing, f"README quotes {missing}, found in no generated file: regenerate or quote the file"
