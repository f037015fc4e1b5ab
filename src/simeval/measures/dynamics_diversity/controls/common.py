"""What the controls share: one-line user errors and the rule that a committed result is replaced only when asked
(`--overwrite`). Whether a file is committed is asked of git in the file's own folder, so the library needs no
checkout path."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import yaml

from simeval.errors import UserError


def fail(message: str) -> None:
    """A user error: the entrypoint prints it as one line, exit status 2."""
    raise UserError(message.removeprefix("error: "))


def preset(conf_dir: Path, group: str, name: str) -> dict:
    """conf/<group>/<name>.yaml as a mapping (the entrypoint gives conf_dir)."""
    path = Path(conf_dir) / group / f"{name}.yaml"
    if not path.is_file():
        known = ", ".join(sorted(p.stem for p in path.parent.glob("*.yaml")))
        fail(f"error: {group} preset {name!r}: no {path} (presets: {known})")
    return yaml.safe_load(path.read_text())


def tracked(path: Path) -> bool:
    """Whether git tracks `path` (False outside a repository)."""
    where = path.parent if path.parent.is_dir() else Path.cwd()
    return subprocess.run(["git", "ls-files", "--error-unmatch", str(path.resolve())], cwd=where,
                          capture_output=True).returncode == 0


def tracks_any_in(folder: Path) -> bool:
    """Whether git tracks any file in `folder` (a control's committed run records)."""
    if not folder.is_dir():
        return False
    out = subprocess.run(["git", "ls-files", str(folder.resolve())], cwd=folder, capture_output=True, text=True)
    return out.returncode == 0 and bool(out.stdout.strip())


def refuse_to_replace_committed(paths: list[Path], new_bytes: list[bytes], overwrite: bool,
                                elsewhere: str = "--out DIR") -> None:
    """A committed result is replaced only when asked (--overwrite): a rebuild that gives the same bytes is fine,
    another one stops with one line naming the file and the option (`elsewhere`) that writes somewhere else."""
    for path, data in zip(paths, new_bytes):
        if overwrite or not path.exists() or path.read_bytes() == data:
            continue
        if tracked(path):
            fail(f"error: {path} is a committed result and this run would change it; write elsewhere "
                 f"with {elsewhere}, or replace it with --overwrite")


def add_output_options(ap, runs: str, made: str) -> None:
    """--out (runs and checkpoints), --tables (what the control makes), --replot and --overwrite, for a control's
    argparse parser: `runs`, where under OUT its runs go; `made`, what it writes under TABLES."""
    ap.add_argument("--out", type=Path, default=Path("outputs"),
                    help=f"runs under OUT/{runs}, checkpoints under OUT/checkpoints (default: outputs)")
    ap.add_argument("--tables", type=Path, default=Path("outputs"), help=f"{made} (default: outputs)")
    ap.add_argument("--replot", action="store_true", help="rebuild from the saved runs only")
    ap.add_argument("--overwrite", action="store_true", help="replace the committed results")


def write_table(tables: Path, name: str, text: str, data, overwrite: bool) -> Path:
    """TABLES/tables/<name>.{md,json} (the markdown `text`, `data` as JSON), refusing to replace a committed one
    unless `overwrite`; returns the stem."""
    stem = tables / "tables" / name
    blob = json.dumps(data, indent=1)
    refuse_to_replace_committed([stem.with_suffix(".md"), stem.with_suffix(".json")], [text.encode(), blob.encode()],
                                overwrite, "--tables DIR")
    stem.parent.mkdir(parents=True, exist_ok=True)
    stem.with_suffix(".md").write_text(text)
    stem.with_suffix(".json").write_text(blob)
    return stem


def write_outputs(args, name: str, table: dict, markdown, plot) -> None:
    """A control's table (write_table, from `markdown(table)`) and figure TABLES/figures/<name>.png
    (`plot(table, path)`), under args.tables, then the table and what was written printed."""
    text = markdown(table)
    stem = write_table(args.tables, name, text, table, args.overwrite)
    figure = args.tables / "figures" / f"{name}.png"
    plot(table, figure)
    print(text)
    print(f"wrote {stem}.md, {stem}.json, {figure}")


def require_folders(**options: Path) -> None:
    """A one-line error where an output option (--out, --tables) names a file, or a folder inside one: found before
    a control runs, not when it writes its table at the end."""
    for name, path in options.items():
        p = Path(path)
        while not p.exists() and p != p.parent:
            p = p.parent
        if p.exists() and not p.is_dir():
            fail(f"error: --{name} {path}: {p} is a file, not a folder; give a folder")
