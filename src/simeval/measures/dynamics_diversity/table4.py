"""Paper Table 4 from dynamics_diversity result.json records: the world model's eval error after training on 3
numbers of episodes per task, per pipeline and group, the paper's values (simeval.writing.paper_values) beside ours.

    rows = build(read_results(root, "dynamics_diversity"), episodes=(10, 20, 40))
    write(rows, "outputs/tables/table4", episodes=(10, 20, 40))   # table4.csv (numbers), .md, .tex
    plot(rows, "outputs/figures/table4.png")                      # and table4.pdf beside it

Only runs of protocol=paper count here (simeval.measures.dynamics_diversity.table4_heldout tabulates protocol=heldout
runs). One row per (pipeline, group, world-model preset) that has runs at one of the chosen episode counts, plus a
paper-only row for every paper cell that has none. `ours_<k>` is the mean eval image error (summed over pixels at
the preset's resolution) of the runs trained on the k-th of `episodes` (several seeds of one cell are averaged;
failed runs are left out), `ours_<k>_per_pixel` the same per pixel and colour channel, `runs_<k>` how many runs
were averaged. The paper sums over 128x128x3 pixels: compare shapes (how the error falls with episodes) and
per-pixel values, not raw magnitudes.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

from simeval.errors import UserError
from simeval.writing.paper_groups import suite_group
from simeval.writing.paper_values import TABLE4 as PAPER
from simeval.writing.paper_values import TABLE4_EPISODES as EPISODES
from simeval.writing.paper_values import TABLE4_PIXELS as PAPER_PIXELS
from simeval.writing.tables import read_csv, to_csv, to_latex, to_markdown
from simeval.results import atomic_write_text

METRIC = "dynamics_diversity"


def _order(pipeline: str) -> int:
    return list(PAPER).index(pipeline) if pipeline in PAPER else len(PAPER)


def _flat(d, prefix: str = "") -> dict:
    if not isinstance(d, dict):
        return {prefix: d}
    out: dict = {}
    for k, v in d.items():
        out.update(_flat(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


def one_setting(row_key: tuple, recs: list[dict]) -> None:
    """A UserError when the runs of one table row differ in their settings (world model, window, evaluation) or
    camera: a row averages seeds of one setting and compares its episode counts, so runs made with, say, windows of
    40 and of 20 under one preset name must not meet in it."""
    flats = [_flat({"settings": r["identity"]["settings"], "camera": r["identity"].get("camera")})
             for r in recs if "settings" in r["identity"]]
    keys = sorted({k for f in flats for k in f if len({repr(g.get(k)) for g in flats}) > 1})
    if keys:
        p, g, pr = row_key
        seen = sorted({repr(f.get(keys[0])) for f in flats})
        named = [k.removeprefix("settings.") for k in keys]
        raise UserError(f"{p}/{g} (preset {pr}): its runs differ in {', '.join(named)} ({named[0]}: "
                        f"{', '.join(seen)}); a row holds runs of one setting: give the report a folder with one "
                        "setting's runs (report.runs_dir=..., or --root where a script takes it)")


def build(records: list[dict], *, episodes: tuple[int, ...] | list[int] = EPISODES, preset: str | None = None
          ) -> list[dict]:
    """Rows of Table 4 (see the module docstring); `episodes`: our training-episode counts, one per paper column
    (the quick profile trains on 1/2/4 in the columns of the paper's 10/20/40); `preset`: only runs of that
    world_model preset."""
    episodes = [int(k) for k in episodes]
    if len(episodes) != len(EPISODES):
        raise UserError(f"episodes={episodes}: give {len(EPISODES)} counts, one per paper column "
                        f"({'/'.join(map(str, EPISODES))})")
    cells: dict = defaultdict(list)
    for rec in records:
        ident = rec.get("identity") or {}
        if rec.get("metric") != METRIC or rec.get("status") != "ok" or (preset and ident.get("preset") != preset):
            continue
        # protocol=heldout runs: simeval.measures.dynamics_diversity.table4_heldout
        if ident.get("protocol", "paper") != "paper":
            continue
        if int(ident["episodes"]) not in episodes:  # see unused_episodes
            continue
        cells[(ident["pipeline"], ident["task_group"], int(ident["episodes"]), ident["preset"])].append(rec)
    keys = sorted({(p, g, pr) for p, g, _, pr in cells} | {(p, g, None) for p in PAPER for g in PAPER[p]},
                  key=lambda x: (_order(x[0]), x[1], str(x[2])))
    ours_pg = {(p, suite_group(p, g)) for p, g, pr in keys if pr is not None}
    rows = []
    for p, g, pr in keys:
        if pr is None and (p, g) in ours_pg:
            continue
        row = {"pipeline": p, "group": g, "preset": pr or ""}
        one_setting((p, g, pr), [r for k in episodes for r in cells.get((p, g, k, pr), [])])
        for k, ours_k in zip(EPISODES, episodes):
            row[f"paper_{k}"] = PAPER.get(p, {}).get(suite_group(p, g), {}).get(k)
            row[f"episodes_{k}"] = ours_k
            recs = cells.get((p, g, ours_k, pr), [])
            vals = [r["values"]["eval"]["image_error"] for r in recs]
            pix = [r["values"]["eval"]["image_error_per_pixel"] for r in recs]
            row[f"ours_{k}"] = sum(vals) / len(vals) if vals else None
            row[f"ours_{k}_per_pixel"] = sum(pix) / len(pix) if pix else None
            row[f"runs_{k}"] = len(recs)
        rows.append(row)
    return rows


def _cell_columns(k: int) -> list[str]:
    return [f"paper_{k}", f"episodes_{k}", f"ours_{k}", f"ours_{k}_per_pixel", f"runs_{k}"]


def read_rows(path: str | Path) -> list[dict]:
    """The rows of a table `write` made, from its CSV, numbers parsed (for `merge`)."""
    lines = [cells for cells in read_csv(path) if cells]  # blank lines (an editor's trailing newline) say nothing
    need = ["pipeline", "group", "preset"] + [c for k in EPISODES for c in _cell_columns(k)]
    if len(lines) < 2 or lines[0] != need:
        raise UserError(f"{path}: not a Table 4 CSV (written by src/report.py report=table4): "
                        + ("no rows" if len(lines) < 2 else f"its header should be {','.join(need[:4])},..."))
    whole = {c for c in need if c.startswith(("episodes_", "runs_"))}
    rows = []
    for i, cells in enumerate(lines[1:], start=2):
        if len(cells) != len(need):
            raise UserError(f"{path}, line {i}: {len(cells)} cells, expected {len(need)}")
        row = dict(zip(need[:3], cells[:3]))
        for c, v in zip(need[3:], cells[3:]):
            try:
                row[c] = None if v == "" else (int if c in whole else float)(v)
            except ValueError:
                raise UserError(f"{path}, line {i}, column {c}: {v!r} is not a number") from None
        rows.append(row)
    return rows


def merge(kept: list[dict], fresh: list[dict], episodes: tuple[int, ...] | list[int] = EPISODES) -> list[dict]:
    """`fresh` rows (from result.json files, built with these `episodes`) with every cell they have no run for taken
    from `kept` (an earlier table's rows, read_rows): a table extended with runs made on another machine, whose
    result.json files are not here. A cell is (pipeline, group, preset, column); a paper-only row is dropped once
    its group has ours. Kept rows must have our runs on the same `episodes` in each column."""
    def key(r):
        return r["pipeline"], r["group"], r["preset"]

    merged = {key(r): dict(r) for r in fresh}
    for old in kept:
        if not old["preset"]:
            continue  # a paper-only row: the paper's values come from paper_values, not from the file
        for k, ours_k in zip(EPISODES, episodes):
            if old[f"episodes_{k}"] != int(ours_k):
                raise UserError(f"{old['pipeline']}/{old['group']}: the kept table's column {k} holds runs on "
                                f"{old[f'episodes_{k}']} episodes per task, this table's on {ours_k} (report.episodes="
                                f"[{','.join(map(str, episodes))}]): build both with the same report.episodes")
        if key(old) not in merged:
            merged[key(old)] = dict(old)
            continue
        row = merged[key(old)]
        for k in EPISODES:
            if not row[f"runs_{k}"]:
                for c in _cell_columns(k)[2:]:
                    row[c] = old[c]
    ours = {(p, suite_group(p, g)) for (p, g, pr) in merged if pr}
    rows = [r for r in merged.values() if r["preset"] or (r["pipeline"], suite_group(r["pipeline"], r["group"]))
            not in ours]
    return sorted(rows, key=lambda r: (_order(r["pipeline"]), r["group"], r["preset"]))


def unused_episodes(records: list[dict], episodes: tuple[int, ...] | list[int] = EPISODES) -> list[int]:
    """The training-episode counts of ok runs that a table with columns `episodes` leaves out (say so to the
    user: the quick profile's 1/2/4-episode runs beside the cpu preset's 10/20/40 ones give two tables)."""
    return sorted({int((r.get("identity") or {})["episodes"]) for r in records
                   if r.get("metric") == METRIC and r.get("status") == "ok"
                   and (r.get("identity") or {}).get("protocol", "paper") == "paper"} - {int(k) for k in episodes})


def _fmt(v, digits: int = 1) -> str:
    return "—" if v is None else f"{v:.{digits}f}"


def suggested_columns(unused: list[int] | tuple[int, ...], episodes: list[int] | tuple[int, ...]) -> list[int]:
    """Counts for a table that shows the unused runs: a table has one count per paper column, so fewer unused
    counts than columns are filled up with the shown ones (whose runs exist), more are cut to the smallest."""
    counts = sorted({int(k) for k in unused})[:len(EPISODES)]
    counts += [int(k) for k in episodes if int(k) not in counts][:len(EPISODES) - len(counts)]
    return sorted(counts)


def display(rows: list[dict], episodes: tuple[int, ...] | list[int] = EPISODES,
            unused: list[int] | tuple[int, ...] = ()) -> tuple[list[str], list[list[str]], list[str]]:
    """(header, body, notes) of the Markdown and LaTeX tables: 'paper / ours' per column, ours per pixel."""
    header = (["Method", "Task group", "preset"] + [f"Eval error on {k} ep (paper / ours)" for k in EPISODES]
              + [f"ours per pixel at {'/'.join(map(str, EPISODES))}"])
    body = [[r["pipeline"], r["group"], r["preset"] or "—"]
            + [f"{_fmt(r[f'paper_{k}'])} / {_fmt(r[f'ours_{k}'])}" for k in EPISODES]
            + [" / ".join(_fmt(r[f"ours_{k}_per_pixel"], 5) for k in EPISODES)] for r in rows]
    notes = [(f"Paper: image error summed over 128x128x3 pixels in [0, 1] (per pixel = value / {PAPER_PIXELS}). "
              "Ours: the same sum at the preset's resolution; '—' = not run")]
    if [int(k) for k in episodes] != list(EPISODES):
        notes.append(f"Ours trained on {'/'.join(map(str, episodes))} episodes per task in the columns of the "
                     f"paper's {'/'.join(map(str, EPISODES))}")
    if unused:  # in the table itself, not only on the console: a reader of the file sees why a cell is '—'
        notes.append(f"Runs trained on {'/'.join(map(str, unused))} episodes per task exist but are not in this "
                     f"table (its columns are {'/'.join(map(str, episodes))}): build one for them with "
                     f"report.episodes=[{','.join(map(str, suggested_columns(unused, episodes)))}]")
    return header, body, notes


def write(rows: list[dict], stem: str | Path, episodes: tuple[int, ...] | list[int] = EPISODES,
          unused: list[int] | tuple[int, ...] = ()) -> dict[str, Path]:
    """`<stem>.csv` (every number of the rows, for scripts), `<stem>.md` and `<stem>.tex` (booktabs) as shown."""
    stem = Path(stem)
    header, body, notes = display(rows, episodes, unused)
    caption = ("World-model evaluation error with a different number of training episodes per task (paper Table 4: "
               "for a diverse task group the error drops as the training episodes increase).")
    return {"csv": atomic_write_text(stem.with_suffix(".csv"),
                                     to_csv(list(rows[0]), [[r[c] for c in rows[0]] for r in rows])),
            "md": atomic_write_text(stem.with_suffix(".md"), to_markdown(header, body, notes)),
            "tex": atomic_write_text(stem.with_suffix(".tex"),
                                     to_latex(header, body, caption=caption, label="tab:table4", notes=notes))}


def plot(rows: list[dict], path: str | Path, formats: tuple[str, ...] = ("png", "pdf")) -> list[Path]:
    """Eval error per pixel against training episodes per task: the paper's (left) and ours (right), one colour
    per pipeline/group in both panels, one marker per preset. Written as `path` with each suffix of `formats`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from simeval.writing.figures import distinct_colors, save_figure

    groups = list(dict.fromkeys((r["pipeline"], suite_group(r["pipeline"], r["group"])) for r in rows))
    color = dict(zip(groups, distinct_colors(len(groups)), strict=True))
    presets = list(dict.fromkeys(r["preset"] for r in rows if r["preset"]))
    marker = {pr: "os^Dv<>"[i % 7] for i, pr in enumerate(presets)}
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10.5, 4.2))
    drawn_paper, drawn_ours = set(), set()
    for r in rows:
        pg = (r["pipeline"], suite_group(r["pipeline"], r["group"]))
        paper = [r[f"paper_{k}"] for k in EPISODES]
        if all(v is not None for v in paper) and pg not in drawn_paper:
            drawn_paper.add(pg)
            ax1.plot(EPISODES, [v / PAPER_PIXELS for v in paper], "o--", color=color[pg], alpha=0.8)
        ours = [(r[f"episodes_{k}"], r[f"ours_{k}_per_pixel"]) for k in EPISODES
                if r[f"ours_{k}_per_pixel"] is not None]
        if ours:
            drawn_ours.add(pg)
            ax2.plot(*zip(*ours), "-", marker=marker[r["preset"]], color=color[pg])
    ours_ticks = sorted({r[f"episodes_{k}"] for r in rows for k in EPISODES})
    for ax, title, ticks, drawn in ((ax1, "paper (128x128)", EPISODES, drawn_paper),
                                    (ax2, "ours", ours_ticks, drawn_ours)):
        ax.set_xticks(ticks)
        ax.set_xlabel("training episodes per task")
        ax.set_ylabel("eval error per pixel")
        ax.set_title(title)
        tops = [y for line in ax.get_lines() for y in line.get_ydata()]
        ax.set_ylim(0, 1.08 * max(tops) if tops else 1)  # from 0, so the drop with episodes is seen at its scale
        ax.grid(alpha=0.3)
        if not drawn:
            ax.text(0.5, 0.5, "no runs", ha="center", va="center", transform=ax.transAxes, color="0.5")
    handles = [Line2D([], [], color=color[(p, g)], lw=2, label=f"{p}/{g}") for p, g in groups]
    handles += [Line2D([], [], color="0.3", ls="--", marker="o", label="paper")]
    handles += [Line2D([], [], color="0.3", ls="-", marker=marker[pr], label=f"ours ({pr})") for pr in presets]
    fig.legend(handles=handles, loc="center left", bbox_to_anchor=(0.83, 0.5), fontsize=8, frameon=False)
    fig.suptitle("Table 4: world-model evaluation error vs training episodes")
    fig.tight_layout(rect=(0, 0, 0.83, 1))
    path = Path(path)
    written = [save_figure(fig, path.with_suffix(f".{fmt}"), dpi=120) for fmt in formats]  # byte-reproducible
    plt.close(fig)
    return written
