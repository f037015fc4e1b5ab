"""Human-score files are read strictly: every mistake is one UserError naming the file, the row and the column."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from simeval.measures.agreement.run import agreement_rows, load_score_tables
from simeval.errors import UserError

ROOT = Path(__file__).resolve().parents[1]
HEADER = "table,pipeline,task,Human,GPT-4\n"


def _write(tmp_path, name, content):
    path = tmp_path / name
    (path.write_bytes if isinstance(content, bytes) else path.write_text)(content)
    return path


def _error(path, **kw) -> str:
    with pytest.raises(UserError) as e:
        load_score_tables(path, **kw)
    message = str(e.value)
    assert message.startswith(f"{path}: ") or message.startswith(f"cannot parse {path}")
    assert "\n" not in message
    return message


def test_a_good_csv_is_read_as_numbers_with_quoted_commas_and_missing_judge_scores(tmp_path):
    path = _write(tmp_path, "s.csv", HEADER + 't,GenSim,"stack, then place",7,8\n\nt,GenSim,b,5,\nu,RoboGen,c,3,4.5\n')
    tables = load_score_tables(path)
    assert tables == {"t": [{"pipeline": "GenSim", "task": "stack, then place", "Human": 7.0, "GPT-4": 8.0},
                            {"pipeline": "GenSim", "task": "b", "Human": 5.0, "GPT-4": None}],
                      "u": [{"pipeline": "RoboGen", "task": "c", "Human": 3.0, "GPT-4": 4.5}]}
    rows = agreement_rows(tables, n_boot=10)
    assert [(r["table"], r["n"]) for r in rows] == [("t", 1), ("u", 1)]  # the empty cell is missing, not 0


def test_unclosed_quote_is_an_error_not_a_bogus_row(tmp_path):
    # The old loader read this as three rows, one of them with task 'b,3,4\nt,p,c,5,6'.
    path = _write(tmp_path, "s.csv", HEADER + 't,p,a,1,2\nt,p,"b,3,4\nt,p,c,5,6\n')
    assert _error(path).endswith("row 3, column 'task': unclosed quote: the quoted field runs to the end of the file")
    path = _write(tmp_path, "q.csv", HEADER + 't,p,a,1,"2"x\n')
    assert "row 2, column 'GPT-4': malformed quoting" in _error(path)


def test_duplicate_tasks_name_both_rows(tmp_path):
    path = _write(tmp_path, "s.csv", HEADER + "t,p,a,1,2\nt,q,a,1,2\nu,p,a,1,2\nt,p,a,3,4\n")
    assert _error(path).endswith("rows 2 and 5, column 'task': task 'a' of pipeline 'p' appears twice in table 't'; "
                                 "keep one row per task")
    path = _write(tmp_path, "s.json", json.dumps({"t": [{"pipeline": "p", "task": "a", "Human": 1, "J": 2},
                                                        {"pipeline": "p", "task": "a", "Human": 3, "J": None}]}))
    assert "table 't' rows 1 and 2, column 'task': task 'a' of pipeline 'p' appears twice" in _error(path)


@pytest.mark.parametrize("value,expected", [
    (True, "table 't' row 1, column 'J': true is a boolean, not a score"),
    (False, "table 't' row 1, column 'J': false is a boolean, not a score"),
    ("3.5", "table 't' row 1, column 'J': not a number: '3.5' (a string; write the number without quotes)"),
    (float("nan"), "table 't' row 1, column 'J': not finite: nan"),
])
def test_json_scores_must_be_numbers(tmp_path, value, expected):
    path = _write(tmp_path, "s.json", json.dumps({"t": [{"pipeline": "p", "task": "a", "Human": 1, "J": value}]}))
    assert _error(path).endswith(expected)


def test_text_booleans_in_a_csv_are_not_numbers(tmp_path):
    path = _write(tmp_path, "s.csv", HEADER + "t,p,a,true,2\n")
    assert _error(path).endswith("row 2, column 'Human': not a number: 'true'")


def test_missing_human_column_or_value(tmp_path):
    path = _write(tmp_path, "s.csv", "table,pipeline,task,human,GPT-4\nt,p,a,1,2\n")
    message = _error(path)
    assert "row 1 (header), column 'Human': no such column" in message and "human_column=NAME" in message
    assert "columns: table, pipeline, task, human, GPT-4" in message
    assert load_score_tables(path, human="human")["t"][0]["human"] == 1.0  # human_column=human reads it
    path = _write(tmp_path, "e.csv", HEADER + "t,p,a,,2\n")
    assert _error(path).endswith("row 2, column 'Human': missing; every row needs a human score")
    path = _write(tmp_path, "s.json", json.dumps({"t": [{"task": "a", "Human": 1, "J": 2}, {"task": "b", "J": 2}]}))
    assert _error(path).endswith("table 't' row 2, column 'Human': missing; every row needs a human score")


def test_no_judge_column(tmp_path):
    path = _write(tmp_path, "s.csv", "table,pipeline,task,Human,Human_var\nt,p,a,1,0.5\n")
    assert "row 1 (header): no judge column; columns: table, pipeline, task, Human, Human_var" in _error(path)
    path = _write(tmp_path, "v.csv", "task,Human,J,K_var\na,1,2,0.1\n")
    assert "row 1 (header), column 'K_var': a variance column without its score column 'K'" in _error(path)


def test_extra_and_missing_fields(tmp_path):
    path = _write(tmp_path, "s.csv", HEADER + "t,p,a,1,2\nt,p,b,1,2,7\n")
    assert _error(path).endswith("row 3, column 6 (after 'GPT-4'): extra value '7'; the header has 5 columns "
                                 "(quote a value that contains a comma)")
    path = _write(tmp_path, "m.csv", HEADER + "t,p,a,1\n")
    assert _error(path).endswith("row 2, column 'GPT-4': no value; the row has 4 fields, the header 5 columns")
    path = _write(tmp_path, "h.csv", "table,task,Human,J,J\nt,a,1,2,3\n")
    assert _error(path).endswith("row 1 (header), column 5: 'J' appears twice (also column 4)")


def test_non_utf8_bytes(tmp_path):
    path = _write(tmp_path, "s.csv", HEADER.encode() + "t,p,café,1,2\n".encode("latin-1"))
    assert _error(path).endswith("row 2, column 'task' (byte 8 of the line): byte 0xe9 is not UTF-8 text; "
                                 "save the file as UTF-8")
    path = _write(tmp_path, "s.json", b'{"t": [\n {"task": "caf\xe9"}]}')
    assert _error(path).endswith("line 2, column 15: byte 0xe9 is not UTF-8 text; save the file as UTF-8")
    bom = _write(tmp_path, "bom.csv", "\ufeff".encode() + HEADER.encode() + b"t,p,a,1,2\n")  # Excel's UTF-8 is fine
    assert load_score_tables(bom)["t"][0]["GPT-4"] == 2.0


def test_file_level_mistakes(tmp_path):
    with pytest.raises(FileNotFoundError, match="score table not found"):  # also a UserError
        load_score_tables(tmp_path / "nope.json")
    assert "line 1, column 2" in _error(_write(tmp_path, "bad.json", "{"))
    assert "expected a JSON object mapping table name -> list of rows, got a list" in _error(
        _write(tmp_path, "l.json", "[]"))
    assert "table 't': expected a non-empty list of rows" in _error(_write(tmp_path, "e.json", '{"t": []}'))
    assert _error(_write(tmp_path, "h.csv", HEADER)).endswith("a header row but no data rows")
    assert "unknown extension '.txt'" in _error(_write(tmp_path, "s.txt", HEADER))


def test_entrypoint_reports_a_bad_file_in_one_line(tmp_path):
    bad = _write(tmp_path, "scores.csv", HEADER + "t,p,a,1,2\nt,p,a,1,3\n")
    res = subprocess.run([sys.executable, str(ROOT / "src" / "agreement.py"), f"scores_path={bad}",
                          f"hydra.run.dir={tmp_path / 'run'}"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert lines == [f"error: {bad}: rows 2 and 3, column 'task': task 'a' of pipeline 'p' appears twice in table "
                     f"'t'; keep one row per task"], res.stderr
    assert "Traceback" not in res.stdout + res.stderr


def test_a_judge_blank_for_a_whole_table_gets_no_row_there(tmp_path):
    from simeval.measures.agreement.run import agreement_rows, load_score_tables

    path = tmp_path / "two_tables.csv"
    path.write_text("table,pipeline,task,Human,A,B\n"
                    "t1,p,a,1,1,\nt1,p,b,2,2,\nt1,p,c,3,3,\n"
                    "t2,p,a,1,,3\nt2,p,b,2,,1\nt2,p,c,3,,2\n")
    rows = agreement_rows(load_score_tables(path), n_boot=20)
    assert sorted((r["table"], r["judge"], r["n"]) for r in rows) == [("t1", "A", 3), ("t2", "B", 3)]
    assert [r["pearson"] for r in sorted(rows, key=lambda r: r["table"])] == pytest.approx([1.0, -0.5])
