"""docs/scaling.md states measured costs: they are the committed benchmark record's.

Regenerate after ``wmr bench`` with::

    .venv/bin/python -c "import json; from analysis.performance import sweep as s; \
s.update_scaling_doc('docs/scaling.md', json.load(open('paper/results/performance.json')))"
"""

from __future__ import annotations

import json
import re
import textwrap
from pathlib import Path

import pytest

from analysis.performance import sweep as _sweep_bench

ROOT = Path(__file__).resolve().parents[1]
RECORD = ROOT / "paper" / "results" / "performance.json"


@pytest.mark.skipif(not RECORD.exists(), reason="no committed benchmark record")
def test_the_measured_paragraph_is_the_committed_records():
    rec = json.loads(RECORD.read_text())
    doc = (ROOT / "docs" / "scaling.md").read_text()
    body = re.search(r"<!-- measured -->\n(.*?)\n<!-- /measured -->", doc, re.S).group(1)
    assert body == textwrap.fill(_sweep_bench.scaling_paragraph(rec), 98,
                                 break_on_hyphens=False)  # fmt: skip
