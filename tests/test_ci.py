"""`.ci/run` fails, with a message, when pytest collects no tests (exit 5), not only when a test fails."""

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("pytest_status,message", [
    (0, None),
    (5, "ci: FAILED: pytest collected no tests (exit 5)"),
    (1, "ci: FAILED: make test exited with status 2"),
])
def test_ci_run_reports_the_test_status(tmp_path, pytest_status, message):
    if shutil.which("make") is None:
        pytest.skip("no make")
    (tmp_path / ".ci").mkdir()
    shutil.copy(ROOT / ".ci" / "run", tmp_path / ".ci" / "run")
    # A stand-in for the Makefile's `test` target that ends as pytest would.
    (tmp_path / "Makefile").write_text(f"test:\n\t@echo tests ran; exit {pytest_status}\n")
    res = subprocess.run(["bash", str(tmp_path / ".ci" / "run")], capture_output=True, text=True, timeout=60)
    out = res.stdout + res.stderr
    assert "tests ran" in out
    if message is None:
        assert res.returncode == 0 and "FAILED" not in out
    else:
        assert res.returncode != 0 and message in res.stderr


def test_a_hung_test_cannot_stall_ci(pytestconfig):
    # pytest-timeout must be loaded and given a finite default (pyproject.toml), or one hang blocks CI for hours.
    assert pytestconfig.pluginmanager.hasplugin("timeout")
    assert 0 < float(pytestconfig.getini("timeout") or 0) <= 600
