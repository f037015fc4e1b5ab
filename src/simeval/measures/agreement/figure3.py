"""Figure 3 of the paper: the judges' agreement with human scores (Pearson r / MAE) per pipeline, from
simeval.measures.agreement.run.agreement_rows."""

from __future__ import annotations

import os
from pathlib import Path


def plot_figure3(rows: list[dict], stem: str | os.PathLike, formats=("png", "pdf")) -> list[Path]:
    """Bar charts of Pearson r / MAE per judge, one panel per table, one bar per pipeline. Negative bars are
    truncated at 0 as in the paper; undefined values are marked 'n/a'."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from simeval.writing.figures import save_figure

    tables = list(dict.fromkeys(r["table"] for r in rows))
    widths = [max(2, len({r["judge"] for r in rows if r["table"] == t})) for t in tables]
    fig, axes = plt.subplots(1, len(tables), figsize=(sum(widths) * 1.3 + 1, 3.6),
                             gridspec_kw={"width_ratios": widths}, squeeze=False)
    for ax, table in zip(axes[0], tables):
        sub = [r for r in rows if r["table"] == table and r["pipeline"] != "all"]
        judges = list(dict.fromkeys(r["judge"] for r in sub))
        pipelines = list(dict.fromkeys(r["pipeline"] for r in sub))
        w = 0.8 / max(1, len(pipelines))
        for k, p in enumerate(pipelines):
            xs, ys = [], []
            for j, judge in enumerate(judges):
                r = next((r for r in sub if r["pipeline"] == p and r["judge"] == judge), None)
                x = j + (k - (len(pipelines) - 1) / 2) * w
                # labels sit a few points above the bar's top (or 0), never across a thin bar
                if r is None or r["r_over_mae"] is None:
                    ax.annotate("n/a", (x, 0), xytext=(0, 3), textcoords="offset points", ha="center",
                                va="bottom", fontsize=7, rotation=90)
                    continue
                xs.append(x)
                ys.append(max(0.0, r["r_over_mae"]))
                if r["r_over_mae"] < 0.05:  # negative: drawn at 0 as the paper does; tiny: too thin to see. Written
                    ax.annotate(f"{r['r_over_mae']:.2f}", (x, ys[-1]), xytext=(0, 3), textcoords="offset points",
                                ha="center", va="bottom", fontsize=7, rotation=90,
                                color="crimson" if r["r_over_mae"] < 0 else "black")
            ax.bar(xs, ys, width=w, label=p)
        ax.set_xticks(range(len(judges)))
        ax.set_xlim(-0.5, len(judges) - 0.5)  # every judge's slot, also where no bar is drawn (n/a labels)
        ax.set_xticklabels(judges, rotation=30, ha="right", fontsize=8)
        ax.set_title(table.replace("_", " "))
        ax.set_ylabel("Pearson r ÷ MAE")
        ax.legend(fontsize=8)
    fig.text(0.01, 0.005, "Negative r/MAE is drawn at 0 and its value written in red, one near 0 in black; n/a: undefined "
             "(a constant column).", fontsize=7, ha="left", va="bottom")
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    out = []
    for fmt in formats:
        out.append(save_figure(fig, Path(stem).with_suffix(f".{fmt}"), dpi=150))  # no dates in the file
    plt.close(fig)
    return out
