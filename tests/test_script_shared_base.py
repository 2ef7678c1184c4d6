"""``scripts/learner_shared_base.py`` (docs/performance.md): its low-rank split reproduces
every version's ``k^T C k`` to rounding, so the timings it prints compare equal work; its
genealogy count follows the learner's updates and copies."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "learner_shared_base.py"


def test_shared_base_split_is_exact_to_rounding() -> None:
    # 150 points: ten versions whose genealogies have split (the property is exact at any
    # size); one timing repeat, as the timings are only checked to exist
    out = subprocess.run([sys.executable, str(SCRIPT), "--points", "150", "--repeats", "1",
                          "--json"], capture_output=True, text=True, timeout=600, check=True)
    report = json.loads(out.stdout)
    assert report["versions"] >= report["experts"] >= 1
    assert report["kck_relative_error_max"] < 1e-10
    assert report["dense_us_per_step"] > 0 and report["shared_us_per_step"] > 0
    # the genealogy: every version has its own updates since its expert's common ancestor
    p50, p90, most = report["updates_since_common_ancestor_p50_p90_max"]
    assert 0 <= p50 <= p90 <= most and most > 0
