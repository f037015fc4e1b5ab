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

    _remove_partials_of_dead_runs(path)
    partial = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        with matplotlib.rc_context({"svg.hashsalt": "simeval"}):  # SVG ids are random otherwise
            fig.savefig(partial, format=fmt, metadata=REPRODUCIBLE_METADATA.get(fmt), **kwargs)
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)
    return path


def _remove_partials_of_dead_runs(path: Path) -> None:
    """A run killed mid-save leaves `.<name>.<pid>.partial` beside the figure: the next save removes those whose
    process is gone (a live one may be another run saving the same figure right now)."""
    for partial in path.parent.glob(f".{path.name}.*.partial"):
        pid = partial.name.removeprefix(f".{path.name}.").removesuffix(".partial")
        if not pid.isdigit():
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            partial.unlink(missing_ok=True)
        except PermissionError:  # alive, another user's
            continue


def distinct_colors(n: int) -> list:
    """`n` colours, one per row of a figure: matplotlib's ten (C0-C9) while they suffice, then tab20's lighter
    shade of each in the same order (rows 11-20), then again. A figure with more rows than colours must neither
    drop a row nor draw two rows alike without saying so; past 20 the colours repeat (the legend still names each)."""
    from matplotlib import colormaps

    if n <= 10:
        return [f"C{i}" for i in range(n)]
    tab20 = colormaps["tab20"]
    return [tab20((2 * (i % 10) + (i // 10) % 2) / 19.999) for i in range(n)]
