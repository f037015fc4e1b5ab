"""Writers for a simple table (a header and rows of strings) as CSV, Markdown and LaTeX."""

from __future__ import annotations

import csv
import io
import os
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from simeval.results import atomic_write_text


@dataclass
class Rebuilt:
    """What a report rebuild wrote, the Markdown table to print and notes for the user (simeval.report.rebuild)."""
    written: list[Path]
    markdown: str
    notes: list[str] = field(default_factory=list)


def read_csv(path: str | Path) -> list[list[str]]:
    """The lines of a CSV file as lists of strings; an unreadable file is a UserError naming it (tables read back
    with --keep)."""
    from simeval.errors import UserError

    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:  # -sig: a byte-order mark (spreadsheets) is dropped
            return list(csv.reader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise UserError(f"{path}: cannot read it ({getattr(e, 'strerror', None) or e})") from e


def to_markdown(header: list[str], rows: list[list[str]], notes: list[str] | None = None) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    if notes:
        lines += [""] + [f"- {n}" for n in notes]
    return "\n".join(lines) + "\n"


_TEX = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "_": r"\_", "#": r"\#", "$": r"\$", "{": r"\{",
        "}": r"\}", "—": "--"}
_TEX_CHARS = re.compile("|".join(re.escape(c) for c in _TEX))


def _tex_escape(s: str) -> str:
    # one pass: sequential replaces would escape the braces that \textbackslash{} itself introduces
    return _TEX_CHARS.sub(lambda m: _TEX[m.group()], s)


def to_latex(header: list[str], rows: list[list[str]], caption: str = "", label: str = "",
             notes: list[str] | None = None) -> str:
    cols = "l" * 2 + "c" * (len(header) - 2)
    out = [r"\begin{table}[t]", r"\centering", r"\small"]
    if caption:
        out.append(r"\caption{" + _tex_escape(caption) + "}")
    out += [r"\begin{tabular}{@{}" + cols + "@{}}", r"\toprule", " & ".join(map(_tex_escape, header)) + r" \\",
            r"\midrule"]
    previous = None
    for r in rows:
        first = r[0] if r[0] != previous else ""
        if first and previous is not None:
            out.append(r"\midrule")
        previous = r[0]
        out.append(" & ".join([_tex_escape(first)] + [_tex_escape(c) for c in r[1:]]) + r" \\")
    out += [r"\bottomrule", r"\end{tabular}"]
    if notes:
        out.append(r"\\[2pt]{\footnotesize " + "; ".join(_tex_escape(n) for n in notes) + "}")
    if label:
        out.append(r"\label{" + label + "}")
    out.append(r"\end{table}")
    return "\n".join(out) + "\n"


def to_csv(header: list[str], rows: list[list]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(rows)
    return buf.getvalue()


def write_table(stem: str | Path, header: list[str], rows: list[list[str]], *, caption: str = "", label: str = "",
                notes: list[str] | None = None) -> list[Path]:
    stem = Path(stem)
    return [
        atomic_write_text(stem.with_suffix(".csv"), to_csv(header, rows)),
        atomic_write_text(stem.with_suffix(".md"), to_markdown(header, rows, notes)),
        atomic_write_text(stem.with_suffix(".tex"), to_latex(header, rows, caption, label, notes)),
    ]


def committed(paths) -> list[Path]:
    """The files among `paths` that exist and that git tracks (in whatever repository holds each): committed results.
    Outside a repository, or without git, nothing is committed."""
    import shutil
    import subprocess

    if shutil.which("git") is None:
        return []
    out = []
    for p in map(Path, paths):
        if p.is_file() and subprocess.run(["git", "ls-files", "--error-unmatch", p.name], cwd=p.parent,
                                          capture_output=True).returncode == 0:
            out.append(p)
    return out


def outputs_named(out_dir: str | Path, id: str) -> list[Path]:
    """The files a report with this id writes into `out_dir`: `<id>.*` and `<id>_*.*`."""
    out = Path(out_dir)
    return sorted({*out.glob(f"{id}.*"), *out.glob(f"{id}_*.*")})


@dataclass(frozen=True)
class ReportWords:
    """How the caller's user asks for things, as a refusal or a note names them: `overwrite`, the flag that
    replaces a committed file; `elsewhere`, what writes somewhere else; `keep`, the key of the kept tables;
    `episodes`, the key that chooses Table 4's columns. The defaults are a Python caller's keyword arguments."""

    overwrite: str = "--overwrite"
    elsewhere: str = "another output path"
    keep: str = "keep"
    episodes: str = "episodes"


def refuse_committed(paths, overwrite: bool, flag: str = "--overwrite", elsewhere: str = "another output path",
                     source: str = "the runs on disk", lost: str = "") -> None:
    """A report of the runs on disk must not replace a committed result unless asked: raises a UserError naming the
    first committed file among `paths`, what would replace it (`source`: "the kept tables alone" for a redraw) and
    how to proceed (`flag`, or `elsewhere`: the keys that write elsewhere), unless `overwrite`. `lost`
    (rows_lost's words): the committed rows the new table would not have, and how to keep them."""
    from simeval.errors import UserError

    if overwrite:
        return
    hit = committed(paths)
    if hit:
        kind = "figure" if Path(hit[0]).suffix in (".png", ".pdf") else "table"
        raise UserError(f"{hit[0]} is a committed result and would be replaced by a {kind} of {source}"
                        f"{'; ' + lost if lost else ''}; write elsewhere ({elsewhere}) or replace it with {flag}")


def rows_lost(csv: str | Path, keep, rows: list[dict], read_rows: Callable[[Path], list[dict]],
              key: Callable[[dict], tuple], keep_key: str = "keep") -> str:
    """Words for the rows of a committed table `csv` that the new `rows` would not have (groups whose runs are on
    another machine: a report of one sweep would write a table of its row alone), naming the `keep_key` that keeps
    them; "" where none would go, `csv` is not committed, or is kept already."""
    from simeval.errors import UserError

    csv = Path(csv)
    if not committed([csv]) or any(Path(k).resolve() == csv.resolve() for k in keep):
        return ""
    try:
        old = [r for r in read_rows(csv) if key(r) is not None]  # None: a row no run makes (the paper's values)
    except UserError:  # not a table of this kind: refuse_committed still names it
        return ""
    new = {key(r) for r in rows}
    gone = [r for r in old if key(r) not in new]
    if not gone:
        return ""
    return (f"{len(gone)} of its {len(old)} rows would go (groups without runs here: {_names(gone)}); "
            f"{keep_key}=[{csv}] keeps them (make: KEEP={csv})")


def replaced_notes(lost: str) -> list[str]:
    """The note of a report that replaced a committed table, as asked, without some of its rows (rows_lost)."""
    return [f"replaced as asked: {lost.replace(' would go', ' went', 1)}"] if lost else []


def _names(rows: list[dict]) -> str:
    names = [f"{r.get('pipeline')}/{r.get('group')}" for r in rows]
    return ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")


def kept_only_hint(keep, keep_key: str = "keep", committed: str | os.PathLike | None = None) -> str:
    """What to add to "no result.json under <runs_dir>": that kept tables can be drawn alone, on purpose
    (`runs_dir=null`), and where none was kept, how to keep the `committed` table (a fresh clone has no runs)."""
    prefix = keep_key.removesuffix("keep")
    if keep:
        return f" ({prefix}runs_dir=null draws from the kept tables alone)"
    if committed is not None and Path(committed).is_file():
        return f" (or redraw {committed} alone: {keep_key}=[{committed}] {prefix}runs_dir=null)"
    return ""


def read_kept(reader, keep, keep_key: str = "keep", table: str = "table") -> list:
    """`reader(path)` of each kept CSV, before any other work, a bad one's error naming the key that gave it: the
    reader names the file and line, but a user who typed a list of paths also needs to know which option to fix."""
    from simeval.errors import UserError

    kept = []
    for path in keep:
        try:
            kept.append(reader(path))
        except UserError as e:
            raise UserError(f"{keep_key}: {e}; give a {table} CSV this report wrote, or leave it out of {keep_key}") \
                from None
    return kept
