"""Agreement of judges with human scores, per table (scene alignment, completion), pipeline and judge.

Input: a JSON mapping table -> list of records {pipeline, task, <human column>, <judge>: score, <judge>_var: ...}
(the layout of the paper's appendix tables), or a CSV with the same fields (UTF-8, a header row; a `table`
column is optional and defaults to one table named `scores`, `pipeline` is optional).

Both are read strictly: every score is a finite number (JSON: a number, never a boolean or a string), an empty
judge cell (JSON: null or an absent key) is a missing score, the human score is never missing, each
(pipeline, task) appears once per table, and a CSV row has exactly as many fields as the header. Every mistake
is a `UserError` naming the file, the row and the column.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from pathlib import Path

import numpy as np

from simeval.errors import UserError
from simeval.measures.agreement.metric import STATISTICS, agreement_summary

RESERVED = {"table", "pipeline", "task"}
PAPER_SCORES = "src/simeval/writing/paper_human_eval.json"  # the paper's appendix tables, shipped with the package
DEFAULT_TABLE = "scores"  # a CSV without a `table` column is one table


class ScoreFileNotFound(UserError, FileNotFoundError):
    """The score file does not exist (a UserError that is also a FileNotFoundError, as before)."""


def load_score_tables(path: str | os.PathLike, human: str = "Human") -> dict[str, list[dict]]:
    """Read and validate a score file. Returns table -> records whose score columns are floats (None: missing).

    `human` is the human score column; it must be present and filled in every row, beside at least one judge
    column (any column other than table, pipeline, task, the human column and `*_var`).
    """
    path = Path(path).expanduser()
    if not path.is_file():
        raise ScoreFileNotFound(f"score table not found: {path}" + (" (a folder)" if path.is_dir() else "")
                                + f"; give a .json or .csv score table (the paper's: {PAPER_SCORES})")
    suffix = path.suffix.lower()
    if suffix not in (".json", ".csv"):
        raise UserError(f"{path}: unknown extension {path.suffix!r}; expected a .json or .csv score table")
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise UserError(_not_utf8(path, raw, e, csv_file=suffix == ".csv")) from None
    if suffix == ".csv":
        tables, header = _read_csv(path, text)
    else:
        tables, header = _read_json(path, text), None
    return {table: _validate_table(path, table, rows, human, header) for table, rows in tables.items()}


# Each reader returns table -> list of (prefix, row, record): "{prefix}row {row}" names the row in messages
# ("row 7": the file's line in a CSV, as a spreadsheet numbers it; "table 'x' row 3": the 3rd record in JSON),
# and a record maps column -> raw value.

def _read_json(path: Path, text: str) -> dict[str, list[tuple[str, int, dict]]]:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise UserError(f"cannot parse {path}: line {e.lineno}, column {e.colno}: {e.msg}") from None
    if not isinstance(data, dict) or not data:
        raise UserError(f"{path}: expected a JSON object mapping table name -> list of rows, got "
                        f"{_json_kind(data)}")
    tables = {}
    for table, records in data.items():
        if not isinstance(records, list) or not records:
            raise UserError(f"{path}: table {table!r}: expected a non-empty list of rows, got {_json_kind(records)}")
        rows = []
        for i, rec in enumerate(records, start=1):
            if not isinstance(rec, dict):
                raise UserError(f"{path}: table {table!r} row {i}: expected an object {{column: value}}, got "
                                f"{_json_kind(rec)}")
            rows.append((f"table {table!r} ", i, rec))
        tables[table] = rows
    return tables


def _read_csv(path: Path, text: str) -> tuple[dict[str, list[tuple[str, int, dict]]], list[str]]:
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    header: list[str] | None = None
    tables: dict[str, list[tuple[str, int, dict]]] = {}
    lines = text.splitlines(keepends=True)
    while True:
        start = reader.line_num + 1  # the line this record starts on (the header is row 1, as in a spreadsheet)
        try:
            fields = next(reader)
        except StopIteration:
            break
        except csv.Error as e:
            column = _column_name(header, _csv_error_field("".join(lines[start - 1:])))
            what = ("unclosed quote: the quoted field runs to the end of the file" if "end of data" in str(e)
                    else f"malformed quoting ({e})")
            raise UserError(f"{path}: row {start}, column {column}: {what}") from None
        if not fields or fields == [""]:  # a blank line
            continue
        if header is None:
            header = [f.strip() for f in fields]
            _check_header(path, header)
            continue
        if len(fields) > len(header):
            raise UserError(f"{path}: row {start}, column {len(header) + 1} (after {header[-1]!r}): extra value "
                            f"{fields[len(header)]!r}; the header has {len(header)} columns (quote a value that "
                            f"contains a comma)")
        if len(fields) < len(header):
            raise UserError(f"{path}: row {start}, column {header[len(fields)]!r}: no value; the row has "
                            f"{len(fields)} fields, the header {len(header)} columns")
        rec = dict(zip(header, fields))
        table = rec.pop("table", DEFAULT_TABLE).strip()
        if not table:
            raise UserError(f"{path}: row {start}, column 'table': empty; name the table this row belongs to")
        tables.setdefault(table, []).append(("", start, rec))
    if header is None:
        raise UserError(f"{path}: empty; expected a header row (table, pipeline, task, Human, <judge>...) and rows")
    if not tables:
        raise UserError(f"{path}: a header row but no data rows")
    return tables, header


def _check_header(path: Path, header: list[str]) -> None:
    for i, name in enumerate(header):
        if not name:
            raise UserError(f"{path}: row 1 (header), column {i + 1}: empty column name")
        if name in header[:i]:
            raise UserError(f"{path}: row 1 (header), column {i + 1}: {name!r} appears twice "
                            f"(also column {header.index(name) + 1})")


def _validate_table(path: Path, table: str, rows: list[tuple[str, int, dict]], human: str,
                    header: list[str] | None) -> list[dict]:
    csv_file = header is not None
    columns = header or list(dict.fromkeys(k for _, _, rec in rows for k in rec))
    head = "row 1 (header)" if csv_file else f"table {table!r}"
    if "task" not in columns:
        raise UserError(f"{path}: {head}, column 'task': no such column; columns: {', '.join(columns)}")
    if human not in columns:
        raise UserError(f"{path}: {head}, column {human!r}: no such column (the human scores); columns: "
                        f"{', '.join(columns)}; set human_column=NAME if the human scores are under another name")
    judges = [c for c in columns if c not in RESERVED and c != human and not c.endswith("_var")]
    if not judges:
        raise UserError(f"{path}: {head}: no judge column; columns: {', '.join(columns)} (a judge column is any "
                        f"column other than table, pipeline, task, {human} and *_var)")
    for c in columns:
        if c.endswith("_var") and c[:-4] not in columns:
            raise UserError(f"{path}: {head}, column {c!r}: a variance column without its score column {c[:-4]!r}")
    out, seen = [], {}
    for prefix, row, rec in rows:
        where = f"{prefix}row {row}"
        if human not in rec:
            raise UserError(f"{path}: {where}, column {human!r}: missing; every row needs a human score")
        clean = {}
        for key in ("pipeline", "task"):
            if key not in rec:
                if key == "task":
                    raise UserError(f"{path}: {where}, column 'task': missing")
                continue
            value = rec[key]
            if not isinstance(value, str) or not value.strip():
                raise UserError(f"{path}: {where}, column {key!r}: expected a non-empty name, got {value!r}")
            clean[key] = value.strip()
        for col, value in rec.items():
            if col in RESERVED:
                continue
            score = _score(value, f"{path}: {where}, column {col!r}", text_ok=csv_file)
            if score is None and col == human:
                raise UserError(f"{path}: {where}, column {human!r}: missing; every row needs a human score")
            clean[col] = score
        key = (clean.get("pipeline"), clean["task"])
        if key in seen:
            pipe = f" of pipeline {key[0]!r}" if key[0] is not None else ""
            raise UserError(f"{path}: {prefix}rows {seen[key]} and {row}, column 'task': task {key[1]!r}{pipe} "
                            f"appears twice in table {table!r}; keep one row per task")
        seen[key] = row
        out.append(clean)
    return out


def _score(value, where: str, text_ok: bool) -> float | None:
    """A finite float, or None for a missing score (JSON null, an empty CSV cell). `text_ok`: a CSV cell, where
    numbers are text; in JSON a score must be a number."""
    if value is None:
        return None
    if isinstance(value, bool):
        raise UserError(f"{where}: {json.dumps(value)} is a boolean, not a score")
    if isinstance(value, (int, float)):
        x = float(value)
    elif isinstance(value, str) and text_ok:
        if not value.strip():
            return None
        try:
            x = float(value)
        except ValueError:
            raise UserError(f"{where}: not a number: {value!r}") from None
    else:
        kind = "a string; write the number without quotes" if isinstance(value, str) else _json_kind(value)
        raise UserError(f"{where}: not a number: {value!r} ({kind})")
    if not math.isfinite(x):
        raise UserError(f"{where}: not finite: {value!r}")
    return x


def _json_kind(value) -> str:
    names = {dict: "an object", list: "a list", str: "a string", bool: "a boolean", type(None): "null",
             int: "a number", float: "a number"}
    return names.get(type(value), type(value).__name__)


def _csv_error_field(text: str) -> int:
    """Index of the field where a strict CSV parse fails in `text` (a record and everything after it): the field
    whose opening quote never closes, or whose closing quote is followed by more text."""
    field, i, n = 0, 0, len(text)
    at_start = True
    while i < n:
        c = text[i]
        if at_start and c == '"':
            quote_field, i = field, i + 1
            while True:
                j = text.find('"', i)
                if j < 0:
                    return quote_field  # never closed
                if text[j + 1:j + 2] == '"':
                    i = j + 2  # an escaped quote
                    continue
                i = j + 1
                break
            if i < n and text[i] not in ",\r\n":
                return quote_field  # text after the closing quote
            at_start = False
            continue
        if c == ",":
            field, at_start = field + 1, True
        elif c in "\r\n":
            return field
        else:
            at_start = False
        i += 1
    return field


def _column_name(header: list[str] | None, index: int) -> str:
    if header is None:
        return f"{index + 1} (header)"
    return repr(header[index]) if index < len(header) else f"{index + 1} (beyond the header)"


def _not_utf8(path: Path, raw: bytes, e: UnicodeDecodeError, csv_file: bool) -> str:
    line_start = raw.rfind(b"\n", 0, e.start) + 1
    line = raw.count(b"\n", 0, e.start) + 1
    byte = e.start - line_start + 1
    if csv_file:  # name the column: count the fields before the bad byte
        fields = next(csv.reader([raw[line_start:e.start].decode("utf-8", "replace")]), [])
        header = None
        if line > 1:
            header = next(csv.reader([raw[:raw.find(b"\n")].decode("utf-8", "replace").strip()]), None)
        where = f"row {line}, column {_column_name(header, max(0, len(fields) - 1))} (byte {byte} of the line)"
    else:
        where = f"line {line}, column {byte}"
    return f"{path}: {where}: byte 0x{raw[e.start]:02x} is not UTF-8 text; save the file as UTF-8"


def judge_columns(records: list[dict], human: str) -> list[str]:
    cols = dict.fromkeys(k for r in records for k in r)
    if human not in cols:
        raise UserError(f"human score column '{human}' not found; columns: {', '.join(cols)}")
    return [c for c in cols if c not in RESERVED and c != human and not c.endswith("_var")]


def _number(value, where: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError) as e:
        raise UserError(f"{where}: not a number: {value!r}") from e
    if not np.isfinite(x):
        raise UserError(f"{where}: not finite: {value!r}")
    return x


def agreement_rows(tables: dict[str, list[dict]], human: str = "Human", *, n_boot: int = 2000,
                   seed: int = 0) -> list[dict]:
    """One row per (table, pipeline incl. 'all', judge) with every statistic and its CI. A judge with no score at
    all in a scope (a CSV holding several tables has every table's judge columns, blank where a judge did not
    score that table) gets no row: "undefined" is kept for statistics that exist but cannot be computed."""
    rows = []
    for table, records in tables.items():
        judges = judge_columns(records, human)
        pipelines = list(dict.fromkeys(str(r.get("pipeline", "all")) for r in records))
        scopes = [(p, [r for r in records if str(r.get("pipeline", "all")) == p]) for p in pipelines]
        if len(pipelines) > 1:
            scopes.append(("all", records))
        for pipeline, recs in scopes:
            for judge in judges:
                pairs = [(r[human], r[judge]) for r in recs if r.get(judge) not in (None, "")]
                if not pairs:
                    continue
                h = [_number(a, f"{table}/{pipeline}/{human}") for a, _ in pairs]
                m = [_number(b, f"{table}/{pipeline}/{judge}") for _, b in pairs]
                rows.append({"table": table, "pipeline": pipeline, "judge": judge,
                             **agreement_summary(h, m, n_boot=n_boot, seed=seed)})
    return rows


def format_rows(rows: list[dict], digits: int = 2) -> tuple[list[str], list[list[str]]]:
    header = ["Table", "Pipeline", "Judge", "n"] + [s for s in STATISTICS]
    body = []
    for r in rows:
        cells = []
        for s in STATISTICS:
            v, ci = r[s], r[f"{s}_ci"]
            cells.append("undefined" if v is None else f"{v:.{digits}f}" + (
                f" [{ci[0]:.{digits}f}, {ci[1]:.{digits}f}]" if ci else ""))
        body.append([r["table"], r["pipeline"], r["judge"], str(r["n"])] + cells)
    return header, body
