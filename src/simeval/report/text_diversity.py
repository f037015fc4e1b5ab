"""Table 3 (text diversity) from text_diversity result.json files.

Tidy rows: one per (pipeline, group, embedding, statistic) with value and 95% CI, or one per missing pipeline x
embedding with the config key that would provide it. Tables pivot those rows; nothing is recomputed.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Sequence

from simeval.metrics.agreement import kendall_tau_b
from simeval.metrics.text_diversity import STATISTICS
TIDY_COLUMNS = ["pipeline", "group", "embedding", "statistic", "value", "ci_low", "ci_high", "n", "status", "note",
                "subsample_n", "subsample_mean", "subsample_std", "version", "git_sha", "source"]


def latest_per_run_key(records: Iterable[dict]) -> list[dict]:
    """Newest record per (pipeline, embedding): a re-run replaces an older one rather than duplicating it."""
    best: dict[tuple, dict] = {}
    for rec in records:
        key = (rec.get("pipeline"), rec.get("embedding"))
        if key not in best or rec.get("created", "") >= best[key].get("created", ""):
            best[key] = rec
    return list(best.values())


def tidy_rows(records: Iterable[dict]) -> list[dict]:
    rows = []
    for rec in latest_per_run_key(records):
        base = {"pipeline": rec["pipeline"], "embedding": rec["embedding"], "version": rec.get("version"),
                "git_sha": rec.get("git_sha"), "source": rec.get("path")}
        if rec.get("status") == "missing":
            rows.append({**base, "group": None, "statistic": None, "status": "missing", "note": rec.get("missing_hint")})
            continue
        for group, v in rec["values"].items():
            if "error" in v:
                rows.append({**base, "group": group, "statistic": "div", "n": v.get("n"), "status": "error",
                             "note": v["error"]})
                continue
            sub = v.get("subsample") or {}
            for stat in STATISTICS:
                ci = v.get(f"{stat}_ci") or [None, None]
                rows.append({**base, "group": group, "statistic": stat, "value": v[stat], "ci_low": ci[0],
                             "ci_high": ci[1], "n": v["n"], "status": "ok", "subsample_n": sub.get("n"),
                             "subsample_mean": sub.get(f"{stat}_mean"), "subsample_std": sub.get(f"{stat}_std")})
    return [{c: r.get(c) for c in TIDY_COLUMNS} for r in rows]


def _lookup(rows: Sequence[dict]) -> dict[tuple, dict]:
    return {(r["pipeline"], r["group"], r["embedding"], r["statistic"]): r for r in rows if r["status"] != "missing"}


def _missing(rows: Sequence[dict]) -> dict[tuple, str]:
    return {(r["pipeline"], r["embedding"]): r["note"] for r in rows if r["status"] == "missing"}


def table3(rows: Sequence[dict], spec_rows: Sequence[dict], columns: Sequence[dict], statistic: str = "div",
           digits: int = 2, with_ci: bool = False) -> tuple[list[str], list[list[str]], list[str]]:
    """(header, rows, notes) in the paper's layout: Method | Task Group | one column per embedding model."""
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
                    if with_ci and r["ci_low"] is not None:
                        cell += f" [{r['ci_low']:.{digits}f}, {r['ci_high']:.{digits}f}]"
                    cells.append(cell)
            out.append([spec["display"], shown] + cells)
        for c in columns:
            if (p, c["embedding"]) in missing:
                notes.append(f"{spec['display']} [{c['display']}] missing: {missing[(p, c['embedding'])]}")
            elif not any(k[0] == p and k[2] == c["embedding"] for k in found):
                notes.append(f"{spec['display']} [{c['display']}] not run")
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
