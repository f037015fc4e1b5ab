"""The README's results at a glance: docs/img/glance.png, one small panel per paper table, drawn only from the
committed tables (outputs/tables/*.csv|json, and Figure 3's outputs/figures/figure3/agreement.csv), so it is
redrawn without rerunning anything:

    .venv/bin/python docs/glance.py            # or: make docs
    .venv/bin/python docs/glance.py --out /tmp/glance.png   # elsewhere (tests/test_docs.py compares the bytes)

Panels: Table 3 (text diversity, Eq. 1), Table 4 under the paper's protocol (eval error per pixel against episodes,
ours beside the paper's), Table 4 held-out with the validity gate (the skill the gate reads, per row), Table 5 (the
eval split: success with its Wilson interval, random actions and the paper's value), Figure 3 (judge-human r/MAE)
and the controls drawn at random (how each reading's 12 draws came out)."""

from __future__ import annotations

import argparse
import csv
import json
import math
import re
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402

from simeval.measures.dynamics_diversity.gate import TOO_WIDE  # noqa: E402  the verdict a fall too uncertain reads

ROOT = Path(__file__).resolve().parents[1]
TABLES = ROOT / "outputs" / "tables"
FIGURE3 = ROOT / "outputs" / "figures" / "figure3" / "agreement.csv"
OUT = ROOT / "docs" / "img" / "glance.png"

PAPER_PIXELS = 128 * 128 * 3  # the paper's Table 4 sums its error over 128x128x3 pixels
GATE_MARGIN = 0.05  # protocol.gate.margin: the skill a count needs against the last frame (and the mean image)
COLOURS = {"gensim": "#4c72b0", "gensim_own": "#55a868", "robogen": "#dd8452", "bbsea": "#c44e52",
           "metaworld": "#8172b3"}
NAMES = {"gensim": "GenSim-style", "gensim_own": "GenSim's own", "robogen": "RoboGen-style", "bbsea": "BBSEA-style",
         "metaworld": "Meta-World"}


def _rows(name: str) -> list[dict[str, str]]:
    with open(TABLES / name, newline="") as f:
        return list(csv.DictReader(f))


def _number(text: str) -> float:
    return float(text) if text not in ("", "-", "—") else math.nan


def _rate(cell: str) -> tuple[float, float, float] | None:
    """'0.12 [0.06, 0.24] (6/50)' -> (0.12, 0.06, 0.24); '-' -> None."""
    m = re.match(r"([\d.]+) \[([\d.]+), ([\d.]+)\]", cell)
    return tuple(float(x) for x in m.groups()) if m else None


def table3(ax) -> None:
    rows = [r for r in _rows("table3.csv") if r["MiniLM-L6-v2"] not in ("", "—")]
    labels = [f"{r['Method']} {r['Task Group']}" for r in rows]
    y = range(len(rows))
    for k, (col, colour) in enumerate([("MiniLM-L6-v2", "#4c72b0"), ("Mpnet-base-v2", "#dd8452")]):
        vals = [float(r[col]) for r in rows]
        ax.barh([i + (k - 0.5) * 0.38 for i in y], vals, height=0.38, color=colour, label=col)
    ax.set_yticks(list(y), labels)
    ax.invert_yaxis()
    ax.set_xlabel("text diversity (Eq. 1)")
    ax.set_title("Table 3: text diversity of task descriptions")
    ax.set_xlim(0, 1.5)
    ax.legend(loc="upper right", fontsize=9)
    ax.text(0.98, 0.03, "BBSEA: no published\ntask list (not run)", transform=ax.transAxes, ha="right", fontsize=9,
            color="0.35")


def table4_paper(ax) -> None:
    counts = (10, 20, 40)
    falls = 0
    for r in _rows("table4.csv"):
        falls += _number(r["ours_10"]) > _number(r["ours_20"]) > _number(r["ours_40"])
        c = COLOURS[r["pipeline"]]
        ours = [_number(r[f"ours_{n}_per_pixel"]) * 1e3 for n in counts]
        paper = [_number(r[f"paper_{n}"]) / PAPER_PIXELS * 1e3 for n in counts]
        ax.plot(counts, ours, "-o", color=c, ms=3, lw=1.4)
        ax.plot(counts, paper, "--", color=c, lw=1, alpha=0.8)
    for r in _rows("table4_paper.csv"):
        if r["preset"] == "paper":
            ax.plot(counts, [_number(r[f"ours_{n}_per_pixel"]) * 1e3 for n in counts], "-s", color="black", ms=4,
                    lw=1.6)
    ax.set_yscale("log")
    ax.set_xticks(counts, [str(n) for n in counts])
    ax.set_xlabel("training episodes per task")
    ax.set_ylabel("eval error per pixel (x1e-3)")
    ax.set_title(f"Table 4, paper protocol: error falls in {falls} of {len(_rows('table4.csv'))} groups")
    handles = [Line2D([], [], color=COLOURS[p], lw=2, label=NAMES[p]) for p in ("gensim", "robogen", "bbsea")]
    handles += [Line2D([], [], color="0.3", ls="-", label="ours (cpu preset)"),
                Line2D([], [], color="0.3", ls="--", label="the paper's"),
                Line2D([], [], color="black", marker="s", label="ours, BBSEA table, paper preset")]
    low, high = ax.get_ylim()
    ax.set_ylim(low / 8, high)  # an empty decade below the lowest line for the key, which covered it
    ax.legend(handles=handles, fontsize=8, loc="lower left", ncol=2)


def _gate_verdicts() -> list[str]:
    """The gate column of the committed table4_heldout.md, one cell per count (the CSV does not carry it)."""
    lines = [x for x in (TABLES / "table4_heldout.md").read_text().splitlines() if x.startswith("|")]
    column = [c.strip() for c in lines[0].strip("|").split("|")].index("gate (pixels)")
    return [[c.strip() for c in x.strip("|").split("|")][column] for x in lines[2:]]


def table4_heldout(ax) -> None:
    rows = _rows("table4_heldout.csv")
    verdicts = _gate_verdicts()
    reads = sum(not v.startswith("no reading") for v in verdicts)
    markers = {10: "o", 20: "s", 40: "^"}
    for i, r in enumerate(rows):
        c = COLOURS[r["pipeline"]]
        skills = {n: _number(r[f"one_step_object_skill_last_{n}"]) for n in markers}
        if r.get("state_fall_verdict"):  # the state reading's verdict on the fall, where the row has one
            # the verdict's head only ("no reading: why ..." is a sentence), in a column of its own right of the
            # axes: inside, "state: no reading" crossed the gate line
            verdict = ("too wide" if r["state_fall_verdict"].startswith(TOO_WIDE)
                       else r["state_fall_verdict"].split(" (")[0].split(":")[0])
            ax.text(1.02, i, f"state: {verdict}", va="center", ha="left", fontsize=7, color="0.2",
                    transform=ax.get_yaxis_transform())
        if all(math.isnan(s) for s in skills.values()):
            ax.text(-2, i, "no skill: too few pixels move", va="center", ha="right", fontsize=8, color="0.35")
            continue
        for n, s in skills.items():
            ax.plot(s, i, markers[n], mfc="none", color=c, ms=5)
    ax.set_xscale("symlog", linthresh=1)
    ax.set_xlim(-3000, 3)
    ax.axvline(GATE_MARGIN, color="black", lw=1)
    ax.text(GATE_MARGIN, len(rows) - 0.7, "gate 0.05 ", fontsize=8, ha="right", va="bottom")
    ax.set_yticks(range(len(rows)), [f"{NAMES[r['pipeline']]} {r['group']}" for r in rows], fontsize=8)
    ax.set_ylim(len(rows) - 0.5, -0.7)
    ax.set_xlabel("object-focused one-step skill vs last frame")
    ax.legend(handles=[Line2D([], [], marker=m, ls="", mfc="none", color="0.3", label=f"{n} episodes")
                       for n, m in markers.items()], fontsize=8, loc="lower left")
    # read: every count passed the state gate (a fall too uncertain to tell is a read group's verdict)
    states = [v for v in (r.get("state_fall_verdict") for r in rows)
              if v and (not v.startswith("no reading") or v.startswith(TOO_WIDE))]
    wide = sum(v.startswith(TOO_WIDE) for v in states)
    ax.set_title(f"Table 4 held-out: {reads} of {len(verdicts)} counts pass the pixel gate"
                 + (f";\nstate reading falls 10 -> 40 in {sum(v == 'falls' for v in states)} of {len(states)} "
                    "groups read" + (f",\n{wide} too wide to tell" if wide else "") if states else ""))


def table5(ax) -> None:
    trained: dict[tuple[str, str], dict[str, str]] = {}
    chance: dict[tuple[str, str], dict[str, str]] = {}
    for r in _rows("table5.csv"):
        key = (r["Pipeline"], r["Task group"])
        if r["Policy"].startswith("random"):
            chance[key] = r
        elif key not in trained or int(r["Runs"]) > int(trained[key]["Runs"]):  # the row with most training seeds
            trained[key] = r
    keys = list(trained)
    for i, key in enumerate(keys):
        r, c = trained[key], COLOURS[key[0]]
        rate = _rate(r["Ours: eval (varied)"])
        if rate:
            ax.errorbar(rate[0], i, xerr=[[rate[0] - rate[1]], [rate[2] - rate[0]]], fmt="o", color=c, ms=5,
                        capsize=2)
        else:
            ax.text(0.3, i, "eval: no scene varied", va="center", fontsize=8, color="0.35")
        if key[0].startswith("gensim") and not math.isnan(_number(r["Ours: eval progress"])):
            ax.plot(_number(r["Ours: eval progress"]), i, "D", mfc="none", color=c, ms=6)
        random_rate = _rate(chance[key]["Ours: eval (varied)"]) if key in chance else None
        if random_rate:
            ax.plot(random_rate[0], i + 0.25, "o", mfc="none", color="0.45", ms=5)
        if not math.isnan(_number(r["Paper"])):
            ax.plot(_number(r["Paper"]), i, "x", color="black", ms=7, mew=1.6)
    ax.set_yticks(range(len(keys)), [f"{NAMES[p]} {g}" for p, g in keys], fontsize=8)
    ax.set_ylim(len(keys) - 0.5, -0.7)
    ax.set_xlim(-0.02, 0.75)
    ax.set_xlabel("eval split (varied scenes)")
    ax.set_title("Table 5: Diffusion Policy on a task group")
    handles = [Line2D([], [], marker="o", ls="", color="0.2", label="success rate [Wilson 95%]"),
               Line2D([], [], marker="D", ls="", mfc="none", color="0.2", label="GenSim: step-wise reward"),
               Line2D([], [], marker="o", ls="", mfc="none", color="0.45", label="random actions: success"),
               Line2D([], [], marker="x", ls="", color="black", mew=1.6, label="the paper")]
    ax.legend(handles=handles, fontsize=8, loc="lower right")


def figure3(ax) -> None:
    with open(FIGURE3, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["Pipeline"] == "all"]
    for i, r in enumerate(rows):
        colour = "#4c72b0" if r["Table"] == "scene_alignment" else "#dd8452"
        m = re.match(r"(-?[\d.]+) \[(-?[\d.]+), (-?[\d.]+)\]", r["r_over_mae"])
        if not m:
            ax.text(0, i, r["r_over_mae"], va="center", ha="center", fontsize=8, color="0.35")
            continue
        v, lo, hi = (float(x) for x in m.groups())
        ax.errorbar(v, i, xerr=[[v - lo], [hi - v]], fmt="o", color=colour, ms=5, capsize=2)
    ax.axvline(0, color="0.6", lw=0.8)
    ax.set_yticks(range(len(rows)), [r["Judge"] for r in rows], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("r / MAE against humans, 20 tasks [bootstrap 95%]")
    ax.set_title("Figure 3: judge-human agreement")
    ax.legend(handles=[Line2D([], [], marker="o", ls="", color="#4c72b0", label="scene alignment"),
                       Line2D([], [], marker="o", ls="", color="#dd8452", label="task completion")],
              fontsize=8, loc="lower right")


def random_controls(ax) -> None:
    counts = json.loads((TABLES / "random_controls.json").read_text())["counts"]
    order = [("right", "#55a868"), ("gated", "#bbbbbb"), ("too wide", "#8c8c8c"), ("no order", "#ccb974"),
             ("wrong", "#c44e52")]
    labels = list(counts)
    for i, name in enumerate(labels):
        left = 0
        for verdict, colour in order:
            n = counts[name].get(verdict, 0)  # "too wide": a verdict the first tables did not have
            ax.barh(i, n, left=left, color=colour)
            if n:
                text = f"{n} {verdict}" if n > 2 else f"{n}\n{verdict}"  # a narrow segment: two short lines
                ax.text(left + n / 2, i, text, ha="center", va="center", fontsize=9 if n > 2 else 8)
            left += n
    ax.set_yticks(range(len(labels)), [s.replace("/", " / ") for s in labels])
    ax.invert_yaxis()
    ax.set_xlim(0, counts[labels[0]]["draws"])
    ax.set_xlabel("draws; verdict of each (none read the wrong order)")
    ax.set_title("Controls drawn at random (12 draws per family)")


def main(out: Path = OUT) -> None:
    plt.rcParams.update({"font.size": 10, "axes.titlesize": 11})
    fig, axes = plt.subplots(2, 3, figsize=(17, 10.5))
    for draw, ax in zip((table3, table4_paper, table4_heldout, table5, figure3, random_controls), axes.flat):
        draw(ax)
    fig.suptitle("simeval's committed results at a glance (outputs/tables/)", fontsize=13)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90, metadata={"Software": None})  # no tool version inside: the same bytes every run
    plt.close(fig)
    print(f"wrote {out}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=OUT, help=f"the PNG to write (default: {OUT.relative_to(ROOT)})")
    main(parser.parse_args().out)
