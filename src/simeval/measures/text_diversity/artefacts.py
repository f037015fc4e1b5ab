"""Build every artefact of a text-diversity report spec from the result.json files under `runs_dir`.

`<id>.{csv,md,tex}`, `<id>_all_metrics.*`, `<id>_rank_agreement.*` and `<id>_tidy.csv` depend only on the numbers
and settings in the records, so they are committed; `<id>_sources.csv` (which result.json, git sha and time each
cell came from) is not (.gitignore)."""

from __future__ import annotations

from pathlib import Path

from simeval.writing.tables import to_csv, write_table
from simeval.errors import UserError
from simeval.measures.text_diversity.table3 import (SOURCE_COLUMNS, STATISTICS, TIDY_COLUMNS, rank_agreement, source_rows,
                                           table3, tidy_rows)
from simeval.results import atomic_write_text, read_results


EXTENDED_CI_NOTE = (" 95% CIs over tasks: percentile bootstrap for div and cos_dist; jackknife for Vendi and Self-BLEU,"
                    " which resampling with replacement biases (a duplicate is not a new item).")


def build_text_diversity_report(runs_dir: str | Path, out_dir: str | Path, *, id: str, rows: list[dict],
                                columns: list[dict], caption: str = "", statistic: str = "div", digits: int = 2,
                                metric: str = "text_diversity") -> dict[str, list[Path]]:
    records = read_results(runs_dir, metric)
    if not records:
        raise UserError(f"no {metric} result.json under {runs_dir}: run the sweep first")
    tidy = tidy_rows(records)
    if not any(r["status"] == "ok" for r in tidy):
        # every pipeline's task source was missing (e.g. a fresh clone without the authors' files): writing would
        # replace a table of numbers with one of dashes
        missing = "; ".join(sorted({f"{r['pipeline']}: {r['note']}" for r in tidy if r.get("note")}))
        raise UserError(f"no {metric} run under {runs_dir} found any task descriptions, so nothing was written "
                        f"({missing or 'no values'}); configure the task sources (README, Table 3)")
    columns = list(columns)
    listed = {c["embedding"] for c in columns}
    for r in tidy:
        if r["embedding"] not in listed:
            listed.add(r["embedding"])
            columns.append({"embedding": r["embedding"], "display": r["embedding"]})
    out = Path(out_dir)
    written = {"tidy": [atomic_write_text(out / f"{id}_tidy.csv",
                                          to_csv(TIDY_COLUMNS, [[r[c] for c in TIDY_COLUMNS] for r in tidy]))],
               "sources": [atomic_write_text(out / f"{id}_sources.csv",
                                             to_csv(SOURCE_COLUMNS, source_rows(records, relative_to=Path.cwd())))]}
    header, body, notes = table3(tidy, rows, columns, statistic, digits)
    written["main"] = write_table(out / id, header, body, caption=caption, label=f"tab:{id}", notes=notes)
    ext_rows = []
    for stat in STATISTICS:
        h, b, _ = table3(tidy, rows, columns, stat, digits, with_ci=True)
        ext_rows += [[stat] + r for r in b]
    # the same statistics at a common subsample size (mean over random subsets), so group sizes do not matter
    common = [{**r, "value": r["subsample_mean"], "ci_low": None, "ci_high": None}
              for r in tidy if r["status"] == "ok" and r["subsample_mean"] is not None]
    sizes = sorted({r["subsample_n"] for r in common})
    for stat in STATISTICS:
        _, b, _ = table3(common, rows, columns, stat, digits)
        ext_rows += [[f"{stat} @ N={'/'.join(map(str, sizes))}"] + r for r in b]
    written["extended"] = write_table(out / f"{id}_all_metrics", ["Statistic"] + h, ext_rows,
                                      caption=caption + EXTENDED_CI_NOTE)
    h, b = rank_agreement(tidy, rows, columns, statistic)
    written["rank_agreement"] = write_table(out / f"{id}_rank_agreement", h, b,
                                            caption="Agreement of embedding models on the ordering of task groups.")
    return written
