"""`make evaluate PIPELINE=robogen` at the quick profile (src/paper.py): every stage runs as a user would
type it, the tables and the HTML report are rebuilt from the runs' result.json files, and a rerun resumes."""

import csv
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_quick_profile_runs_one_pipeline_end_to_end_and_resumes(tmp_path):
    out = tmp_path / "paper"
    cmd = [sys.executable, str(ROOT / "src" / "paper.py"), "profile=quick", "pipelines=[robogen]",
           f"out={out}"]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    rows = {r["group"]: r for r in csv.DictReader((out / "tables" / "table4.csv").open()) if r["pipeline"] == "robogen"}
    assert set(rows) == {"table_top", "ground"}
    for r in rows.values():  # a world model per (group, 1/2/4 episodes), beside the paper's 10/20/40 values
        assert [r["episodes_10"], r["episodes_20"], r["episodes_40"]] == ["1", "2", "4"]
        assert all(float(r[f"ours_{k}"]) > 0 for k in (10, 20, 40)) and r["preset"] == "tiny"
    t5 = {r["Task group"]: r for r in csv.DictReader((out / "tables" / "table5.csv").open())
          if r["Pipeline"] == "robogen"}
    assert t5["table_top"]["Runs"] == "1" and t5["ground"]["Runs"] == "1" and t5["ground"]["Policy"] == "tiny"
    # Table 3's layout on the suite's own task descriptions, and Figure 3 from the paper's shipped score tables
    t3 = {r["Task Group"]: r for r in csv.DictReader((out / "tables" / "table3.csv").open()) if r["Method"] == "RoboGen"}
    assert set(t3) == {"Table-Top", "Ground", "All"} and all(0 < float(r["MiniLM-L6-v2"]) for r in t3.values())
    assert (out / "figures" / "figure3" / "figure3.png").is_file()
    agreement = (out / "figures" / "figure3" / "agreement.md").read_text()
    assert agreement == (ROOT / "outputs" / "figures" / "figure3" / "agreement.md").read_text()
    html = (out / "report" / "index.html").read_text()
    assert "table4/robogen/ground/episodes_4" in html and "generalization" in html
    # a run's label tells it from the others of its sweep (the episode count, the embedding model)
    assert "robogen / ground · episodes 4 · preset tiny" in html and "robogen / each · embedding mpnet" in html
    again = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert again.returncode == 0
    for finished in ("diversity.py", "generalization.py", "text_diversity.py", "agreement.py"):
        assert finished not in again.stdout  # finished stages are skipped, and the console says which
    assert f"kept: {out / 'table4' / 'robogen' / 'ground' / 'episodes_4'} (finished earlier" in again.stdout
    assert f"kept: {out / 'table3' / 'runs'} (finished" in again.stdout


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/status").read_text().split("State:")[1].split()[0]
    except (FileNotFoundError, IndexError):
        return False
    return state != "Z"  # a zombie has exited; whoever adopted it reaps it later


def test_a_stage_stops_when_paper_py_is_killed(tmp_path):
    """kill -9 of src/paper.py must not leave its running stage writing beside the rerun that resumes it."""
    import os
    import signal
    import time

    if not sys.platform.startswith("linux"):
        import pytest

        pytest.skip("PR_SET_PDEATHSIG is Linux's")
    # collecting a GenSim group takes 8-30 s, so a stage that outlives paper.py is caught in the act
    p = subprocess.Popen([sys.executable, str(ROOT / "src" / "paper.py"), "profile=quick",
                          "pipelines=[gensim]", "stages=[collect]", f"out={tmp_path / 'paper'}"],
                         cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline, kids = time.time() + 60, []
    while not kids and time.time() < deadline:
        kids = [int(k) for k in Path(f"/proc/{p.pid}/task/{p.pid}/children").read_text().split()]
        time.sleep(0.05)
    assert kids, "the collect stage never started"
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    deadline = time.time() + 3
    while any(_alive(k) for k in kids) and time.time() < deadline:
        time.sleep(0.1)
    assert not any(_alive(k) for k in kids), "the stage kept running after paper.py was killed"


def test_pipelines_without_a_suite_only_are_one_line_not_a_run_that_does_nothing(tmp_path):
    p = subprocess.run([sys.executable, str(ROOT / "src" / "paper.py"), "profile=quick", "pipelines=[custom]",
                        f"out={tmp_path / 'out'}"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    assert p.stderr.strip().splitlines() == [
        "error: pipelines: custom: no simeval suite to collect episodes from (pipeline.suite is null); pipelines "
        "with one: bbsea, gensim, robogen. For your own pipeline, import its episodes with src/import_data.py and "
        "run the entrypoints on them"]
    assert not (tmp_path / "out").exists()


def test_a_stage_that_refuses_a_value_is_its_one_line_and_exit_2(tmp_path):
    """A stage's own user error (here collect's workers=-1, given through the profile) reaches the console as that
    stage's one line, naming the stage and its log, as the stage alone would print it; not its log's tail."""
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, str(ROOT / "src" / "paper.py"), "profile=quick", "pipelines=[bbsea]",
                        "stages=[collect]", "profile.overrides.collect=['debug=tiny','workers=-1']", f"out={out}"],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    log = out / "logs" / "collect_bbsea_drawer.log"
    assert p.returncode == 2 and p.stderr.strip().splitlines() == [
        "error: collect_bbsea_drawer: workers must be 0 (one per CPU core) or a positive number of processes, got -1 "
        f"(log: {log})"], p.stderr
    assert log.read_text().strip().splitlines()[-1] == ("error: workers must be 0 (one per CPU core) or a positive "
                                                        "number of processes, got -1")


def test_the_slurm_launcher_without_a_reachable_controller_is_one_line(tmp_path):
    """squeue here fails as Debian's does on a machine with the client but no slurm.conf (stand-in scripts on PATH,
    so the test does not depend on what this machine has installed)."""
    import os

    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for tool in ("sbatch", "sacct", "squeue"):
        (bin_dir / tool).write_text("#!/bin/sh\necho 'squeue: error: resolve_ctls_from_dns_srv: res_nsearch error: "
                                    "Unknown host' >&2\necho 'squeue: fatal: Could not establish a configuration "
                                    "source' >&2\nexit 1\n")
        (bin_dir / tool).chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}"}
    p = subprocess.run([sys.executable, str(ROOT / "src" / "paper.py"), "profile=quick", "pipelines=[robogen]",
                        "launcher=slurm", f"out={tmp_path / 'out'}"], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and p.stderr.splitlines() == [
        "error: launcher=slurm: no SLURM controller answers here (squeue: fatal: Could not establish a "
        "configuration source); run it on the cluster's login node, or point SLURM_CONF at its slurm.conf"]
    assert not (tmp_path / "out").exists()  # nothing submitted, nothing written


def test_every_profile_composes_with_what_each_stage_needs_and_takes_overrides():
    """The profiles are Hydra configs (conf/profile/, composed by conf/paper.yaml): a value changes from the command
    line like any other key, and the output folder follows the profile's name."""
    from hydra import compose, initialize_config_dir

    stages = {"collect", "quality", "diversity", "generalization"}
    with initialize_config_dir(version_base="1.3", config_dir=str(ROOT / "conf")):
        for name in ("quick", "cpu", "paper"):
            cfg = compose("paper", overrides=[f"profile={name}"])
            assert cfg.profile.name == name and cfg.out == f"outputs/paper/{name}"
            assert set(cfg.profile.overrides) == stages
            assert len(cfg.profile.world_model_episodes) == 3 and cfg.profile.episodes >= 4
        cfg = compose("paper", overrides=["profile=quick", "profile.episodes=6", "paths.root=/scratch/me"])
        assert cfg.profile.episodes == 6 and cfg.out == "/scratch/me/paper/quick"
