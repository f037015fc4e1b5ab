"""Saving figures reproducibly: the same figure gives the same bytes on every run, so a committed PNG/PDF does
not change when nothing in it changed. Matplotlib otherwise stamps PDFs with the creation time (and SVGs with a
date); the Software/Producer lines only name the pinned matplotlib version and are dropped too."""

from __future__ import annotations

import os
from pathlib import Path

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
    path.parent.mkdir(parents=True, exist_ok=True)
    fmt = path.suffix.lstrip(".").lower()
    import matplotlib

    partial = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        with matplotlib.rc_context({"svg.hashsalt": "simeval"}):  # SVG ids are random otherwise
            fig.savefig(partial, format=fmt, metadata=REPRODUCIBLE_METADATA.get(fmt), **kwargs)
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)
    return path


def distinct_colors(n: int) -> list:
    """`n` colours, one per row of a figure: matplotlib's ten (C0-C9) while they suffice, then tab20's lighter
    shade of each in the same order (rows 11-20), then again. A figure with more rows than colours must neither
    drop a row nor draw two rows alike without saying so; past 20 the colours repeat (the legend still names each)."""
    from matplotlib import colormaps

    if n <= 10:
        return [f"C{i}" for i in range(n)]
    tab20 = colormaps["tab20"]
    return [tab20((2 * (i % 10) + (i // 10) % 2) / 19.999) for i in range(n)]
