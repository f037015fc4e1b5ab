"""Resuming a collection: episodes recorded with other settings are refused (not kept as if they matched, not
overwritten), a worker killed alone ends the run with one line and keeps what was finished, and mistakes in
seed_offset / store / task selection / import src are one line naming the key and value."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from simeval.collect import collect
from simeval.pipelines.importers import IMPORTERS, import_into_store
from simeval.episodes.store import EpisodeStore
from simeval.errors import UserError
from simeval.sim.rollout import RecordSettings
from simeval.sim.tasks.spec import suite_dir, load_suite, select_specs

ROOT = Path(__file__).resolve().parents[1]
SUITE = {s.name: s for s in load_suite(suite_dir("gensim"))}
SMALL = {"image_size": (16, 16), "scene_view_size": (16, 16), "cameras": ("top", "front"), "control_hz": 30.0}


def _run(script, tmp_path, *args, **kw):
    return subprocess.Popen([sys.executable, str(ROOT / "src" / script), f"hydra.run.dir={tmp_path / 'run'}", *args],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def _one_line(res_stderr: str) -> str:
    text = res_stderr.strip()
    assert "Traceback" not in text and len(text.splitlines()) == 1, text
    return text


def test_resuming_with_other_recording_settings_is_refused(tmp_path):
    store = EpisodeStore(tmp_path / "store")
    spec = [SUITE["build-bridge"]]
    collect(spec, [0], store, RecordSettings(**SMALL), workers=1, progress=False)
    path = store.path_for("gensim", "build-bridge", 0)
    before = path.stat().st_mtime_ns
    for change, stored, asked in [({"image_size": (24, 24)}, "[16, 16]", "[24, 24]"),
                                  ({"scene_view_size": (8, 8)}, "[16, 16]", "[8, 8]"),
                                  ({"cameras": ("top",)}, "['front', 'top']", "['top']"),
                                  ({"control_hz": 15}, "30", "15")]:
        key = "record." + next(iter(change))
        with pytest.raises(UserError) as e:
            collect(spec, [0], store, RecordSettings(**{**SMALL, **change}), workers=1, progress=False)
        assert str(e.value).startswith(f"{path} was recorded with {key}={stored}, this run asks for {asked};"), e.value
        assert "store=" in str(e.value)
    assert path.stat().st_mtime_ns == before  # kept, not overwritten
    same = collect(spec, [0], store, RecordSettings(**SMALL), workers=1, progress=False)
    assert same["skipped"] == 1 and same["new"] == []  # the same settings resume as before


def _workers(pid: int) -> list[int]:
    """The collector's pool workers: its children running the same command line (forked)."""
    me = Path(f"/proc/{pid}/cmdline").read_bytes()
    kids = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        kids += [int(c) for c in (task / "children").read_text().split()]
    out = []
    for k in kids:
        try:
            if Path(f"/proc/{k}/cmdline").read_bytes() == me:
                out.append(k)
        except FileNotFoundError:
            pass
    return out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_worker_killed_alone_ends_the_run_with_one_line_and_the_run_resumes(tmp_path):
    args = [f"store={tmp_path / 'store'}", "tasks=[build-bridge]", "episodes=4", "workers=2",
            "record.image_size=[64,64]", "record.scene_view_size=[16,16]"]
    proc = _run("collect.py", tmp_path, *args)
    deadline = time.time() + 120
    while not (workers := _workers(proc.pid)) and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert workers, "no worker appeared"
    # into its first episode: CPU time, not a wall-clock sleep, which a loaded machine can spend before the worker
    # runs at all. A worker announces its episode at once and then records for seconds of CPU at 64x64.
    while _cpu_seconds(workers[0]) < 0.3 and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    os.kill(workers[0], signal.SIGKILL)  # what the out-of-memory killer does
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 1, err[-2000:]
    line = _last_error(err)
    assert line.startswith("error: a collection worker died while recording build-bridge seed "), line
    assert f"(pid {workers[0]}, killed by signal 9" in line
    assert "finished in this run are kept in" in line and "run the same command again to resume" in line
    res = _run("collect.py", tmp_path, *args)  # the same command resumes
    out, err = res.communicate(timeout=300)
    assert res.returncode == 0, err[-2000:]
    assert len(EpisodeStore(tmp_path / "store").paths("gensim", "build-bridge")) == 4


def _cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process (/proc/<pid>/stat fields 14 and 15, after the command's parentheses)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _last_error(err: str) -> str:
    """stderr holds the progress bar too; the error is the only line starting with 'error:' and nothing else
    (no traceback) may follow it."""
    assert "Traceback" not in err, err
    lines = [ln for ln in err.replace("\r", "\n").splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("error:")]
    assert len(errors) == 1 and lines[-1] == errors[0], err
    return errors[0]


@pytest.mark.parametrize("arg,expected", [
    ("seed_offset=-5", "error: seed_offset must be a whole number >= 0, got -5"),
    ("store={afile}", "error: store={afile}: is a file, not a folder; give a folder (it is created if missing)"),
    ("store=/proc/nope", "error: store=/proc/nope: cannot create the folder ("),
    ("task_group=piles", "error: tasks=['build-bridge'] and task_group=piles were both given; tasks= selects by "
                         "name and task_group= by group: give only one"),
])
def test_collect_seed_store_and_selection_mistakes_are_one_line(tmp_path, arg, expected):
    afile = tmp_path / "afile"
    afile.write_text("")
    arg, expected = arg.format(afile=afile), expected.format(afile=afile)
    proc = _run("collect.py", tmp_path, "tasks=[build-bridge]", "episodes=1", "workers=1", "debug=tiny", arg)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2, err[-2000:]
    assert _one_line(err).startswith(expected), err


def test_library_refuses_negative_seeds_and_task_group_with_tasks(tmp_path):
    with pytest.raises(UserError, match=r"seed_offset >= 0\), got seed -5"):
        collect([SUITE["build-bridge"]], range(-5, -4), EpisodeStore(tmp_path / "s"), RecordSettings(**SMALL),
                workers=1, progress=False)
    with pytest.raises(UserError, match="were both given"):
        select_specs(list(SUITE.values()), ["build-bridge"], "piles")
    assert [s.name for s in select_specs(list(SUITE.values()), ["build-bridge"], "all")] == ["build-bridge"]


def test_import_of_a_missing_src_says_it_does_not_exist_before_any_progress(tmp_path):
    proc = _run("import_data.py", tmp_path, f"src={tmp_path / 'nope'}", f"store={tmp_path / 'store'}")
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2, err[-2000:]
    hint = "give the folder that holds the demonstrations"
    assert _one_line(err) == f"error: src={tmp_path / 'nope'} does not exist; {hint}"  # no progress bar before it
    with pytest.raises(UserError, match="does not exist"):
        import_into_store(IMPORTERS["ravens"], tmp_path / "nope", EpisodeStore(tmp_path / "store"))
    (tmp_path / "demos.txt").write_text("not demonstrations")
    (tmp_path / "empty").mkdir()
    for src, line in [(tmp_path / "demos.txt", f"error: src={tmp_path / 'demos.txt'}: is a file, not a folder; {hint}"),
                      (tmp_path / "empty", (f"error: src={tmp_path / 'empty'}: no Ravens demo folders "
                                            f"(<task>-<mode>/action/*.pkl); {hint}"))]:
        proc = _run("import_data.py", tmp_path, f"src={src}", f"store={tmp_path / 'store'}")
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 2 and _one_line(err) == line, err[-2000:]
