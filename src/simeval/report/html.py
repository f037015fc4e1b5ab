"""One static HTML page for a run or sweep folder, built only from files already on disk (nothing is rerun).

`build_html_report(runs_dir, out_dir, tables_dir=..., figures_dir=...)` writes `<out_dir>/index.html` and copies
everything the page shows under `<out_dir>/assets/`, so every `src`/`href` is a relative path inside `out_dir`:
the folder can be zipped and opened on another machine. Sections:

- Runs: one row per result.json under `runs_dir` (metric, status, label or pipeline, git sha, headline values),
  each linking to a copy of its record (copied as `record.json`, never `result.json`: collectors that glob
  `result.json` under outputs/ must not count a report's copy as a run).
- Videos: per run, the mp4s it left beside its result.json (open-loop predictions of a world model, a policy's best
  and worst rollouts), played in the page.
- Tables: every Markdown table under `tables_dir` (as written by simeval.writing.tables), with links to its CSV/TeX.
- Figures: every PNG under `figures_dir` (PDF siblings linked).
- Quality gallery: per quality run, one card per task, the lowest-scoring first, with what the judge saw (the scene
  views and the trajectory frames sampled as simeval.measures.quality.run samples them, and the video when there is
  one) and every judge reply from `scores.jsonl`, so a reviewer sees why a task scored low. Bundles are found as
  simeval.measures.quality.task_media finds them; a run whose bundles are gone is shown with its scores, replies and a
  note saying so.

Records under `out_dir` are ignored, so a report written inside `runs_dir` does not report on itself.
"""

from __future__ import annotations

import html
import json
import re
import shutil
from collections.abc import Callable
from contextlib import contextmanager
from functools import partial
from pathlib import Path

from simeval.errors import UserError
from simeval.measures.quality.task_media import SCALES, find_bundles, judged_media, normalized, ordered_tasks
from simeval.results import RESULT_FILE, atomic_write_text, read_results

ASSETS = "assets"
LONG_TABLE_ROWS = 30
GENERATOR_TAG = '<meta name="generator" content="simeval.report.html">'  # marks a folder this module may rewrite
_SAFE = re.compile(r"[^A-Za-z0-9._-]+")

CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;margin:0 auto;max-width:1200px;padding:1rem 1.5rem;
color:#1d1d1f;background:#fafafa}
h1{font-size:1.6rem;margin-bottom:.2rem} h2{border-bottom:2px solid #ddd;padding-bottom:.2rem;margin-top:2rem}
h3{margin-bottom:.3rem} .muted{color:#666;font-size:.85rem}
table{border-collapse:collapse;margin:.5rem 0 1rem;font-size:.85rem;background:#fff}
th,td{border:1px solid #ddd;padding:.25rem .5rem;text-align:left;vertical-align:top} th{background:#f0f0f3}
td.num{text-align:right;font-variant-numeric:tabular-nums}
.status-ok{color:#1a7f37;font-weight:600} .status-failed,.status-stopped,.status-missing{color:#c62828;font-weight:600}
figure{display:inline-block;margin:.5rem;vertical-align:top;background:#fff;border:1px solid #ddd;padding:.4rem}
figure img{max-width:540px;max-height:420px} figcaption{font-size:.8rem;color:#444}
.card{background:#fff;border:1px solid #ddd;border-left:6px solid #999;border-radius:4px;padding:.6rem .9rem;
margin:.8rem 0}
.card.low{border-left-color:#c62828} .card.mid{border-left-color:#e6a700} .card.high{border-left-color:#1a7f37}
.card.failed{border-left-color:#6a1b9a}
.strip{display:flex;flex-wrap:wrap;gap:4px;align-items:flex-start;margin:.2rem 0 .5rem}
.strip img{width:128px;height:auto;border:1px solid #ccc;image-rendering:pixelated}
.strip video{width:256px;border:1px solid #ccc}
.label{font-size:.75rem;color:#555;margin-top:.4rem}
.reply{font-family:ui-monospace,monospace;font-size:.78rem;white-space:pre-wrap;background:#f6f6f6;padding:.15rem .3rem;
margin:.1rem 0;border-radius:3px} .reply.invalid{background:#fdecea}
.error{color:#c62828;font-size:.85rem} details summary{cursor:pointer}
nav a{margin-right:1rem}
"""


def _e(x) -> str:
    return html.escape("" if x is None else str(x), quote=True)


def _slug(text: str) -> str:
    return _SAFE.sub("_", text).strip("_") or "x"


def _fmt(x, digits: int = 2) -> str:
    if x is None:
        return "—"
    if isinstance(x, float):
        return f"{x:.{digits}f}"
    return str(x)


class _Assets:
    """Copies files under `<out_dir>/assets/<group>/` and hands back their paths relative to out_dir."""

    def __init__(self, out_dir: Path) -> None:
        self.out_dir = out_dir
        self.root = out_dir / ASSETS

    def copy(self, src: Path, group: str, name: str | None = None) -> str:
        dest = self.root / group / _slug(name or src.name)
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, dest)
        return dest.relative_to(self.out_dir).as_posix()

    def write_png(self, array, group: str, name: str) -> str:
        from PIL import Image as PILImage

        dest = self.root / group / _slug(name)
        dest.parent.mkdir(parents=True, exist_ok=True)
        PILImage.fromarray(array).save(dest)
        return dest.relative_to(self.out_dir).as_posix()


# ---------------------------------------------------------------------------------------------------- tables


def markdown_blocks(text: str) -> list[tuple[str, object]]:
    """[("table", (header, rows)) | ("text", line)] from a Markdown file as simeval.writing.tables writes it."""
    blocks: list[tuple[str, object]] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i].strip()
        if line.startswith("|") and i + 1 < len(lines) and re.fullmatch(r"\|(\s*:?-{3,}:?\s*\|)+", lines[i + 1].strip()):
            header = [c.strip() for c in line.strip("|").split("|")]
            rows, i = [], i + 2
            while i < len(lines) and lines[i].strip().startswith("|"):
                rows.append([c.strip() for c in lines[i].strip().strip("|").split("|")])
                i += 1
            blocks.append(("table", (header, rows)))
            continue
        if line:
            blocks.append(("text", line[2:] if line.startswith("- ") else line))
        i += 1
    return blocks


def _numeric(cell: str) -> bool:
    return bool(re.fullmatch(r"[-+]?[\d.]+(\s*[\[(][^\])]*[\])])?%?|—|-", cell))


def _html_table(header: list[str], rows: list[list[str]]) -> str:
    out = ["<table><thead><tr>" + "".join(f"<th>{_e(h)}</th>" for h in header) + "</tr></thead><tbody>"]
    for r in rows:
        cells = "".join(f"<td class='num'>{_e(c)}</td>" if _numeric(c) else f"<td>{_e(c)}</td>" for c in r)
        out.append(f"<tr>{cells}</tr>")
    out.append("</tbody></table>")
    return "\n".join(out)


PAPER_FIRST = re.compile(r"^(table|figure)\d")  # the paper's tables and figures lead; controls, oracle tables follow


def _reading_order(path: Path, root: Path) -> tuple:
    rel = path.relative_to(root)
    return (0 if PAPER_FIRST.match(rel.name) else 1, str(rel))


def _in_reading_order(folder: Path | None, pattern: str, kind: str) -> list[tuple[Path, Path, str]]:
    """(file, its path relative to folder, its asset group: kind/subfolder) of the files matching `pattern` below
    `folder`, the paper's first."""
    if not (folder and folder.is_dir()):
        return []
    files = sorted(folder.rglob(pattern), key=lambda f: _reading_order(f, folder))
    rels = [f.relative_to(folder) for f in files]
    return [(f, r, f"{kind}/{_slug(str(r.parent))}" if r.parent != Path(".") else kind) for f, r in zip(files, rels)]


def _section(folder: Path | None, pattern: str, kind: str, render: Callable[[Path, Path, str], list[str]]) -> str:
    """The HTML of every `pattern` file under `folder` in reading order, each as `render(file, relative path,
    asset group)` gives it; a line saying there are none otherwise."""
    files = _in_reading_order(folder, pattern, kind)
    if not files:
        return f"<p class='muted'>No {kind} under {_e(folder)}.</p>"
    return "\n".join(part for file, rel, group in files for part in render(file, rel, group))


def _table_html(md: Path, rel: Path, group: str, assets: _Assets) -> list[str]:
    links = [f"<a href='{_e(assets.copy(md, group))}'>md</a>"]
    for ext in (".csv", ".tex"):
        if md.with_suffix(ext).is_file():
            links.append(f"<a href='{_e(assets.copy(md.with_suffix(ext), group))}'>{ext[1:]}</a>")
    parts = [(f"<h3 id='table-{_e(_slug(str(rel)))}'>{_e(rel.with_suffix(''))}</h3>"
              f"<p class='muted'>{' · '.join(links)}</p>")]
    for kind, body in markdown_blocks(md.read_text(encoding="utf-8")):
        if kind != "table":
            parts.append(f"<p class='muted'>{_e(body)}</p>")
        elif len(body[1]) > LONG_TABLE_ROWS:  # folded, so a long table does not bury the gallery below it
            parts.append(f"<details><summary>{len(body[1])} rows (show)</summary>{_html_table(*body)}</details>")
        else:
            parts.append(_html_table(*body))
    return parts


def _figure_html(png: Path, rel: Path, group: str, assets: _Assets) -> list[str]:
    src = assets.copy(png, group)
    pdf = png.with_suffix(".pdf")
    pdf_link = f" · <a href='{_e(assets.copy(pdf, group))}'>pdf</a>" if pdf.is_file() else ""
    return [(f"<figure><a href='{_e(src)}'><img src='{_e(src)}' alt='{_e(rel)}'></a>"
             f"<figcaption>{_e(rel)}{pdf_link}</figcaption></figure>")]


# ------------------------------------------------------------------------------------------------------ runs


HEADLINE_VALUES = 6  # numbers per run in the runs table; a cut cell links to the whole record


def headline_values(rec: dict, limit: int = HEADLINE_VALUES) -> list[tuple[str, object]]:
    """A few (name, number) pairs that say what a record measured, for the runs table."""
    values = rec.get("values")
    if rec.get("metric") == "quality" and isinstance(values, dict):
        out = []
        for metric, per_task in values.items():
            means = [v["mean"] for v in per_task.values() if isinstance(v, dict) and v.get("mean") is not None]
            if means:
                out.append((f"{metric} (mean of {len(means)} tasks)", sum(means) / len(means)))
        return out
    if rec.get("metric") == "agreement" and isinstance(values, list):  # rows per (table, pipeline, judge)
        pooled = [v for v in values if isinstance(v, dict) and v.get("pipeline") == "all"] or values
        return [(f"{v.get('table')} {v.get('judge')} ({v.get('pipeline')}) r/MAE", v.get("r_over_mae"))
                for v in pooled[:limit] if isinstance(v, dict)]
    if rec.get("metric") == "dynamics_diversity" and isinstance(values, dict) and "prediction" in values:
        return dynamics_headline(values)
    flat: list[tuple[str, object]] = []

    def walk(x, prefix):
        if len(flat) >= limit:
            return
        if isinstance(x, dict):
            for k, v in x.items():
                walk(v, f"{prefix}.{k}" if prefix else str(k))
        elif isinstance(x, (int, float)) and not isinstance(x, bool):
            flat.append((prefix, x))

    walk(values, "")
    return flat[:limit]


def dynamics_headline(values: dict) -> list[tuple[str, object]]:
    """A held-out dynamics-diversity run: its gate's verdict in place of its numbers where the model does not beat
    the baselines (simeval.measures.dynamics_diversity.gate), else the primary number and its skills; then the state
    reading's line."""
    gate = values.get("gate")
    if values.get("prediction") is None:  # protocol.pixels=false: the state reading only
        out = [("pixel reading", "not read (protocol.pixels=false)")]
    elif gate is not None and not gate["passes"]:
        out = [("pixel reading", gate["verdict"])]
    else:
        one = values["prediction"]["summary"]["one_step"]
        out = [("object-focused one-step error (x1e-3/pixel)", 1e3 * one["model"]["object_error_per_pixel"]),
               ("skill vs last frame", one.get("object_skill_vs_last")),
               ("skill vs mean image", one.get("object_skill_vs_mean"))]
    if values.get("state"):
        out.append(("state reading", values["state"]["line"]))
    return out


def _run_name(rec: dict, runs_dir: Path) -> str:
    run_dir = Path(rec["path"]).parent
    try:
        rel = run_dir.resolve().relative_to(runs_dir.resolve())
    except ValueError:
        rel = run_dir
    return "." if str(rel) == "." else rel.as_posix()


def _runs_section(records: list[dict], names: list[str], assets: _Assets) -> str:
    rows = ["<table><thead><tr><th>Run</th><th>Metric</th><th>Status</th><th>Label / pipeline</th><th>Git sha</th>"
            "<th>Created</th><th>Values</th></tr></thead><tbody>"]
    for rec, name in zip(records, names):
        ident = rec.get("identity") or {}
        label = rec.get("label") or ident.get("pipeline") or ident.get("label") or ""
        if rec.get("judge"):
            label = f"{label} (judge: {rec['judge']})" if label else f"judge: {rec['judge']}"
        if ident.get("task_group"):
            label = f"{label} / {ident['task_group']}" if label else ident["task_group"]
        for key in ("embedding", "episodes", "policy", "preset"):  # what tells runs of one sweep apart
            if ident.get(key) is not None:
                label = f"{label} · {key} {ident[key]}"
        link = assets.copy(Path(rec["path"]), f"runs/{_slug(name)}", "record.json")
        status = rec.get("status", "ok")
        shown = headline_values(rec, limit=HEADLINE_VALUES + 1)
        values = "<br>".join(f"{_e(k)}: {_e(_fmt(v, 3))}" for k, v in shown[:HEADLINE_VALUES])
        if len(shown) > HEADLINE_VALUES:  # say that the cell is cut, and where the rest is
            values += f"<br><a href='{_e(link)}'>… all values</a>"
        gallery = (f" · <a href='#run-{_e(_slug(name))}'>gallery</a>" if rec.get("metric") == "quality" else "")
        rows.append(f"<tr><td><a href='{_e(link)}'>{_e(name)}</a>{gallery}</td><td>{_e(rec.get('metric'))}</td>"
                    f"<td class='status-{_e(status)}'>{_e(status)}</td><td>{_e(label)}</td>"
                    f"<td><code>{_e((rec.get('git_sha') or '')[:12])}</code></td><td>{_e(rec.get('created'))}</td>"
                    f"<td>{values}</td></tr>")
    rows.append("</tbody></table>")
    return "\n".join(rows)


VIDEOS_PER_RUN = 8  # a sweep of many runs stays a page, not a download


def _videos_section(records: list[dict], names: list[str], assets: _Assets) -> str:
    """The videos each run left beside its result.json (a world model's open-loop predictions, videos/*.mp4; a
    policy's best and worst rollouts, *.mp4), played in the page: what a number summarises, next to it."""
    parts = []
    for rec, name in zip(records, names):
        run_dir = Path(rec["path"]).parent
        videos = sorted({*run_dir.glob("*.mp4"), *run_dir.glob("videos/*.mp4")})
        if not videos:
            continue
        shown = videos[:VIDEOS_PER_RUN]
        more = f" (first {len(shown)} of {len(videos)})" if len(videos) > len(shown) else ""
        clips = []
        for v in shown:
            src = assets.copy(v, f"runs/{_slug(name)}/videos")
            clips.append(f"<figure><video controls muted preload='metadata' src='{_e(src)}'></video>"
                         f"<figcaption>{_e(v.stem)}</figcaption></figure>")
        parts.append(f"<h3>{_e(name)}{_e(more)}</h3><div class='strip'>{''.join(clips)}</div>")
    return "\n".join(parts) if parts else "<p class='muted'>No run here left videos.</p>"


# ------------------------------------------------------------------------------------------- quality gallery


def read_scores(path: Path) -> dict[tuple[str, str], list[dict]]:
    """{(task, metric): [score record, ...]} from a run's scores.jsonl ({} when absent: the oracle writes none)."""
    out: dict[tuple[str, str], list[dict]] = {}
    if not path.is_file():
        return out
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError as e:
            raise UserError(f"{path}: line {n} is not JSON ({e})") from e
        out.setdefault((rec["item"], rec["metric"]), []).append(rec)
    return out


def _media_strip(bundle, n_frames: int, assets: _Assets, group: str) -> str:
    """What the judge saw: the scene views, the sampled trajectory frames (and the video when there is one)."""
    media = judged_media(bundle, n_frames)
    parts = []
    if media.scene:
        srcs = [assets.copy(v, f"{group}/scene") for v in media.scene]
        imgs = "".join(f"<a href='{_e(s)}'><img src='{_e(s)}' alt='scene view {v.stem}' title='{_e(v.name)}'></a>"
                       for v, s in zip(media.scene, srcs))
        parts.append(f"<div class='label'>Scene views ({len(media.scene)})</div><div class='strip'>{imgs}</div>")
    if media.error:
        return "".join(parts) + f"<p class='error'>{_e(media.error)}</p>"
    srcs, titles = [], []
    for i, (path, array) in enumerate(media.frames):
        if path is not None:
            srcs.append(assets.copy(path, f"{group}/frames"))
            titles.append(path.name)
        else:
            srcs.append(assets.write_png(array, f"{group}/frames", f"frame{i:02d}.png"))
            titles.append(f"sampled frame {i}")
    vid = ""
    if media.video is not None:
        vsrc = assets.copy(media.video, f"{group}/video")
        vid = (f"<video controls muted preload='metadata' src='{_e(vsrc)}'></video>"
               f"<a href='{_e(vsrc)}'>{_e(media.video.name)}</a>")
        note = f"Trajectory: the {len(srcs)} sampled frames the judge saw, and the video"
    else:
        note = f"Trajectory: the {len(srcs)} of {media.n_total_frames} frames the judge saw"
    if srcs:
        imgs = "".join(f"<a href='{_e(s)}'><img src='{_e(s)}' alt='{_e(t)}' title='{_e(t)}'></a>"
                       for s, t in zip(srcs, titles))
        parts.append(f"<div class='label'>{_e(note)}</div><div class='strip'>{imgs}{vid}</div>")
    return "".join(parts)


def ground_truth_line(truth: dict) -> str:
    """`success: yes, progress: 1.00 (oracle completion 10.0 / 10)`: the simulator's verdict beside the judge's,
    the oracle completion computed as simeval.measures.quality.run.oracle_completion does."""
    parts = []
    if "success" in truth:
        parts.append(f"success: {'yes' if truth['success'] else 'no'}")
    if "progress" in truth:
        parts.append(f"progress: {truth['progress']:.2f}")
    oracle = 10.0 * truth["progress"] if "progress" in truth else (10.0 * truth["success"] if "success" in truth
                                                                    else None)
    return ", ".join(parts) + (f" (oracle completion {oracle:.1f} / 10)" if oracle is not None else "")


def _replies_html(score_recs: list[dict]) -> str:
    lines = []
    for r in sorted(score_recs, key=lambda r: r.get("repeat", 0)):
        for a in r.get("asks", []):
            cls = "reply" if a.get("valid") else "reply invalid"
            tag = f"repeat {r.get('repeat')} ask {a.get('ask')}" + ("" if a.get("valid") else f" — {a.get('error')}")
            lines.append(f"<div class='{cls}' title='{_e(tag)}'>[{_e(tag)}] {_e(a.get('reply'))}</div>")
    return "".join(lines)


def _quality_gallery(rec: dict, name: str, assets: _Assets) -> str:
    values = rec.get("values") or {}
    errors = rec.get("errors") or {}
    tasks = ordered_tasks(rec)
    scores = read_scores(Path(rec["path"]).parent / "scores.jsonl")
    bundles, note = find_bundles(rec)
    n_frames = int((rec.get("config") or {}).get("n_frames") or 8)
    judge = rec.get("judge")
    model = ((rec.get("config") or {}).get("judge") or {}).get("provider", {}) or {}
    title = f"{rec['label']} · run {name}" if rec.get("label") else f"run {name}"
    head = (f"<h3 id='run-{_e(_slug(name))}'>{_e(title)}</h3><p class='muted'>run {_e(name)} · "
            f"judge {_e(judge)}{(' (' + _e(model.get('model')) + ')') if model.get('model') else ''} · "
            f"{len(tasks)} tasks, lowest score first · {_e(rec.get('summary') or '')}</p>")
    if note:
        head += f"<p class='muted'>{_e(note)}</p>"
    cards = []
    for task in tasks:
        per_metric = {m: (values.get(m) or {}).get(task) for m in SCALES}
        known = [normalized(m, v.get("mean")) for m, v in per_metric.items() if v and v.get("mean") is not None]
        cls = "failed" if not known else ("low" if min(known) < 0.4 else "mid" if min(known) < 0.7 else "high")
        bundle = bundles.get(task)
        desc = bundle.description if bundle is not None else ""
        cells = []
        for m, v in per_metric.items():
            if v is None:
                continue
            lo, hi = SCALES[m]
            cells.append(f"<tr><td>{_e(m.replace('_', ' '))} ({lo:g}-{hi:g})</td><td class='num'>{_fmt(v.get('mean'))}"
                         f"</td><td class='num'>{_fmt(v.get('var'))}</td><td class='num'>{_e(v.get('n_valid'))}</td>"
                         f"<td class='num'>{_e(v.get('n_invalid'))}</td></tr>")
        score_table = ("<table><thead><tr><th>Score</th><th>Mean</th><th>Var</th><th>Valid</th><th>Invalid</th>"
                       "</tr></thead><tbody>" + "".join(cells) + "</tbody></table>") if cells else ""
        truth = ""
        if bundle is not None and bundle.ground_truth:
            truth = "<p class='muted'>Ground truth: " + _e(ground_truth_line(bundle.ground_truth)) + "</p>"
        media = _media_strip(bundle, n_frames, assets, f"quality/{_slug(name)}/{_slug(task)}") if bundle else ""
        replies = "".join(
            f"<details{' open' if cls in ('low', 'failed') else ''}><summary>Judge replies: "
            f"{_e(m.replace('_', ' '))} ({len(scores[(task, m)])} repeats)</summary>"
            f"{_replies_html(scores[(task, m)])}</details>" for m in SCALES if (task, m) in scores)
        err = f"<p class='error'>{_e(errors[task])}</p>" if task in errors else ""
        cards.append(f"<div class='card {cls}' id='task-{_e(_slug(name))}-{_e(_slug(task))}'><b>{_e(task)}</b>"
                     f"{' — ' + _e(desc) if desc else ''}{err}{score_table}{truth}{media}{replies}</div>")
    return head + "\n".join(cards)


# ------------------------------------------------------------------------------------------------------ page


def build_html_report(runs_dir: str | Path, out_dir: str | Path | None = None, *, tables_dir: str | Path | None = None,
                      figures_dir: str | Path | None = None, title: str = "simeval report") -> Path:
    """Write `<out_dir>/index.html` (default out_dir: `<runs_dir>/report`) and its assets; returns the page's path.
    A previous report's assets/ in out_dir are deleted first, so nothing stale is left linked; an assets/ folder
    that is not a report's (no index.html with GENERATOR_TAG beside it) is a UserError, never deleted."""
    runs_dir = Path(runs_dir)
    if not runs_dir.is_dir():
        raise UserError(f"report.runs_dir={str(runs_dir)!r} is not a folder: give a run or sweep folder "
                        "(e.g. outputs/runs or outputs/multiruns/quality/<time>)")
    out_dir = Path(out_dir) if out_dir else runs_dir / "report"
    out_dir.mkdir(parents=True, exist_ok=True)
    with _exclusive(out_dir / ".report.lock"):  # two reports into one folder take turns (each would delete assets/)
        return _build(runs_dir, out_dir, tables_dir, figures_dir, title)


@contextmanager
def _exclusive(lock_path: Path):
    """An exclusive advisory lock (fcntl.flock, released when the holder exits, even killed), so that concurrent
    reports into one folder run one after the other instead of deleting each other's assets mid-write."""
    import fcntl

    with open(lock_path, "w") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _build(runs_dir: Path, out_dir: Path, tables_dir, figures_dir, title: str) -> Path:
    out_resolved = out_dir.resolve()
    records = [r for r in read_results(runs_dir)
               if out_resolved not in Path(r["path"]).resolve().parents]
    records.sort(key=lambda r: (r.get("metric") or "", r.get("created") or "", r["path"]))
    if (out_dir / ASSETS).is_dir():
        page = out_dir / "index.html"
        if not (page.is_file() and GENERATOR_TAG in page.read_text(encoding="utf-8", errors="replace")):
            raise UserError(f"report.out_dir={str(out_dir)!r} already holds an assets/ folder that no simeval report "
                            "wrote (no index.html of ours beside it): choose an empty or new report.out_dir")
        shutil.rmtree(out_dir / ASSETS)  # a previous report's: nothing stale stays linked
    assets = _Assets(out_dir)
    names = [_run_name(r, runs_dir) for r in records]
    quality = [(r, n) for r, n in zip(records, names) if r.get("metric") == "quality"]
    gallery = "\n".join(_quality_gallery(r, n, assets) for r, n in quality) if quality else \
        "<p class='muted'>No quality runs here.</p>"
    counts = {}
    for r in records:
        counts[r.get("metric")] = counts.get(r.get("metric"), 0) + 1
    summary = ", ".join(f"{n} {m}" for m, n in sorted(counts.items(), key=lambda kv: str(kv[0]))) or "none"
    body = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width, initial-scale=1">
{GENERATOR_TAG}
<title>{_e(title)}</title><style>{CSS}</style></head><body>
<h1>{_e(title)}</h1>
<p class="muted">Built from the {RESULT_FILE} files under <code>{_e(runs_dir)}</code> ({_e(summary)}), the tables
under <code>{_e(tables_dir)}</code> and the figures under <code>{_e(figures_dir)}</code>. Nothing was rerun.</p>
<nav><a href="#runs">Runs</a><a href="#videos">Videos</a><a href="#tables">Tables</a><a href="#figures">Figures</a>
<a href="#quality">Quality gallery</a></nav>
<h2 id="runs">Runs ({len(records)})</h2>
{_runs_section(records, names, assets) if records else "<p class='muted'>No result.json here.</p>"}
<h2 id="videos">Videos</h2>
{_videos_section(records, names, assets)}
<h2 id="tables">Tables</h2>
<p class="muted">The files under <code>{_e(tables_dir)}</code> as they are (the paper's first): tables of whatever runs
built them (the committed ones unless rebuilt), not computed from the runs above.</p>
{_section(Path(tables_dir) if tables_dir else None, '*.md', 'tables', partial(_table_html, assets=assets))}
<h2 id="figures">Figures</h2>
{_section(Path(figures_dir) if figures_dir else None, '*.png', 'figures', partial(_figure_html, assets=assets))}
<h2 id="quality">Quality gallery</h2>
<p class="muted">Per task, what the judge saw and every reply it gave; the lowest-scoring tasks first (scores
normalised to [0, 1]; red below 0.4, amber below 0.7, purple: no valid score).</p>
{gallery}
</body></html>
"""
    return atomic_write_text(out_dir / "index.html", body)
