"""The `slurm` launcher on a real one-node SLURM cluster (experiments/local_slurm.py: Debian's slurm-wlm, slurmdbd,
munge and MariaDB, brought up for this module and torn down after it). Skipped, with the reason on one line, where
the cluster cannot be brought up (not root, packages missing and not installable)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ["hydra/launcher=slurm", "hydra.launcher.partition=debug", "hydra.launcher.gpus_per_node=0",
          "hydra.launcher.mem_gb=1", "hydra.launcher.cpus_per_task=1"]


@pytest.fixture(scope="module")
def slurm(tmp_path_factory):
    from local_slurm import Unavailable, down, up

    state = tmp_path_factory.mktemp("slurm")
    try:
        env = up(state)
    except Unavailable as e:
        pytest.skip(f"no local SLURM cluster: {e}")
    try:
        yield {**os.environ, **env, "HYDRA_FULL_ERROR": "0"}
    finally:
        down(state)


def _tasks(tmp: Path) -> Path:
    path = tmp / "tasks.yaml"
    path.write_text(yaml.safe_dump({"stack": ["stack the red block on the blue block", "build a tower of three cubes",
                                              "put the green block on top of the yellow one"],
                                    "place": ["place the cylinder in the bowl", "move the ball into the zone",
                                              "drop every block into the bin"]}))
    return path


def _sweep(env: dict, tmp: Path, *overrides: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "src" / "text_diversity.py"), "-m", *LAUNCH, "pipeline=custom",
                           f"pipeline.tasks_path={_tasks(tmp)}", f"cache_dir={tmp / 'cache'}",
                           f"hydra.sweep.dir={tmp / 'sweep'}", *overrides], cwd=tmp, env=env, capture_output=True,
                          text=True, timeout=600)


def test_a_sweep_runs_as_slurm_jobs_with_accounting(slurm, tmp_path):
    """Two jobs submitted with sbatch, run by slurmd, each writing its result.json; submitit's status polls read
    sacct (accounting through slurmdbd), so no 'Bypassing sacct error' warning is printed per poll."""
    r = _sweep(slurm, tmp_path, "embedding=minilm,mpnet")
    assert r.returncode == 0, r.stderr[-3000:]
    assert "sacct error" not in r.stdout + r.stderr
    recs = [json.loads((tmp_path / "sweep" / str(i) / "result.json").read_text()) for i in range(2)]
    assert [r["embedding"] for r in recs] == ["minilm", "mpnet"]
    divs = [r["values"]["all"]["div"] for r in recs]
    assert all(0 < d < 2 for d in divs) and divs[0] != divs[1]  # cosine distances, two models: two numbers
    tasks = sorted(p.name for p in (tmp_path / "sweep" / ".submitit").iterdir() if p.is_dir() and "_" in p.name)
    array = tasks[0].split("_")[0]
    assert tasks == [f"{array}_0", f"{array}_1"]  # one SLURM job array, a task per sweep point
    done = [f"{array}_0|COMPLETED", f"{array}_1|COMPLETED"]
    deadline = time.time() + 60  # slurmctld reports a job's end to the accounting daemon after the job has ended
    while True:
        acct = sorted(subprocess.run(["sacct", "-n", "-X", "-P", "-o", "JobID,State", "-j", array], env=slurm,
                                     capture_output=True, text=True, check=True).stdout.split())
        if acct == done or time.time() > deadline:
            break
        time.sleep(1)
    assert acct == done


@pytest.mark.parametrize("ask,said", [("hydra.launcher.mem_gb=100000", "Memory specification can not be satisfied"),
                                      ("hydra.launcher.cpus_per_task=512", "More processors requested than permitted")])
def test_a_job_asking_more_than_any_node_has_is_refused_at_submission(slurm, tmp_path, ask, said):
    """Not left pending forever: sbatch refuses it, and the sweep ends with one line saying what sbatch said and
    what to change, exit 2 (a setting, not a job to rerun)."""
    r = _sweep(slurm, tmp_path, "embedding=minilm", ask)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("error: sbatch refused the sweep's jobs: ") and said in last
    assert "hydra.launcher.mem_gb, cpus_per_task, gpus_per_node" in last
    assert not list((tmp_path / "sweep").rglob("result.json"))
    queue = subprocess.run(["squeue", "-h"], env=slurm, capture_output=True, text=True, check=True).stdout
    assert queue.strip() == ""  # nothing pending
