"""The paper's appendix score tables shipped with the package (Figure 3 without ../shared), checked against a copy
typed independently. (They were extracted once from the paper's LaTeX by a script that git keeps: commit 51b21a6's
experiments/paper_human_eval.py.)"""

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "src" / "simeval" / "writing" / "paper_human_eval.json"
SHARED = ROOT.parent / "shared"


def test_shipped_tables_equal_the_independently_typed_copy():
    typed = SHARED / "data" / "human_eval_tables.json"
    if not typed.is_file():
        pytest.skip("no ../shared/data/human_eval_tables.json")
    assert json.loads(SHIPPED.read_text()) == json.loads(typed.read_text())
