"""Saving figures reproducibly: the same figure gives the same bytes on every run, so a committed PNG/PDF does
not change when nothing in it changed. Matplotlib otherwise stamps PDFs with the creation time (and SVGs with a
date); the Software/Producer lines only name the pinned matplotlib version and are dropped too."""

from __future__ import annotations

from pathlib import Path

from simeval.results import atomic_path
from simeval.errors import UserError

# per format: metadata keys set to None are left out of the file
REPRODUCIBLE_METADATA = {
    "png": {"Software": None},
    "pdf": {"CreationDate": None, "ModDate": None, "Producer": None, "Creator": None},
    "svg": {"Date": None, "Creator": None},
}


def save_figure(fig, path: str | Path, **kwargs) -> Path:
    """fig.savefig(path, ...) without dates or tool versions in the file; returns the path. Written beside `path`
    and renamed over it, so a run killed while saving leaves the previous figure (a committed one too), not a
    truncated file."""
    path = Path(path)
    fmt = path.suffix.lstrip(".").lower()
    import matplotlib

    with atomic_path(path) as tmp, matplotlib.rc_context({"svg.hashsalt": "simeval"}):  # SVG ids: random otherwise
        fig.savefig(tmp, format=fmt, metadata=REPRODUCIBLE_METADATA.get(fmt), **kwargs)
    return path


# filled shapes that stay apart at 5-6 pt; a row's marker, with its colour, tells rows apart where two of
# distinct_colors' shades are close (tab20's pairs: a row 11-20 beside the row ten before it)
ROW_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">", "p", "h", "*", "d")


def row_markers(n: int) -> list[str]:
    """`n` marker shapes, one per row of a figure, in ROW_MARKERS' order; past its 13 they repeat (with other
    colours: distinct_colors repeats only past 20)."""
    return [ROW_MARKERS[i % len(ROW_MARKERS)] for i in range(n)]


def cut_wide_intervals(ax, drawn: list[tuple[str, object, object, object]], pad: float = 0.15,
                       min_spread: float = 0.5) -> list[str]:
    """y-limits for `ax` that hold every drawn point with `pad` of their spread (at least `min_spread`: a skill's
    scale) around them, and every interval that fits there; a wider interval (one row's few moving pixels) is cut
    at the panel's edge instead of squeezing the other rows into a strip. `drawn`: (row name, values, lows, highs)
    per line. Returns what was cut, one entry per row and edge ("gensim/assembling down to -1.72"), for the
    caller to say beside the panel; empty (and the limits left as drawn) when every interval fits."""
    import numpy as np

    def finite(key: int) -> np.ndarray:
        parts = [np.asarray(d[key], dtype=float).ravel() for d in drawn]
        values = np.concatenate(parts) if parts else np.array([])
        return values[np.isfinite(values)]

    points, lows, highs = finite(1), finite(2), finite(3)
    if not points.size:
        return []
    spread = max(points.max() - points.min(), min_spread)
    bottom, top = points.min() - pad * spread, points.max() + pad * spread
    if lows.min(initial=bottom) >= bottom and highs.max(initial=top) <= top:
        return []  # every interval fits near the points: matplotlib's own limits
    lowest, highest = {}, {}
    for name, _, lo, hi in drawn:
        lowest[name] = min(lowest.get(name, np.inf), np.nanmin(np.asarray(lo, dtype=float), initial=np.inf))
        highest[name] = max(highest.get(name, -np.inf), np.nanmax(np.asarray(hi, dtype=float), initial=-np.inf))
    cut = [f"{name} down to {v:.2f}" for name, v in lowest.items() if v < bottom]
    cut += [f"{name} up to {v:.2f}" for name, v in highest.items() if v > top]
    low, high = max(lows.min(), bottom), min(highs.max(), top)
    margin = 0.04 * (high - low)
    ax.set_ylim(low - margin, high + margin)
    return cut


def distinct_colors(n: int) -> list:
    """`n` colours, one per row of a figure: matplotlib's ten (C0-C9) while they suffice, then tab20's lighter
    shade of each in the same order (rows 11-20), then again. A figure with more rows than colours must neither
    drop a row nor draw two rows alike without saying so; past 20 the colours repeat (the legend still names each)."""
    from matplotlib import colormaps

    if n <= 10:
        return [f"C{i}" for i in range(n)]
    tab20 = colormaps["tab20"]
    return [tab20((2 * (i % 10) + (i // 10) % 2) / 19.999) for i in range(n)]


def check_figure_formats(key: str, formats: list[str]) -> None:
    """Each of `formats` a file type matplotlib writes, else a UserError naming `key`: checked before any work,
    since matplotlib refuses an unknown one only when the figure is saved, after the tables."""
    from matplotlib.backend_bases import FigureCanvasBase

    known = sorted(FigureCanvasBase.get_supported_filetypes())
    unknown = [f for f in formats if f not in known]
    if unknown:
        raise UserError(f"{key}: {', '.join(map(repr, unknown))} is not a figure format matplotlib writes; "
                        f"expected {', '.join(known)}")
