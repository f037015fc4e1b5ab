"""Table 3 (text diversity) from text_diversity result.json files.

How records become cells. A cell is (pipeline, task group, embedding name): the embedding name is the column, so
two models shown side by side need two names (`embedding=hf embedding.name=mymodel`). Each record's `identity`
(simeval.results) says what it measured; the report reads it as
  - cell keys:     pipeline, embedding (and each group in `values`);
  - repeat key:    seed. Records of one cell that differ only in seed are repeats: the cell shows their mean,
                   `± std` over seeds when there are several, and the tidy table has n_seeds and seed_std;
  - coverage key:  task_group. A run of one group (`task_group=stacking`) fills that group's cell only; the other
                   groups keep their rows from the earlier complete run, and a note names which groups came from
                   which kind of run (file paths are in <id>_sources.csv, which git ignores);
  - settings:      everything else (version, model, source, tasks_sha, metric settings). Two records that claim
                   one cell with different settings are refused with a UserError naming both files: which one is
                   meant is the user's decision (rename the embedding, or move a run out of runs_dir).
Re-running a seed replaces the older record of that seed (the newest `created`, then the later path), so a
re-run is not counted twice. A `missing` record (pipeline source not configured) is noted only when no run of
that pipeline x embedding has values.

The committed outputs (tables and the tidy CSV) hold numbers and settings only, never paths, git shas or times,
so rebuilding them from the same numbers gives the same bytes; floats in the tidy CSV are rounded to 6 decimals
so that last-bit differences between machines do not show up as a changed file.

Tidy rows: one per (pipeline, group, embedding, statistic) with value and 95% CI, or one per missing pipeline x
embedding with the config key that would provide it. Tables pivot those rows; nothing is recomputed.
"""

from __future__ import annotations

import hashlib
import itertools
import statistics
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

from simeval.errors import UserError
from simeval.measures.agreement.metric import kendall_tau_b
from simeval.measures.text_diversity.metric import METRIC_VERSION, STATISTICS
from simeval.writing.paper_groups import paper_group
from simeval.results import identity_difference, record_identity

TIDY_COLUMNS = ["pipeline", "group", "embedding", "statistic", "value", "ci_low", "ci_high", "n", "status", "note",
                "subsample_n", "subsample_mean", "subsample_std", "version", "n_seeds", "seed_std", "seeds",
                "task_group"]
SOURCE_COLUMNS = ["pipeline", "group", "embedding", "seed", "task_group", "created", "git_sha", "path"]
CELL_KEYS = ("metric", "pipeline", "embedding")
COVERAGE_KEYS = ("task_group",)
REPEAT_KEYS = ("seed",)
TIDY_DECIMALS = 6


def run_record(pipeline: str, source, task_group, embedding: Mapping, metrics: Mapping, seed, overrides) -> dict:
    """What src/text_diversity.py writes beside its values: metric, version, seed, overrides, and the `identity` the
    report merges runs by (see the module docstring; tasks_sha is filled in once the tasks are loaded)."""
    backend = embedding["backend"]
    identity = {"pipeline": pipeline, "source": source, "tasks_sha": None, "task_group": task_group,
                "embedding": embedding["name"], "model": backend.get("model_id") or backend.get("model"),
                "settings": metrics}
    return {"metric": "text_diversity", "version": METRIC_VERSION, "seed": seed, "overrides": overrides,
            "pipeline": pipeline, "embedding": embedding["name"], "identity": identity}


def tasks_fingerprint(tasks: Iterable) -> str:
    """A short hash of the (group, text) pairs a run loaded: two runs on the same tasks share it wherever the
    files lie, and a run on an edited file does not."""
    h = hashlib.sha256()
    for group, text in sorted((t.group, t.text) for t in tasks):
        h.update(f"{group}\t{text}\n".encode())
    return h.hexdigest()[:16]


def _settings(identity: dict) -> dict:
    return {k: v for k, v in identity.items() if k not in CELL_KEYS + COVERAGE_KEYS + REPEAT_KEYS}


def _identity(rec: dict) -> dict:
    ident = record_identity(rec)
    ident.setdefault("pipeline", rec.get("pipeline"))
    ident.setdefault("embedding", rec.get("embedding"))
    ident.setdefault("task_group", (rec.get("config") or {}).get("task_group"))
    return ident


def select_cells(records: Iterable[dict]) -> tuple[dict[tuple, list[tuple[dict, dict]]], dict[tuple, dict]]:
    """({(pipeline, group, embedding): [(record, group values), one per seed]}, {(pipeline, embedding): newest
    missing record}). Raises UserError when two records claim a cell with different settings."""
    cells: dict[tuple, dict] = {}
    first: dict[tuple, dict] = {}
    missing: dict[tuple, dict] = {}
    for rec in sorted(records, key=lambda r: (r.get("created") or "", r.get("path") or "")):
        ident = _identity(rec)
        pe = (ident["pipeline"], ident["embedding"])
        if rec.get("status") == "missing":
            missing[pe] = rec
            continue
        if rec.get("status", "ok") != "ok":
            continue
        for group, v in (rec.get("values") or {}).items():
            group = paper_group(ident["pipeline"], group)  # the suites' table_top / table are the paper's table-top
            cell = (ident["pipeline"], group, ident["embedding"])
            if cell in first and _settings(_identity(first[cell])) != _settings(ident):
                other = first[cell]
                raise UserError(
                    f"{other.get('path')} and {rec.get('path')} both give {cell[0]}/{group} [{cell[2]}] but differ in "
                    f"{identity_difference(_settings(_identity(other)), _settings(ident))}: give one run a distinct "
                    "embedding.name=..., or move one out of report.runs_dir")
            first.setdefault(cell, rec)
            cells.setdefault(cell, {})[ident.get("seed")] = (rec, v)  # sorted oldest first: a re-run replaces
    return ({cell: [by_seed[s] for s in sorted(by_seed, key=lambda s: (s is None, s if s is not None else 0))]
             for cell, by_seed in cells.items()},
            {pe: rec for pe, rec in missing.items() if not any(c[0] == pe[0] and c[2] == pe[1] for c in cells)})


def _mean(xs: list) -> float | None:
    xs = [x for x in xs if x is not None]
    return statistics.fmean(xs) if xs else None


def _round(x):
    return round(x, TIDY_DECIMALS) if isinstance(x, float) else x


def tidy_rows(records: Iterable[dict]) -> list[dict]:
    cells, missing = select_cells(records)
    rows = []
    for (pipeline, embedding), rec in sorted(missing.items()):
        rows.append({"pipeline": pipeline, "embedding": embedding, "version": rec.get("version"), "status": "missing",
                     "note": rec.get("missing_hint")})
    for (pipeline, group, embedding), runs in cells.items():
        recs = [r for r, _ in runs]
        base = {"pipeline": pipeline, "group": group, "embedding": embedding,
                "version": "/".join(sorted({str(r.get("version")) for r in recs})),
                "n_seeds": len(runs), "seeds": ";".join(str(_identity(r).get("seed")) for r in recs),
                "task_group": ";".join(sorted({str(_identity(r).get("task_group")) for r in recs}))}
        ok = [v for _, v in runs if "error" not in v]
        if not ok:
            v = runs[-1][1]
            rows.append({**base, "statistic": "div", "n": v.get("n"), "status": "error", "note": v["error"]})
            continue
        subs = [v.get("subsample") or {} for v in ok]
        same_sub = len({s.get("n") for s in subs}) == 1
        for stat in STATISTICS:
            vals = [v[stat] for v in ok]
            cis = [v.get(f"{stat}_ci") or [None, None] for v in ok]
            rows.append({**base, "statistic": stat, "value": _mean(vals), "ci_low": _mean([c[0] for c in cis]),
                         "ci_high": _mean([c[1] for c in cis]), "n": ok[0]["n"], "status": "ok",
                         "n_seeds": len(ok), "seed_std": statistics.stdev(vals) if len(vals) > 1 else None,
                         "subsample_n": subs[0].get("n") if same_sub else None,
                         "subsample_mean": _mean([s.get(f"{stat}_mean") for s in subs]) if same_sub else None,
                         "subsample_std": _mean([s.get(f"{stat}_std") for s in subs]) if same_sub else None})
    return [{c: _round(r.get(c)) for c in TIDY_COLUMNS} for r in rows]


def source_rows(records: Iterable[dict], relative_to: str | Path | None = None) -> list[list]:
    """Which result.json each cell's numbers came from (for <id>_sources.csv; not committed: paths and shas)."""
    cells, _ = select_cells(records)
    out = []
    for (pipeline, group, embedding), runs in sorted(cells.items()):
        for rec, _ in runs:
            path = Path(rec.get("path") or "")
            if relative_to is not None:
                try:
                    path = path.resolve().relative_to(Path(relative_to).resolve())
                except ValueError:
                    pass
            ident = _identity(rec)
            out.append([pipeline, group, embedding, ident.get("seed"), ident.get("task_group"), rec.get("created"),
                        rec.get("git_sha"), str(path)])
    return out


def _lookup(rows: Sequence[dict]) -> dict[tuple, dict]:
    return {(r["pipeline"], r["group"], r["embedding"], r["statistic"]): r for r in rows if r["status"] != "missing"}


def _missing(rows: Sequence[dict]) -> dict[tuple, str]:
    return {(r["pipeline"], r["embedding"]): r["note"] for r in rows if r["status"] == "missing"}


def _describe_runs(task_group: str, seeds: str) -> str:
    seeds = seeds.split(";")
    return f"task_group={task_group}, seed{'s' if len(seeds) > 1 else ''} {', '.join(seeds)}"


def table3(rows: Sequence[dict], spec_rows: Sequence[dict], columns: Sequence[dict], statistic: str = "div",
           digits: int = 2, with_ci: bool = False) -> tuple[list[str], list[list[str]], list[str]]:
    """(header, rows, notes) in the paper's layout: Method | Task Group | one column per embedding model.
    A cell averaged over several seeds reads `mean ± std`; a column whose groups come from different runs gets a
    note saying which (see the module docstring)."""
    found, missing = _lookup(rows), _missing(rows)
    header = ["Method", "Task Group"] + [c["display"] for c in columns]
    out, notes = [], []
    for spec in spec_rows:
        p = spec["pipeline"]
        for group, shown in spec["groups"].items():
            cells = []
            for c in columns:
                r = found.get((p, group, c["embedding"], statistic))
                if r is None:
                    cells.append("—")
                elif r["status"] == "error":
                    cells.append("undefined")
                    notes.append(f"{spec['display']} {shown} [{c['display']}]: {r['note']}")
                else:
                    cell = f"{r['value']:.{digits}f}"
                    if (r.get("n_seeds") or 1) > 1:
                        cell += f" ± {r['seed_std']:.{digits}f}"
                        notes.append("x ± s: mean and standard deviation over repeated seeds")
                    if with_ci and r["ci_low"] is not None:
                        cell += f" [{r['ci_low']:.{digits}f}, {r['ci_high']:.{digits}f}]"
                    cells.append(cell)
            out.append([spec["display"], shown] + cells)
        for c in columns:
            if (p, c["embedding"]) in missing:
                notes.append(f"{spec['display']} [{c['display']}] missing: {missing[(p, c['embedding'])]}")
            elif not any(k[0] == p and k[2] == c["embedding"] for k in found):
                notes.append(f"{spec['display']} [{c['display']}] not run")
            runs: dict[tuple, list[str]] = {}
            for group, shown in spec["groups"].items():
                r = found.get((p, group, c["embedding"], statistic))
                if r is not None:
                    runs.setdefault((r.get("task_group") or "?", str(r.get("seeds"))), []).append(shown)
            if len(runs) > 1:
                parts = [f"{', '.join(shown)} from {_describe_runs(*key)}" for key, shown in runs.items()]
                notes.append(f"{spec['display']} [{c['display']}] rows come from different runs: {'; '.join(parts)} "
                             "(files in the _sources.csv beside this table)")
    return header, out, list(dict.fromkeys(notes))


def rank_agreement(rows: Sequence[dict], spec_rows: Sequence[dict], columns: Sequence[dict],
                   statistic: str = "div") -> tuple[list[str], list[list[str]]]:
    """Kendall tau between embedding models on the ordering of each pipeline's groups (`all` excluded), and
    over every pipeline's groups pooled. The paper found the models disagree; this makes it visible."""
    found = _lookup(rows)
    header = ["Scope", "Model A", "Model B", "Groups", "Kendall tau"]
    out = []
    scopes = [(s["display"], [(s["pipeline"], g) for g in s["groups"] if g != "all"]) for s in spec_rows]
    scopes.append(("All pipelines", [k for _, ks in scopes for k in ks]))
    for (name, keys), (a, b) in itertools.product(scopes, itertools.combinations(columns, 2)):
        pairs = [(found.get((p, g, a["embedding"], statistic)), found.get((p, g, b["embedding"], statistic)))
                 for p, g in keys]
        pairs = [(ra["value"], rb["value"]) for ra, rb in pairs if ra and rb and ra["status"] == rb["status"] == "ok"]
        if not pairs:
            continue
        tau = kendall_tau_b([x for x, _ in pairs], [y for _, y in pairs])
        out.append([name, a["display"], b["display"], str(len(pairs)), "undefined" if tau is None else f"{tau:.2f}"])
    return header, out
