"""Saving figures reproducibly: the same figure gives the same bytes on every run, so a committed PNG/PDF does
not change when nothing in it changed. Matplotlib otherwise stamps PDFs with the creation time (and SVGs with a
date); the Software/Producer lines only name the pinned matplotlib version and are dropped too."""

from __future__ import annotations

from pathlib import Path

# per format: metadata keys set to None are left out of the file
REPRODUCIBLE_METADATA = {
    "png": {"Software": None},
    "pdf": {"CreationDate": None, "ModDate": None, "Producer": None, "Creator": None},
    "svg": {"Date": None, "Creator": None},
}


def save_figure(fig, path: str | Path, **kwargs) -> Path:
    """fig.savefig(path, ...) without dates or tool versions in the file; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fmt = path.suffix.lstrip(".").lower()
    import matplotlib

    with matplotlib.rc_context({"svg.hashsalt": "simeval"}):  # SVG ids are random otherwise
        fig.savefig(path, metadata=REPRODUCIBLE_METADATA.get(fmt), **kwargs)
    return path
