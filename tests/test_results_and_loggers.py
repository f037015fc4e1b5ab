"""result.json writing, secret redaction, and the logger group (csv, wandb offline)."""

import json
import os

import pytest

from simeval.cli import move_multirun_flag_first
from simeval.loggers import CsvLogger, WandbLogger
from simeval.results import atomic_write_text, read_results, redact_secrets, write_result


def test_write_and_read_result(tmp_path):
    path = write_result(tmp_path / "run", metric="m", version="1.0", values={"g": {"n": 2}}, seed=3,
                        choices={"pipeline": "gensim"}, config={"judge": {"api_key": "sk-secret", "api_key_env": "K"}})
    rec = json.loads(path.read_text())
    assert rec["metric"] == "m" and rec["version"] == "1.0" and rec["seed"] == 3
    assert rec["choices"] == {"pipeline": "gensim"} and "git_sha" in rec
    assert rec["config"]["judge"] == {"api_key": "<redacted>", "api_key_env": "K"}
    assert "sk-secret" not in path.read_text()
    assert [r["metric"] for r in read_results(tmp_path)] == ["m"]


def test_corrupt_result_is_an_error_naming_the_file(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "result.json").write_text("{not json")
    with pytest.raises(ValueError, match="a/result.json"):
        read_results(tmp_path)


def test_atomic_write_leaves_no_temp_files(tmp_path):
    atomic_write_text(tmp_path / "x.txt", "hello")
    assert os.listdir(tmp_path) == ["x.txt"]


def test_redaction_is_recursive():
    cfg = {"a": [{"token": "t"}], "password": None, "nested": {"Authorization": "Bearer x", "name": "ok"}}
    assert redact_secrets(cfg) == {"a": [{"token": "<redacted>"}], "password": None,
                                   "nested": {"Authorization": "<redacted>", "name": "ok"}}


@pytest.mark.parametrize("argv,expected", [
    (["p.py", "pipeline=bbsea", "-m", "episodes=10,20"], ["p.py", "--multirun", "pipeline=bbsea", "episodes=10,20"]),
    (["p.py", "a=1", "--multirun"], ["p.py", "--multirun", "a=1"]),
    (["p.py", "a=1"], ["p.py", "a=1"]),
    (["p.py", "key=-m", "b=2"], ["p.py", "key=-m", "b=2"]),
])
def test_multirun_flag_moves_first(argv, expected):
    assert move_multirun_flag_first(argv) == expected


def test_csv_logger(tmp_path):
    with CsvLogger(run_dir=str(tmp_path)) as log:
        log.log_metrics({"g": {"div": 0.5, "n": 3}})
    assert (tmp_path / "metrics.csv").read_text().splitlines() == ["step,key,value", ",g/div,0.5", ",g/n,3"]


def test_wandb_offline_finishes_on_error_and_never_stores_secrets(tmp_path, monkeypatch):
    monkeypatch.setenv("WANDB_MODE", "offline")
    with pytest.raises(RuntimeError, match="boom"):
        with WandbLogger(run_dir=str(tmp_path), run_config={"embedding": {"api_key": "sk-leak-me"}}) as log:
            log.log_metrics({"div": 0.5})
            raise RuntimeError("boom")
    assert log.run is None  # finish() ran despite the error
    files = [p for p in tmp_path.rglob("*") if p.is_file()]
    assert any(p.suffix == ".wandb" for p in files)
    assert not any(b"sk-leak-me" in p.read_bytes() for p in files)
