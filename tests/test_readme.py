"""The README points only inside the repository, and at files that exist."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).parents[1]


def test_readme_links_stay_inside_the_repository() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    targets = re.findall(r"\]\(([^)\s]+)\)", text)
    assert targets, "the README has no links at all (figures are links too)"
    for target in targets:
        assert "://" not in target, f"link outside the repository: {target}"
        path = (ROOT / target.split("#")[0]).resolve()
        assert path.is_relative_to(ROOT.resolve()), f"link outside the repository: {target}"
        assert path.exists(), f"link to a missing file: {target}"
    assert "../shared" not in text
