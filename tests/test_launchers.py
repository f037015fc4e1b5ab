"""Sweeps through the Hydra launcher plugins: `hydra/launcher=joblib` (parallel local processes) and
`hydra/launcher=submitit_local` (the SLURM plugin's local executor) each run a 2-job text_diversity sweep with
`debug=tiny` on a loopback embedding server, with `-m` typed after the overrides as users do. A user error inside a
job is one line and exit 2 under both. The SLURM config (conf/hydra/launcher/slurm.yaml) is composed and checked,
not submitted: there is no cluster here."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
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
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    write_group(tmp_path / "store", "diverse", n_tasks=2, episodes=3, n_actions=10, size=16, pipeline="gensim")
    res = _diversity_sweep(tmp_path, "task_group=diverse", "protocol=paper", "eval_episodes=[1,3]", "heldout_episodes=null", "videos=0",
                           "-m", "episodes=0,2")
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr[-3000:]
    assert res.stderr.splitlines() == ["error: episodes must be a whole number >= 1, got 0"]
    assert not (tmp_path / "sweep" / "0" / "result.json").exists()
    rec = json.loads((tmp_path / "sweep" / "1" / "result.json").read_text())  # the good job ran to the end
    assert rec["identity"]["episodes"] == 2 and rec["values"]["train"]["steps"] > 0


def _signal_the_job_of_a_training_sweep(tmp_path: Path, sig: int, epochs: int = 400):
    """Start a 1-job diversity sweep under submitit_local on a synthetic group, wait for its first checkpoint, send
    `sig` to the job's process and wait for the sweep: (process, stderr, sweep folder, controller pid, command)."""
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    write_group(tmp_path / "store", "diverse", n_tasks=2, episodes=3, n_actions=10, size=16, pipeline="gensim")
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "OMP_NUM_THREADS": "1"}
    env.pop("SUBMITIT_PREEMPT_SIGNAL", None)
    env.pop("HYDRA_FULL_ERROR", None)
    sweep = tmp_path / "sweep"
    cmd = [sys.executable, str(ROOT / "src" / "diversity.py"), "pipeline=gensim", "debug=tiny", "threads=1",
           "progress=false", f"store={tmp_path / 'store'}", f"checkpoint_dir={tmp_path / 'ck'}", "task_group=diverse",
           "protocol=paper", "eval_episodes=[1,3]", "heldout_episodes=null", "videos=0", f"world_model.train.epochs={epochs}",
           "hydra/launcher=submitit_local", f"hydra.sweep.dir={sweep}", "-m", "episodes=2"]
    proc = subprocess.Popen(cmd, cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 120
        while not list((tmp_path / "ck").glob("world_model-*.pt")):
            assert proc.poll() is None and time.time() < deadline, proc.communicate()[1][-2000:]
            time.sleep(0.05)
        # the local executor's controller is named by the job folder; the job runs in its one child process
        [controller] = [d.name for d in (sweep / ".submitit").iterdir() if d.name.isdigit()]
        [job] = Path(f"/proc/{controller}/task/{controller}/children").read_text().split()
        os.kill(int(job), sig)
        _, err = proc.communicate(timeout=280)
    finally:
        if proc.poll() is None:
            proc.kill()
    return proc, err, sweep, controller, (cmd, env)


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="finds the job's process through /proc (Linux)")
def test_a_preempted_submitit_job_is_requeued_and_resumes_its_training_from_the_checkpoint(tmp_path):
    """What SLURM does to a preempted job, with submitit's local executor: the job's process gets submitit's
    preemption signal (USR2), submitit requeues the same job (the same overrides, so the same run folder and the
    same checkpoint key), and the training resumes from the step it was preempted in instead of step 0. (Before
    simeval.runtime.preemption, submitit's SystemExit was now and then raised inside a finaliser and dropped: the
    job trained on, exited 0 and was never requeued.)"""
    steps = 400  # 4 training windows, batch 8: one step (and one checkpoint) per epoch
    proc, err, sweep, controller, _ = _signal_the_job_of_a_training_sweep(tmp_path, signal.SIGUSR2, steps)
    assert proc.returncode == 0, err[-3000:]
    log = _job_logs(sweep) + "".join(p.read_text() for p in sweep.glob(".submitit/*/*_log.out"))
    assert "this job is preempted" in log and f"Requeued job {controller}" in log
    resumed = re.findall(r"resumed from \S+world_model-\w+\.pt at epoch \d+, batch \d+ \(step (\d+)\)", log)
    assert len(resumed) == 1, log[-6000:]
    [resumed] = resumed
    assert 0 < int(resumed) < steps
    # saved in the step the signal came in, not at the last periodic checkpoint (simeval.runtime.preemption)
    assert re.findall(r"preempted at step (\d+): checkpoint saved", log) == [resumed]
    rec = json.loads((sweep / "0" / "result.json").read_text())  # the requeued job wrote to the same folder
    assert rec["values"]["train"]["steps"] == steps and rec["status"] == "ok"


def test_slurm_launcher_config_asks_for_one_gpu_per_job():
    from hydra import compose, initialize_config_dir
    from hydra.utils import get_class

    with initialize_config_dir(version_base="1.3", config_dir=str(ROOT / "conf")):
        cfg = compose("diversity", overrides=["hydra/launcher=slurm"], return_hydra_config=True)
    launcher = cfg.hydra.launcher
    assert get_class(launcher._target_).__name__ == "SlurmLauncher"
    assert (launcher.gpus_per_node, launcher.tasks_per_node, launcher.nodes) == (1, 1, 1)
    assert launcher.max_num_timeout >= 1  # preempted jobs are requeued


class _Submitted(Exception):
    pass


def _sbatch_script(tmp_path: Path, monkeypatch, *overrides: str) -> tuple[str, object]:
    """The sbatch script hydra/launcher=slurm would submit for one diversity job, built by the plugin's own launch()
    and submitit's own script writer; submission is stopped before `sbatch` runs (there is no cluster here).
    submitit only checks that an `srun` is on PATH: a stub stands in."""
    import submitit
    from hydra import compose, initialize_config_dir
    from hydra.utils import get_class

    stub = tmp_path / "bin" / "srun"
    stub.parent.mkdir(exist_ok=True)
    stub.write_text("#!/bin/sh\nexit 1\n")
    stub.chmod(0o755)
    monkeypatch.setenv("PATH", f"{stub.parent}{os.pathsep}{os.environ['PATH']}")
    with initialize_config_dir(version_base="1.3", config_dir=str(ROOT / "conf")):
        cfg = compose("diversity", overrides=["hydra/launcher=slurm", f"hydra.sweep.dir={tmp_path / 'sweep'}",
                                              *overrides], return_hydra_config=True)
    params = {k: v for k, v in cfg.hydra.launcher.items() if k != "_target_"}
    launcher = get_class(cfg.hydra.launcher._target_)(**params)
    launcher.config = cfg
    captured = {}

    def capture(executor, fn, *iterables):
        captured["executor"] = executor._executor
        raise _Submitted

    monkeypatch.setattr(submitit.AutoExecutor, "map_array", capture)
    with pytest.raises(_Submitted):
        launcher.launch([["episodes=10"]], initial_job_idx=0)
    ex = captured["executor"]
    return ex._make_submission_file_text(ex._submitit_command_str, "uid"), ex


def test_slurm_launcher_submits_one_gpu_8_cpus_12_h_with_the_requeue_signal(tmp_path, monkeypatch):
    monkeypatch.delenv("SLURM_PARTITION", raising=False)
    monkeypatch.delenv("SLURM_ACCOUNT", raising=False)
    script, ex = _sbatch_script(tmp_path, monkeypatch)
    flags = {line for line in script.splitlines() if line.startswith("#SBATCH")}
    assert {"#SBATCH --gpus-per-node=1", "#SBATCH --cpus-per-task=8", "#SBATCH --mem=32GB", "#SBATCH --time=720",
            "#SBATCH --nodes=1", "#SBATCH --ntasks-per-node=1", "#SBATCH --signal=USR2@120",
            "#SBATCH --open-mode=append"} <= flags, script
    assert not any(f.startswith(("#SBATCH --partition", "#SBATCH --account")) for f in flags)  # sbatch's defaults
    assert "export SUBMITIT_EXECUTOR=slurm" in script and "srun --unbuffered" in script
    assert ex.max_num_timeout == 3  # a job that hits its time limit is requeued up to 3 times
    # the job's logs are kept in the sweep folder (appended to across requeues)
    assert f"#SBATCH --output={tmp_path / 'sweep' / '.submitit' / '%j' / '%j_0_log.out'}" in flags


def test_slurm_partition_and_account_come_from_the_environment_or_the_command_line(tmp_path, monkeypatch):
    monkeypatch.setenv("SLURM_PARTITION", "gpu-long")
    monkeypatch.setenv("SLURM_ACCOUNT", "robotics")
    script, _ = _sbatch_script(tmp_path, monkeypatch)
    assert "#SBATCH --partition=gpu-long" in script and "#SBATCH --account=robotics" in script
    script, _ = _sbatch_script(tmp_path, monkeypatch, "hydra.launcher.partition=a100", "hydra.launcher.gpus_per_node=0")
    assert "#SBATCH --partition=a100" in script and "#SBATCH --gpus-per-node=0" in script


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="finds the job's process through /proc (Linux)")
def test_a_killed_submitit_job_ends_the_sweep_with_one_line_naming_its_log_and_a_rerun_resumes(tmp_path):
    """kill -9 of the job process (what the out-of-memory killer does): submitit raises UncompletedJobError in the
    launching process; the user gets one line naming the job's log and exit 1, and the same command resumes."""
    proc, err, sweep, controller, (cmd, env) = _signal_the_job_of_a_training_sweep(tmp_path, signal.SIGKILL)
    assert proc.returncode == 1 and "Traceback" not in err, err[-3000:]
    [line] = err.strip().splitlines()
    log = sweep / ".submitit" / controller / f"{controller}_0"
    assert line == (f"error: a job of the sweep died without a result (killed, out of memory?): job {controller} "
                    f"(task 0) left no result; its log: {log}_log.err and _log.out. Run the same command again: "
                    "finished runs are kept and a training resumes from its last checkpoint")
    again = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=280)
    assert again.returncode == 0, again.stderr[-3000:]
    logs = "".join(p.read_text() for p in sweep.glob(".submitit/*/*_log.out"))
    assert re.search(r"resumed from \S+world_model-\w+\.pt at epoch \d+, batch \d+ \(step [1-9]\d*\)", logs), logs[-3000:]


def test_the_dead_job_line_names_slurms_state_of_the_job_not_the_local_executors():
    """submitit's UncompletedJobError carries the scheduler's state of the job: SLURM's (OUT_OF_MEMORY, TIMEOUT,
    CANCELLED by <uid>) says what ended it and is kept; the local executor's (FINISHED, INTERRUPTED) is that of
    its controller process and would mislead, so it is left out."""
    from submitit.core.utils import UncompletedJobError

    from simeval.cli import dead_job_line

    def line(state: str) -> str:
        return dead_job_line(UncompletedJobError(f"Job 12 (task: 0) with path /s/12/12_0_result.pkl\nhas not "
                                                 f"produced any output (state: {state})\nError stream produced:\n..."))

    tail = ("; its log: /s/12/12_0_log.err and _log.out. Run the same command again: finished runs are kept and a "
            "training resumes from its last checkpoint")
    head = "a job of the sweep died without a result (killed, out of memory?): job 12 (task 0) left no result"
    assert line("OUT_OF_MEMORY") == head + " (state: OUT_OF_MEMORY)" + tail
    assert line("CANCELLED by 0") == head + " (state: CANCELLED by 0)" + tail
    assert line("FINISHED") == line("INTERRUPTED") == line("UNKNOWN") == head + tail


APP = '''
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig

from simeval.cli import exit_cleanly_on_user_error, launch


@hydra.main(version_base="1.3", config_path="conf", config_name="app")
@exit_cleanly_on_user_error
def main(cfg):
    if cfg.x == 1:
        raise RuntimeError("boom in the job of x=1")
    Path(HydraConfig.get().runtime.output_dir, "done").write_text(str(cfg.x))


if __name__ == "__main__":
    launch(main)
'''


def test_a_job_that_crashes_in_a_local_sweep_says_so_at_once_and_the_sweep_ends_naming_it_with_exit_1(tmp_path):
    """A job that raises (a bug, not a user error) under the basic launcher: Hydra keeps the exception and starts
    the next job with nothing said, then shows one traceback at the end. Here the traceback is logged in the job's
    log and on the console when it happens, the other jobs run, and the sweep ends with one line per failed job
    naming its log, exit 1. A small app with the product's decorator and sweeper (conf/hydra/default.yaml's)."""
    (tmp_path / "conf").mkdir()
    (tmp_path / "conf" / "app.yaml").write_text(yaml.safe_dump({
        "x": 0, "hydra": {"sweeper": {"_target_": "hydra_plugins.simeval_sweeper.user_error_sweeper.UserErrorSweeper"},
                          "sweep": {"dir": str(tmp_path / "sweep"), "subdir": "${hydra.job.num}"}}}))
    (tmp_path / "app.py").write_text(APP)
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    env.pop("HYDRA_FULL_ERROR", None)
    res = subprocess.run([sys.executable, "app.py", "-m", "x=0,1,2"], cwd=tmp_path, env=env, capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 1, res.stderr[-3000:]
    sweep = tmp_path / "sweep"
    assert (sweep / "0" / "done").exists() and (sweep / "2" / "done").exists()  # the jobs around it ran
    log = (sweep / "1" / "app.log").read_text()
    assert "this job failed (RuntimeError: boom in the job of x=1)" in log and "Traceback" in log
    assert res.stdout.index("this job failed") < res.stdout.index("#2 : x=2")  # before the next job started
    assert res.stderr.splitlines()[-2:] == [
        f"error: the sweep's job [x=1] failed: RuntimeError: boom in the job of x=1 (traceback in "
        f"{sweep / '1' / 'app.log'})",
        "error: 1 of 3 jobs failed; the others' results are kept"]
