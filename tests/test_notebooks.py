"""The notebooks' code cells run, in order, against the current library (so they cannot rot)."""

import json
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


def test_the_notebooks_are_found():
    # An empty parametrization is a skip, not a failure: without this a moved notebooks/ folder tests nothing.
    assert "quickstart.ipynb" in [p.name for p in NOTEBOOKS], "notebooks/quickstart.ipynb not found"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_code_runs(path, capsys):
    namespace: dict = {}
    for cell in json.loads(path.read_text())["cells"]:
        if cell["cell_type"] == "code":
            exec(compile("".join(cell["source"]), f"{path.name}", "exec"), namespace)  # noqa: S102
    out = capsys.readouterr().out
    assert "div=" in out and "success: True" in out and "undefined, not 0" in out
