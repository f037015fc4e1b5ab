"""One pipeline's scorecard: each aspect's reading (or why it has none) beside the committed reference rows of the
pipelines simeval has measured (GenSim, RoboGen, BBSEA, Meta-World), from result.json files and committed tables
only. src/evaluate.py runs the measures and calls `build` and `write`.

A card is {"pipeline", "aspects": [aspect, ...]}; an aspect is
    {"aspect": name, "reading": "reads" | "no reading" | "skipped", "line": one sentence a user reads,
     "value": a number or None, "unit": str, "references": [{"pipeline", "group", "value", "text"}, ...]}
Aspects: text_diversity (Eq. 1 of the paper, all-MiniLM-L6-v2: Table 3's MiniLM column), quality (the oracle
judge's completion score from recorded success; references: the suites' expert success rates), dynamics_diversity
(Table 4 held-out: the gate's verdict per training-episode count and the fall's; references: the committed rows),
generalization (Table 5: needs an environment to roll a policy out in).
"""

from __future__ import annotations

import csv
import html
import json
from pathlib import Path

from simeval.errors import UserError

ASPECTS = ("text_diversity", "quality", "dynamics_diversity", "generalization")
AXES = {"text_diversity": "Eq. 1 (higher: more diverse texts)",
        "quality": "oracle score (references: suites' expert success x 10)",
        "generalization": "success rate on the eval (varied) scenes, else train"}
TITLES = {"text_diversity": "Text diversity (Table 3, Eq. 1, MiniLM)", "quality": "Quality (oracle judge, 0-10)",
          "dynamics_diversity": "Dynamics diversity (Table 4 held-out, gated)",
          "generalization": "Generalization (Table 5)"}


def aspect(name: str, reading: str, line: str, value: float | None = None, unit: str = "",
           references: list[dict] | None = None) -> dict:
    if name not in ASPECTS or reading not in ("reads", "no reading", "skipped"):
        raise ValueError(f"aspect {name!r} / reading {reading!r}")
    return {"aspect": name, "reading": reading, "line": line, "value": value, "unit": unit,
            "references": references or []}


def _rows(path: Path) -> list[dict]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def _number(text: str) -> float | None:
    try:
        return float(str(text).split()[0])
    except (ValueError, IndexError):
        return None


def references(tables: str | Path) -> dict[str, list[dict]]:
    """The committed reference rows per aspect, from the tables folder (outputs/tables); an aspect whose table is
    missing has none (a fresh clone has them all)."""
    tables = Path(tables)
    out: dict[str, list[dict]] = {a: [] for a in ASPECTS}
    if (tables / "table3.csv").is_file():
        for r in _rows(tables / "table3.csv"):
            v = _number(r.get("MiniLM-L6-v2", ""))
            out["text_diversity"].append({"pipeline": r["Method"], "group": r["Task Group"], "value": v,
                                          "text": f"{v:.2f}" if v is not None else "-"})
    for p in sorted(tables.glob("oracle_success_*.csv")):
        if p.stem.endswith(("_episodes", "_eval")) or "_eval_" in p.stem:
            continue
        done = total = 0
        for r in _rows(p):
            a, _, b = str(r.get("Success", "")).partition("/")
            if a.isdigit() and b.isdigit():
                done, total = done + int(a), total + int(b)
        if total:
            out["quality"].append({"pipeline": p.stem[len("oracle_success_"):], "group": "all",
                                   "value": 10 * done / total, "text": f"{10 * done / total:.2f} "
                                   f"({done}/{total} expert episodes succeed)"})
    if (tables / "table4_heldout.csv").is_file():
        from simeval.measures.dynamics_diversity.table4_heldout import read_rows, row_gate

        for r in read_rows(tables / "table4_heldout.csv"):
            counts = [int(k) for k in str(r["counts"]).split("/")]
            verdicts = [row_gate(r, k) for k in counts]
            read = [str(k) for k, (ok, _) in zip(counts, verdicts) if ok]
            text = (f"reads at {'/'.join(read)} episodes" if read else
                    f"no reading at {'/'.join(map(str, counts))} episodes")
            out["dynamics_diversity"].append({"pipeline": r["pipeline"], "group": r["group"], "value": None,
                                              "text": text + (f"; fall: {r['fall_verdict']}"
                                                              if r.get("fall_verdict") else "")})
    if (tables / "table5.csv").is_file():
        for r in _rows(tables / "table5.csv"):
            if str(r.get("Policy", "")).startswith("random"):
                continue
            cell = r.get("Ours: eval (varied)", "")
            out["generalization"].append({"pipeline": r["Pipeline"], "group": f"{r['Task group']} ({r['Policy']})",
                                          "value": _number(cell), "text": cell or "-"})
    return out


def build(pipeline: str, aspects: list[dict], tables: str | Path) -> dict:
    refs = references(tables)
    for a in aspects:
        a["references"] = a["references"] or refs[a["aspect"]]
    return {"pipeline": pipeline, "aspects": aspects}


def lines(card: dict) -> list[str]:
    """One line per aspect: what it reads, or "no reading: " / "skipped: " and why."""
    return [f"{a['aspect']}: {_verdict(a)}" for a in card["aspects"]]


def _verdict(a: dict) -> str:
    """The aspect's line, led by its reading where that is not "reads" (the line says why, not whether)."""
    if a["reading"] == "reads" or a["line"].startswith(a["reading"]):
        return a["line"]
    return f"{a['reading']}: {a['line']}"


def markdown(card: dict) -> str:
    out = [f"# Scorecard: {card['pipeline']}", "", *([f"**{card['note']}**", ""] if card.get("note") else []),
           *[f"- {x}" for x in lines(card)], ""]
    for a in card["aspects"]:
        out += [f"## {TITLES[a['aspect']]}", "", f"**{card['pipeline']}**: {_verdict(a)}", ""]
        if a["references"]:
            out += ["| reference pipeline | group | reading |", "|---|---|---|"]
            out += [f"| {r['pipeline']} | {r['group']} | {r['text']} |" for r in a["references"]]
            out.append("")
    return "\n".join(out)


def _html(card: dict) -> str:
    e = html.escape
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>Scorecard: {e(card['pipeline'])}</title>",
             "<style>body{font-family:system-ui,sans-serif;max-width:1000px;margin:auto;padding:1rem}"
             "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:2px 8px}"
             ".no{color:#a00}.reads{color:#070}</style></head><body>",
             f"<h1>Scorecard: {e(card['pipeline'])}</h1>"
             + (f"<p><b>{e(card['note'])}</b></p>" if card.get("note") else "") + "<img src='scorecard.png' alt='scorecard figure' "
             "style='max-width:100%'><ul>"]
    parts += [f"<li class='{'reads' if a['reading'] == 'reads' else 'no'}'>{e(a['aspect'])}: {e(a['line'])}</li>"
              for a in card["aspects"]]
    parts.append("</ul>")
    for a in card["aspects"]:
        parts.append(f"<h2>{e(TITLES[a['aspect']])}</h2><p><b>{e(card['pipeline'])}</b>: {e(a['line'])}</p>")
        if a["references"]:
            parts.append("<table><tr><th>reference pipeline</th><th>group</th><th>reading</th></tr>")
            parts += [f"<tr><td>{e(r['pipeline'])}</td><td>{e(r['group'])}</td><td>{e(r['text'])}</td></tr>"
                      for r in a["references"]]
            parts.append("</table>")
    return "".join(parts) + "</body></html>\n"


def plot(card: dict, path: Path) -> None:
    """A panel per aspect: the pipeline's value (red) beside the references' (grey) where the aspect has numbers;
    the line in words where it has none."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(card["aspects"]), figsize=(4.2 * len(card["aspects"]), 4.2), squeeze=False)
    for ax, a in zip(axes[0], card["aspects"]):
        refs = [r for r in a["references"] if r["value"] is not None]
        ax.set_title(TITLES[a["aspect"]], fontsize=9)
        if a["value"] is None and not refs or a["aspect"] == "dynamics_diversity":
            import textwrap

            ax.text(0.02, 0.98, textwrap.fill(a["line"], 40, break_long_words=False), va="top", fontsize=7,
                    transform=ax.transAxes,
                    color="tab:green" if a["reading"] == "reads" else "tab:red")
            ax.axis("off")
            continue
        names = [f"{r['pipeline']}/{r['group']}" for r in refs]
        values = [r["value"] for r in refs]
        colors = ["0.6"] * len(refs)
        if a["value"] is not None:
            names, values, colors = [card["pipeline"], *names], [a["value"], *values], ["tab:red", *colors]
        ax.barh(range(len(values)), values, color=colors)
        for i, v in enumerate(values):  # a zero is a reading too, not a missing bar
            ax.text(v, i, f" {v:.2f}", va="center", fontsize=6)
        ax.set_yticks(range(len(values)), names, fontsize=6)
        ax.invert_yaxis()
        label = AXES.get(a["aspect"], "")
        if a["value"] is None:
            import textwrap

            label += "\n" + textwrap.fill(f"{card['pipeline']}: {a['line']}", 50)
        ax.set_xlabel(label, fontsize=7, color="k" if a["value"] is not None else "tab:red")
    fig.suptitle(f"simeval scorecard: {card['pipeline']}" + (f" ({card['note']})" if card.get("note") else ""),
                 fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write(card: dict, out_dir: str | Path) -> dict[str, Path]:
    """scorecard.{md,csv,html,json,png} in `out_dir`."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {k: out / f"scorecard.{k}" for k in ("md", "csv", "html", "json", "png")}
    paths["md"].write_text(markdown(card))
    with paths["csv"].open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["aspect", "pipeline", "group", "reading", "value", "text"])
        for a in card["aspects"]:
            w.writerow([a["aspect"], card["pipeline"], "", a["reading"], "" if a["value"] is None else a["value"],
                        a["line"]])
            for r in a["references"]:
                w.writerow([a["aspect"], r["pipeline"], r["group"], "reference",
                            "" if r["value"] is None else r["value"], r["text"]])
    paths["json"].write_text(json.dumps(card, indent=1))
    paths["html"].write_text(_html(card))
    plot(card, paths["png"])
    return paths


def read(path: str | Path) -> dict:
    try:
        return json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise UserError(f"{path}: not a scorecard ({e})") from e
