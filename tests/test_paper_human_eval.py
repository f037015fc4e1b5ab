"""The paper's appendix score tables shipped with the package (Figure 3 without ../shared): extracted from the
paper's LaTeX by experiments/paper_human_eval.py, checked against a copy typed independently."""

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "src" / "simeval" / "report" / "paper_human_eval.json"
SHARED = ROOT.parent / "shared"

from paper_human_eval import extract, parse_table  # noqa: E402


def test_shipped_tables_equal_the_independently_typed_copy():
    typed = SHARED / "data" / "human_eval_tables.json"
    if not typed.is_file():
        pytest.skip("no ../shared/data/human_eval_tables.json")
    assert json.loads(SHIPPED.read_text()) == json.loads(typed.read_text())


def test_extraction_from_the_paper_source_gives_the_shipped_file():
    tex = sorted((SHARED / "paper").glob("*.tex")) if (SHARED / "paper").is_dir() else []
    if not tex:
        pytest.skip("no ../shared/paper/*.tex")
    tables = extract(tex[0].read_text(encoding="utf-8"))
    assert tables == json.loads(SHIPPED.read_text())
    # spot values read off the paper: GPT-4v aligns "Open Laptop" at 3.96 (variance 0.03); humans give 9.5
    # completion to "Color Ordered Insertion"
    open_laptop = next(r for r in tables["scene_alignment"] if r["task"] == "Open Laptop")
    assert (open_laptop["pipeline"], open_laptop["GPT-4v"], open_laptop["GPT-4v_var"]) == ("RoboGen", 3.96, 0.03)
    insertion = next(r for r in tables["task_completion"] if r["task"] == "Color Ordered Insertion")
    assert insertion["Human"] == 9.5 and "Human_var" not in insertion


def test_a_cell_that_is_not_a_number_names_its_row_and_column():
    body = ("\\textbf{Task Name (RoboGen)} & \\textbf{Human} & \\textbf{GPT-4} \\\\\n"
            "Open Laptop & 8.2 & 7.96(0.01) \\\\\n"
            "Close Window & 9.3 & n/a \\\\\n")
    with pytest.raises(ValueError, match=r"'Close Window', column 'GPT-4': cannot read 'n/a'"):
        parse_table(body, "task_completion")
    ok = parse_table(body.rsplit("Close", 1)[0], "task_completion")
    assert ok == [{"pipeline": "RoboGen", "task": "Open Laptop", "Human": 8.2, "GPT-4": 7.96, "GPT-4_var": 0.01}]
