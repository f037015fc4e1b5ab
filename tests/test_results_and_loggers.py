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


def test_a_killed_writers_temp_file_is_removed_by_the_next_write_of_the_same_file(tmp_path):
    """A table redraw killed -9 between the temp file and its rename left `.t5.csv.<random>.tmp` beside the table
    for good (untracked files in a checkout's outputs/tables): temp files now carry their writer's pid@host, and the
    next write of the same file removes those of this host's dead processes, never a live or another host's one."""
    import socket
    import subprocess
    import sys

    host = socket.gethostname().split(".")[0]
    dead = int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                              text=True, check=True).stdout)
    left = tmp_path / f".t5.csv.{dead}@{host}.k2x9.tmp"
    alive = tmp_path / f".t5.csv.{os.getppid()}@{host}.a1b2.tmp"  # a live run writing the same table now
    remote = tmp_path / f".t5.csv.{dead}@not-{host}.c3d4.tmp"  # a shared folder: that pid is not ours to ask
    other = tmp_path / f".t5.md.{dead}@{host}.e5f6.tmp"  # another file's: its own next write removes it
    unnamed = tmp_path / ".t5.csv.q8w7e6r5.tmp"  # before writers were named: nothing says whose it is
    for p in (left, alive, remote, other, unnamed):
        p.write_text("half")
    atomic_write_text(tmp_path / "t5.csv", "a,b\n")
    assert (tmp_path / "t5.csv").read_text() == "a,b\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [p.name for p in (alive, remote, other, unnamed)] + ["t5.csv"])


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


def test_redaction_keeps_counts_and_catches_key_shaped_values():
    cfg = {"max_tokens": 300, "image_tokens": 85, "api_key_env": "OPENAI_API_KEY", "access_token": "abc",
           "notes": ["sk-abcdefghijklmnopqrstuvwx", "plain"], "hf": {"path": "hf_ABCDEFGHIJKLMNOPQRSTUVWXYZ"}}
    assert redact_secrets(cfg) == {"max_tokens": 300, "image_tokens": 85, "api_key_env": "OPENAI_API_KEY",
                                   "access_token": "<redacted>", "notes": ["<redacted>", "plain"],
                                   "hf": {"path": "<redacted>"}}


def test_result_json_is_strict_and_world_readable_under_the_umask(tmp_path):
    import numpy as np

    old = os.umask(0o022)
    try:
        path = write_result(tmp_path, metric="m", version="1", values={"a": float("nan"), "b": np.float32(0.5),
                                                                       "c": [float("inf"), np.int64(3)]})
    finally:
        os.umask(old)
    rec = json.loads(path.read_text(), parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"))
    assert rec["values"] == {"a": None, "b": 0.5, "c": [None, 3]}
    assert path.stat().st_mode & 0o777 == 0o644


def test_key_typed_on_the_command_line_stops_before_hydra_saves_it(tmp_path):
    import subprocess
    import sys

    from conftest import ROOT

    proc = subprocess.run([sys.executable, str(ROOT / "src" / "text_diversity.py"),
                           "judge.provider.api_key_env=sk-abcdefghijklmnopqrstuvwx", f"hydra.run.dir={tmp_path}/run"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "judge.provider.api_key_env" in proc.stderr
    assert "sk-abcdefghijklmnopqrstuvwx" not in proc.stderr and not (tmp_path / "run").exists()


def test_user_error_is_one_line_and_exit_2(tmp_path):
    import subprocess
    import sys

    from conftest import ROOT

    cmd = [sys.executable, str(ROOT / "src" / "text_diversity.py"), "pipeline=custom",
           f"pipeline.tasks_path={tmp_path}/missing.yaml", f"hydra.run.dir={tmp_path}/run"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env={**os.environ, "HYDRA_FULL_ERROR": ""})
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and "missing.yaml" in proc.stderr.strip().splitlines()[-1]


def test_key_pasted_into_a_config_file_is_refused_and_scrubbed_from_hydra_files(tmp_path):
    import subprocess
    import sys

    from conftest import ROOT

    key = "sk-" + "q" * 30
    (tmp_path / "conf" / "embedding").mkdir(parents=True)
    (tmp_path / "conf" / "embedding" / "leaky.yaml").write_text(
        "name: leaky\nbackend:\n  _target_: simeval.embeddings.local.MiniLM\n  api_key_env: " + key + "\n")
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "notes.txt").write_text("the user's own file keeps the refused run's folder\n")
    proc = subprocess.run([sys.executable, str(ROOT / "src" / "text_diversity.py"), "embedding=leaky",
                           f"hydra.searchpath=[file://{tmp_path}/conf]", f"hydra.run.dir={tmp_path}/run"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "embedding.backend.api_key_env" in proc.stderr and key not in proc.stderr + proc.stdout
    saved = list((tmp_path / "run" / ".hydra").glob("*.yaml"))
    assert len(saved) == 3 and not any(key in p.read_text() for p in saved)
    assert "<redacted>" in (tmp_path / "run" / ".hydra" / "config.yaml").read_text()


def test_a_refused_run_leaves_no_folder_but_a_folder_with_anything_else_stays(tmp_path):
    import subprocess
    import sys

    from conftest import ROOT

    def diversity(*args):
        return subprocess.run([sys.executable, str(ROOT / "src" / "diversity.py"), "episodes=-1",
                               f"paths.root={tmp_path / 'out'}", *args], capture_output=True, text=True, timeout=120)

    (tmp_path / "out").mkdir()
    refused = diversity()  # the folder Hydra named: gone, with its parents left empty
    assert refused.returncode == 2 and "episodes must be a whole number >= 1, got -1" in refused.stderr
    sweep = diversity("-m", "seed=0,1")
    assert sweep.returncode == 2 and "Traceback" not in sweep.stderr
    assert list((tmp_path / "out").iterdir()) == []
    (tmp_path / "mine").mkdir()  # a folder the user named stays, even empty
    assert diversity(f"hydra.run.dir={tmp_path / 'mine'}").returncode == 2
    assert sorted(p.name for p in (tmp_path / "mine").iterdir()) == [".hydra", "diversity.log"]
    (tmp_path / "out" / "runs" / "diversity").mkdir(parents=True)
    (tmp_path / "out" / "runs" / "diversity" / "earlier_run").mkdir()
    assert diversity().returncode == 2  # a parent that holds another run stays
    assert [p.name for p in (tmp_path / "out" / "runs" / "diversity").iterdir()] == ["earlier_run"]
    # refused after it logged a line (one task: no held-out split to roll out), for want of training episodes
    logged = subprocess.run([sys.executable, str(ROOT / "src" / "generalization.py"), "tasks=[stack-two-blocks]",
                             f"paths.root={tmp_path / 'out2'}", f"store={tmp_path / 'empty_store'}"],
                            capture_output=True, text=True, timeout=120)
    assert logged.returncode == 2 and "fewer than episodes_per_task=40 episodes" in logged.stderr, logged.stderr
    assert not (tmp_path / "out2" / "runs").exists()  # its folder, which held the log line, is gone


def test_a_constructor_error_inside_instantiate_is_one_line(tmp_path):
    import subprocess
    import sys

    from conftest import ROOT

    (tmp_path / "tasks.yaml").write_text("stacking: [stack two blocks, stack three blocks]\n")
    proc = subprocess.run([sys.executable, str(ROOT / "src" / "text_diversity.py"), "embedding.backend.batch_size=0",
                           f"hydra.run.dir={tmp_path}/run", "pipeline=custom", f"pipeline.tasks_path={tmp_path}/tasks.yaml"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip() == "error: embedding.backend.batch_size must be >= 1, got 0"
