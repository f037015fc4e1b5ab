"""Sweeps through the Hydra launcher plugins: `hydra/launcher=joblib` (parallel local processes) and
`hydra/launcher=submitit_local` (the SLURM plugin's local executor) each run a 2-job text_diversity sweep with
`debug=tiny` on a loopback embedding server, with `-m` typed after the overrides as users do. A user error inside a
job is one line and exit 2 under both. The SLURM config (conf/hydra/launcher/slurm.yaml) is composed and checked,
not submitted: there is no cluster here."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]


def _sweep(tmp_path: Path, server, launcher: str, *extra: str, tasks_path: Path | None = None):
    tasks = tmp_path / "tasks.yaml"
    tasks.write_text(yaml.safe_dump({"push": ["push the red block to the zone", "push the pile of beans",
                                              "slide the box along the line"],
                                     "stack": ["stack two blocks", "stack three cups into a tower",
                                               "build a pyramid of blocks"]}))
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    args = ["pipeline=custom", f"pipeline.tasks_path={tasks_path or tasks}", "embedding=openai",
            f"embedding.backend.base_url={server.base_url}", "debug=tiny", f"cache_dir={tmp_path / 'cache'}",
            "task_group=each,push", "-m", f"hydra/launcher={launcher}", f"hydra.sweep.dir={tmp_path / 'sweep'}",
            *extra]
    return subprocess.run([sys.executable, str(ROOT / "src" / "text_diversity.py"), *args], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)


def _check_two_jobs(sweep: Path, target: str) -> None:
    results = sorted(sweep.glob("*/result.json"))
    assert [p.parent.name for p in results] == ["0", "1"]
    recs = [json.loads(p.read_text()) for p in results]
    assert all(r["status"] == "ok" and r["metric"] == "text_diversity" for r in recs)
    assert [r["identity"]["task_group"] for r in recs] == ["each", "push"]
    assert set(recs[0]["values"]) == {"push", "stack", "all"} and set(recs[1]["values"]) == {"push"}
    # the same numbers whichever process computed them
    assert recs[0]["values"]["push"]["div"] == pytest.approx(recs[1]["values"]["push"]["div"])
    for p in results:  # each job really ran under the plugin's launcher
        hydra_cfg = yaml.safe_load((p.parent / ".hydra" / "hydra.yaml").read_text())["hydra"]
        assert hydra_cfg["launcher"]["_target_"] == target


def test_joblib_launcher_runs_a_parallel_local_sweep(openai_server, tmp_path):
    res = _sweep(tmp_path, openai_server, "joblib", "hydra.launcher.n_jobs=2")
    assert res.returncode == 0, res.stderr[-3000:]
    assert "Joblib.Parallel(n_jobs=2" in res.stdout + res.stderr
    _check_two_jobs(tmp_path / "sweep", "hydra_plugins.hydra_joblib_launcher.joblib_launcher.JoblibLauncher")


def test_submitit_local_launcher_runs_each_job_as_a_submitit_job(openai_server, tmp_path):
    res = _sweep(tmp_path, openai_server, "submitit_local")
    assert res.returncode == 0, res.stderr[-3000:]
    _check_two_jobs(tmp_path / "sweep", "hydra_plugins.hydra_submitit_launcher.submitit_launcher.LocalLauncher")
    # submitit kept a log and a result per job (what a SLURM user reads when a job dies)
    assert len(list((tmp_path / "sweep" / ".submitit").glob("*/*_0_result.pkl"))) == 2


def test_a_user_error_in_a_joblib_job_is_one_line_and_exit_2(openai_server, tmp_path):
    res = _sweep(tmp_path, openai_server, "joblib", "hydra.launcher.n_jobs=2", tasks_path=tmp_path / "nope.yaml")
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr[-3000:]
    assert f"error: task file not found: {tmp_path / 'nope.yaml'}" in res.stderr.splitlines()


def _diversity_sweep(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "OMP_NUM_THREADS": "1"}
    env.pop("HYDRA_FULL_ERROR", None)
    return subprocess.run([sys.executable, str(ROOT / "src" / "diversity.py"), "pipeline=gensim", "debug=tiny",
                           "threads=1", "progress=false", f"store={tmp_path / 'store'}", f"checkpoint_dir={tmp_path / 'ck'}",
                           "hydra/launcher=submitit_local", f"hydra.sweep.dir={tmp_path / 'sweep'}", *args],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)


def _job_logs(sweep: Path) -> str:
    return "".join(p.read_text() for p in sorted(sweep.glob(".submitit/*/*_log.err")))


def test_a_user_error_in_a_submitit_job_is_one_line_and_exit_2(tmp_path):
    res = _diversity_sweep(tmp_path, "task_group=nope", "-m", "episodes=1")
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr[-3000:]
    [line] = res.stderr.splitlines()
    assert line.startswith(f"error: no episodes of pipeline 'gensim' group 'nope' in store {tmp_path / 'store'}")
    assert "the gensim suite's groups are assembling, piles, placement, stacking" in line  # what would be valid
    assert line in _job_logs(tmp_path / "sweep").splitlines()  # the job's own log says it too (SLURM users read it)


def test_a_bad_value_in_one_submitit_job_ends_the_sweep_with_its_line_and_keeps_the_other_result(tmp_path):
    from simeval.models.synthetic import write_group

    write_group(tmp_path / "store", "diverse", n_tasks=2, episodes=3, n_actions=10, size=16, pipeline="gensim")
    res = _diversity_sweep(tmp_path, "task_group=diverse", "eval_episodes=[1,3]", "heldout_episodes=null", "videos=0",
                           "-m", "episodes=0,2")
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr[-3000:]
    assert res.stderr.splitlines() == ["error: episodes=0: expected a whole number >= 1 (the paper uses 10, 20, 40)"]
    assert not (tmp_path / "sweep" / "0" / "result.json").exists()
    rec = json.loads((tmp_path / "sweep" / "1" / "result.json").read_text())  # the good job ran to the end
    assert rec["identity"]["episodes"] == 2 and rec["values"]["train"]["steps"] > 0


def test_slurm_launcher_config_asks_for_one_gpu_per_job():
    from hydra import compose, initialize_config_dir
    from hydra.utils import get_class

    with initialize_config_dir(version_base="1.3", config_dir=str(ROOT / "conf")):
        cfg = compose("diversity", overrides=["hydra/launcher=slurm"], return_hydra_config=True)
    launcher = cfg.hydra.launcher
    assert get_class(launcher._target_).__name__ == "SlurmLauncher"
    assert (launcher.gpus_per_node, launcher.tasks_per_node, launcher.nodes) == (1, 1, 1)
    assert launcher.max_num_timeout >= 1  # preempted jobs are requeued
