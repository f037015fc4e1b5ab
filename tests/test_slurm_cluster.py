"""The `slurm` launcher on a real one-node SLURM cluster (simeval.devcluster: Debian's slurm-wlm, slurmdbd,
munge and MariaDB, brought up for this module and torn down after it). Skipped, with the reason on one line, where
the cluster cannot be brought up (not root, packages missing and not installable)."""

from __future__ import annotations

import json
import os
import re
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
    from simeval.devcluster import Unavailable, down, up

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


def _episode_arrays(store: Path) -> dict:
    import h5py

    out = {}
    for path in sorted(store.rglob("episode_*.h5")):
        with h5py.File(path, "r") as f:
            f.visititems(lambda name, obj, p=path: out.__setitem__(f"{p.relative_to(store)}:{name}", obj[()])
                         if isinstance(obj, h5py.Dataset) else None)
    return out


@pytest.mark.timeout(900)  # two short sweeps twice: here (~30 s) and on the cluster
def test_collect_and_policy_sweeps_run_as_slurm_jobs_and_match_the_local_runs(slurm, tmp_path):
    """The other two entrypoint kinds as sweeps of SLURM jobs: a collection over two tasks (two jobs writing one
    store) and a tiny policy over two seeds trained on what it collected. Every job's result, every stored array and
    the policies' losses equal those of the same sweeps run here with Hydra's basic launcher."""
    def sweeps(where: str, launch: list[str], env: dict) -> tuple[list, list, dict]:
        root = tmp_path / where
        root.mkdir()

        def run(script: str, *args: str) -> subprocess.CompletedProcess:
            return subprocess.run([sys.executable, str(ROOT / "src" / script), *args], cwd=root, env=env,
                                  capture_output=True, text=True, timeout=600)

        c = run("collect.py", "pipeline=gensim", "debug=tiny", "episodes=2", "workers=1", f"store={root / 'store'}",
                f"hydra.sweep.dir={root / 'collect'}", *launch, "-m", "tasks=[stack-two-blocks],[place-red-in-green]")
        assert c.returncode == 0, c.stderr[-3000:]
        p = run("generalization.py", "pipeline=gensim", "debug=tiny", f"store={root / 'store'}", "task_group=stacking",
                "tasks=[stack-two-blocks]", "heldout_tasks=[]", "eval.splits=[]", "eval.sampler_check=false",
                "torch_threads=1", f"checkpoint_dir={root / 'ck'}", "progress=false",
                f"hydra.sweep.dir={root / 'policy'}", *launch, "-m", "seed=0,1")
        assert p.returncode == 0, p.stderr[-3000:]
        collected = [json.loads((root / "collect" / str(i) / "result.json").read_text())["values"] for i in range(2)]
        trained = [json.loads((root / "policy" / str(i) / "result.json").read_text())["values"]["training"]
                   for i in range(2)]
        return ([{"tasks": v["tasks"], "new": [(e["task"], e["seed"], e["success"], e["steps"]) for e in v["new"]]}
                 for v in collected],
                [(t["steps"], t["windows"], t["final_loss"]) for t in trained], _episode_arrays(root / "store"))

    local = sweeps("local", [], {k: v for k, v in slurm.items() if k != "SLURM_CONF"})
    on_cluster = sweeps("slurm", [*LAUNCH, "hydra.launcher.mem_gb=2"], slurm)
    assert on_cluster[0] == local[0] and on_cluster[1] == local[1]
    assert sorted({k.split("/")[1] for k in on_cluster[2]}) == ["place-red-in-green", "stack-two-blocks"]
    assert on_cluster[2].keys() == local[2].keys()
    for key, array in local[2].items():
        assert (on_cluster[2][key] == array).all(), key
    assert len(list((tmp_path / "slurm" / "collect" / ".submitit").glob("*_0"))) == 1  # ran as SLURM array jobs
    assert on_cluster[1][0][2] != on_cluster[1][1][2]  # two seeds, two trainings


# A tiny world-model sweep long enough to be interrupted: 1 training window per epoch, one step per epoch
TRAINING = ["pipeline=gensim", "debug=tiny", "threads=1", "progress=false", "task_group=diverse", "protocol=paper",
            "eval_episodes=[1,3]", "heldout_episodes=null", "videos=0", "world_model.train.checkpoint_every=50"]
EPOCHS = 800  # one step each: ~20-40 s of training
RESUMED = r"resumed from \S+world_model-\w+\.pt at epoch \d+, batch \d+ \(step (\d+)\)"  # its step: group 1


@pytest.fixture(scope="module")
def training_store(tmp_path_factory):
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    store = tmp_path_factory.mktemp("store")
    write_group(store, "diverse", n_tasks=2, episodes=3, n_actions=10, size=16, pipeline="gensim")
    return store


def _training_sweep(env: dict, tmp: Path, store: Path, *overrides: str, slurm: bool = True,
                    epochs: int = EPOCHS) -> subprocess.Popen:
    cmd = [sys.executable, str(ROOT / "src" / "diversity.py"), *TRAINING, f"world_model.train.epochs={epochs}",
           f"store={store}", f"checkpoint_dir={tmp / 'ck'}", f"hydra.sweep.dir={tmp / 'sweep'}",
           *(LAUNCH if slurm else []), *overrides, "-m", "episodes=2"]
    # the sweep's output to files, not pipes: a full pipe nobody reads would stop the training mid-log
    with (tmp / "sweep.out").open("a") as out, (tmp / "sweep.err").open("w") as err:
        return subprocess.Popen(cmd, cwd=tmp, env={**env, "OMP_NUM_THREADS": "1"}, stdout=out, stderr=err)


_HELD_SINCE: dict[str, float] = {}  # job id -> when _release_requeued first saw it held after a requeue
RELEASE_AFTER_S = 2.0


def _release_requeued(env: dict) -> None:
    """SLURM holds a requeued job for 2 minutes (Reason=BeginTime) before it may start again, which would only make
    a test slow: start it, but not within the second of its requeue. The hold is the credential's lifetime
    (`AuthInfo=cred_expire`, 120 s): slurmd revokes the job's credential at the requeue, to the second, and refuses
    a launch whose new credential carries the same second ("Job N already killed, do not launch batch job";
    slurmctld: "Killing non-startable batch JobId=N: Job credential revoked"), so the job ends FAILED without a
    result. Released at once, that happened whenever the restart fell in the requeue's second (once on CI, once in a
    full local run; reproduced at the first requeue with a 0.05 s poll); RELEASE_AFTER_S after the hold is first
    seen it cannot."""
    held = set()
    for line in subprocess.run(["squeue", "-h", "-o", "%i %r"], env=env, capture_output=True,
                               text=True).stdout.splitlines():
        job, reason = line.split(maxsplit=1)
        if reason != "BeginTime":
            continue
        held.add(job)
        if time.time() - _HELD_SINCE.setdefault(job, time.time()) >= RELEASE_AFTER_S:
            subprocess.run(["scontrol", "update", f"JobId={job}", "StartTime=now"], env=env, capture_output=True)
    for job in set(_HELD_SINCE) - held:  # started again (or gone): its next requeue waits afresh
        del _HELD_SINCE[job]


def _wait(proc: subprocess.Popen, env: dict, tmp: Path, timeout: float = 600) -> tuple[int, str]:
    """Wait for the sweep, releasing its requeued jobs (_release_requeued: 2 s after their hold is first seen)."""
    deadline = time.time() + timeout
    while proc.poll() is None and time.time() < deadline:
        _release_requeued(env)
        time.sleep(0.5)
    if proc.poll() is None:
        proc.kill()
    return proc.wait(), (tmp / "sweep.err").read_text()


def _job_logs(tmp: Path) -> str:
    return "".join(p.read_text() for p in sorted((tmp / "sweep" / ".submitit").glob("*/*_log.*")))


def _failed_sweep(env: dict, tmp: Path, err: str) -> str:
    """What a failed training sweep's assertion shows: the launching process's stderr, the job's own log (what it
    did when it stopped; not the per-epoch lines) and SLURM's record of each of its runs (when it started and ended,
    how). CI keeps none of these once the test is over."""
    log = "".join(line for line in _job_logs(tmp).splitlines(keepends=True) if " done: step " not in line) \
        if (tmp / "sweep" / ".submitit").is_dir() else ""
    runs = subprocess.run(["sacct", "-D", "-X", "-P", "-o", "JobID,State,Start,End,ExitCode"], env=env,
                          capture_output=True, text=True, check=False).stdout if "SLURM_CONF" in env else ""
    return f"the sweep's stderr:\n{err[-3000:]}\nthe job's log:\n{log[-5000:]}\nsacct -D:\n{runs}"


def _values(tmp: Path) -> dict:
    rec = json.loads((tmp / "sweep" / "0" / "result.json").read_text())
    assert rec["status"] == "ok"
    train = rec["values"]["train"]
    return {"eval": rec["values"]["eval"], "steps": train["steps"], "frames": train["frames"]}


@pytest.fixture(scope="module")
def uninterrupted(training_store, tmp_path_factory):
    """The same sweep run straight through on this machine (Hydra's basic launcher): what every interrupted
    cluster run must end with, bit for bit (a resumed training replays the same batches and draws)."""
    tmp = tmp_path_factory.mktemp("uninterrupted")
    env = {k: v for k, v in os.environ.items() if k != "HYDRA_FULL_ERROR"}
    rc, err = _wait(_training_sweep(env, tmp, training_store, slurm=False), env, tmp)
    assert rc == 0, err[-3000:]
    return _values(tmp)


LONG_EPOCHS = 5000  # must outlast SLURM's signal. slurmctld checks time limits every 30 s and sends `--signal=USR2@W`
# at the first check with at most W + 30 s left: under a 2-minute limit with W = 60, 30-60 s after each start (seen
# here: 56-58 s), 1600-3200 steps at 0.019 s/step, and 60-90 s before the kill. A 1-minute limit with W = 40 (the
# earlier set-up) signals at the first check after the start, which can fall before submitit's handler is installed
# (the job then dies of the signal without a result: seen once on CI)


@pytest.mark.timeout(900)  # waits for a training sweep of 2-4 min (more on a busy machine)
def test_a_job_at_its_time_limit_is_requeued_and_resumes_at_the_step_it_stopped(slurm, tmp_path, training_store):
    """SLURM itself signals the job (USR2, `--signal=USR2@60` under a 2-minute limit); submitit requeues it and the
    training goes on from the step the signal came in, however many times, to its last step. (That a resumed training
    ends bit for bit as the uninterrupted one is the next two tests' check, on the shorter training.)"""
    rc, err = _wait(_training_sweep(slurm, tmp_path, training_store, "hydra.launcher.timeout_min=2",
                                    "hydra.launcher.signal_delay_s=60", "hydra.launcher.max_num_timeout=8",
                                    epochs=LONG_EPOCHS), slurm, tmp_path)
    assert rc == 0, _failed_sweep(slurm, tmp_path, err)
    log = _job_logs(tmp_path)
    stopped = re.findall(r"preempted at step (\d+): checkpoint saved", log)
    resumed = re.findall(RESUMED, log)
    assert stopped, f"the training ended before SLURM's signal: lengthen LONG_EPOCHS\n{log[-2000:]}"
    assert resumed == stopped, log[-4000:]  # every stop resumed at its own step, none from step 0
    assert "this job is timed-out" in log  # SLURM's time-limit signal, not one the test sent
    assert _values(tmp_path)["steps"] == LONG_EPOCHS


@pytest.mark.timeout(900)  # each waits for a training sweep of ~1 min (more on a busy machine)
def test_a_cancelled_job_resumes_from_its_checkpoint_when_the_sweep_is_run_again(slurm, tmp_path, training_store,
                                                                                 uninterrupted):
    proc = _training_sweep(slurm, tmp_path, training_store)
    deadline = time.time() + 120
    while not ((tmp_path / "sweep" / ".submitit").is_dir() and f"epoch 120/{EPOCHS} done" in _job_logs(tmp_path)):
        assert proc.poll() is None and time.time() < deadline, (tmp_path / "sweep.err").read_text()[-3000:]
        time.sleep(0.2)
    [job] = subprocess.run(["squeue", "-h", "-o", "%i"], env=slurm, capture_output=True, text=True).stdout.split()
    subprocess.run(["scancel", job], env=slurm, check=True)
    rc, err = _wait(proc, slurm, tmp_path)
    assert rc == 1 and "Traceback" not in err, err[-3000:]
    # with what SLURM said of the job (sacct: "CANCELLED by <uid>")
    assert re.fullmatch(
        re.escape(f"error: a job of the sweep died without a result (killed, out of memory?): job {job} (task 0) "
                  "left no result (state: CANCELLED") + r"[^)]*" + re.escape(
            f"); its log: {tmp_path / 'sweep' / '.submitit' / job / job}_0_log.err and _log.out. Run the same "
            "command again: finished runs are kept and a training resumes from its last checkpoint"),
        err.strip().splitlines()[-1]), err[-3000:]
    rc, err = _wait(_training_sweep(slurm, tmp_path, training_store), slurm, tmp_path)  # the same command again
    assert rc == 0, _failed_sweep(slurm, tmp_path, err)
    [step] = re.findall(RESUMED, _job_logs(tmp_path))
    assert int(step) >= 100  # the last periodic checkpoint before the kill (every 50 steps), not step 0
    assert _values(tmp_path) == uninterrupted


def _epochs_done(log: str) -> int:
    return max(map(int, re.findall(rf"epoch (\d+)/{EPOCHS} done", log)), default=0)


@pytest.mark.timeout(900)  # each waits for a training sweep of ~1 min (more on a busy machine)
def test_a_preempted_then_requeued_job_resumes_each_time_and_ends_as_the_uninterrupted_run(slurm, tmp_path,
                                                                                          training_store,
                                                                                          uninterrupted):
    """Two interruptions of one running job. A preemption: SLURM's preemption signal (USR2, sent here with `scancel
    --signal`, far from the time limit), on which the training checkpoints at the step it is in and submitit
    requeues the job itself (a preemption does not count against max_num_timeout); it resumes at that step. Then an
    administrator's `scontrol requeue`, which gives no signal to checkpoint on (SIGTERM, which submitit ignores, and
    SIGKILL 5 s later): the job comes back and resumes from its last checkpoint (saved at every epoch's end; here
    an epoch is one step), past the step it had reached when requeued. It ends with the numbers of the run never
    interrupted."""
    proc = _training_sweep(slurm, tmp_path, training_store)

    def wait_for(done, what: str) -> str:
        deadline = time.time() + 300
        while True:
            log = _job_logs(tmp_path) if (tmp_path / "sweep" / ".submitit").is_dir() else ""
            if done(log):
                return log
            # the sweep's own stderr too: once (a full local run, 2026-11-28) the launching process ended with
            # status 1 right after the preemption and only the job's log was shown
            assert proc.poll() is None and time.time() < deadline, \
                f"{what}: sweep status {proc.poll()}; its stderr: {(tmp_path / 'sweep.err').read_text()[-3000:]}; " \
                f"the job's log: {log[-3000:]}"
            _release_requeued(slurm)
            time.sleep(0.2)

    wait_for(lambda log: _epochs_done(log) >= 120, "the first 120 steps")
    [job] = subprocess.run(["squeue", "-h", "-o", "%i"], env=slurm, capture_output=True, text=True).stdout.split()
    subprocess.run(["scancel", "--signal=USR2", job], env=slurm, check=True)
    log = wait_for(lambda log: len(re.findall(RESUMED, log)) == 1, "the resume after the preemption")
    [stopped] = map(int, re.findall(r"preempted at step (\d+): checkpoint saved", log))
    assert "this job is preempted" in log and re.findall(RESUMED, log) == [str(stopped)]
    wait_for(lambda log: len(re.findall(RESUMED, log)) == 1 and _epochs_done(log.split("resumed from")[-1]) >= 220,
             "100 steps after the resume")
    subprocess.run(["scontrol", "requeue", job], env=slurm, check=True)
    rc, err = _wait(proc, slurm, tmp_path)
    assert rc == 0, _failed_sweep(slurm, tmp_path, err)
    log = _job_logs(tmp_path)
    first, second = map(int, re.findall(RESUMED, log))
    assert first == stopped and second >= 220  # its last checkpoint (each epoch's end), not the preemption's
    assert len(re.findall(r"preempted at step", log)) == 1  # the requeue gave nothing to checkpoint on
    assert _values(tmp_path) == uninterrupted


@pytest.mark.timeout(900)  # waits for SLURM's signal, 30-60 s after the job starts (more on a busy machine)
def test_a_job_out_of_requeues_ends_the_sweep_with_one_line_naming_the_limits(slurm, tmp_path, training_store):
    rc, err = _wait(_training_sweep(slurm, tmp_path, training_store, "hydra.launcher.timeout_min=2",
                                    "hydra.launcher.signal_delay_s=60", "hydra.launcher.max_num_timeout=0",
                                    epochs=LONG_EPOCHS), slurm, tmp_path)
    assert rc == 1 and "Traceback" not in err, _failed_sweep(slurm, tmp_path, err)
    last = err.strip().splitlines()[-1]
    assert last.startswith("error: the sweep's job [") and "episodes=2] stopped and was not requeued again " \
        "(timed-out too many times; hydra.launcher.timeout_min=2, hydra.launcher.max_num_timeout=0): its last " \
        "checkpoint is kept; run the same command again to resume it" in last
    assert list((tmp_path / "ck").glob("world_model-*.pt"))  # saved in the step the signal came in


def _sacct_times(env: dict, jobs: list[str]) -> dict[str, tuple[str, str]]:
    out = subprocess.run(["sacct", "-n", "-X", "-P", "-o", "JobID,Start,End", "-j", ",".join(jobs)], env=env,
                         capture_output=True, text=True, check=True).stdout
    return {j: (start, end) for j, start, end in (line.split("|") for line in out.split())}


@pytest.mark.timeout(1500)  # the quick chain of one pipeline twice (here and on the cluster), ~3 min each
def test_the_paper_chain_as_dependent_jobs_survives_a_cancelled_job_and_ends_with_the_local_tables(slurm, tmp_path):
    """`make evaluate PIPELINE=robogen LAUNCHER=slurm` at the quick profile: every stage a job, each world model
    and policy started only after its group's collection ended, the report after everything; a job cancelled
    mid-run ends the run with one line naming it, and the same command again finishes what is left and gives the
    tables of the run made here, stage after stage."""
    common = [sys.executable, str(ROOT / "src" / "paper.py"), "profile=quick", "pipelines=[robogen]",
              "stages=[collect,table4,table5,report]"]
    local = subprocess.run([*common, f"out={tmp_path / 'local'}"], cwd=ROOT, capture_output=True, text=True,
                           timeout=900, env={k: v for k, v in slurm.items() if k != "SLURM_CONF"})
    assert local.returncode == 0, local.stderr[-3000:]
    on_cluster = [*common, f"out={tmp_path / 'slurm'}", "launcher=slurm",
                  "sbatch_args='--partition=debug --mem=2G --cpus-per-task=1'"]
    with (tmp_path / "first.out").open("w") as out, (tmp_path / "first.err").open("w") as err:
        first = subprocess.Popen(on_cluster, cwd=ROOT, env=slurm, stdout=out, stderr=err)
    deadline, cancelled = time.time() + 600, None
    while cancelled is None:  # cancel the first world model as soon as it runs
        assert first.poll() is None and time.time() < deadline, (tmp_path / "first.err").read_text()[-3000:]
        submitted = re.findall(r"job (\d+) after (\d+): .*diversity\.py", (tmp_path / "first.out").read_text())
        running = subprocess.run(["squeue", "-h", "-t", "R", "-o", "%i"], env=slurm, capture_output=True,
                                 text=True).stdout.split()
        cancelled = next((job for job, _ in submitted if job in running), None)
        time.sleep(0.2)
    subprocess.run(["scancel", cancelled], env=slurm, check=True)
    assert first.wait(timeout=600) == 1
    last = (tmp_path / "first.err").read_text().strip().splitlines()[-1]
    assert last.startswith("error: ") and f"the first, {cancelled} (table4_robogen_" in last and \
        "ended CANCELLED" in last and last.endswith("rerun the same command: finished stages are kept")
    text = (tmp_path / "first.out").read_text()
    for job, collect in re.findall(r"job (\d+) after (\d+): .*(?:diversity|generalization)\.py", text):
        times = _sacct_times(slurm, [job, collect])
        if job != cancelled and times[job][0] != "None":  # started: only once its group's collection had ended
            assert times[job][0] >= times[collect][1]
    again = subprocess.run(on_cluster, cwd=ROOT, env=slurm, capture_output=True, text=True, timeout=900)
    assert again.returncode == 0, again.stderr[-3000:]
    assert "diversity.py" in again.stdout and f"job {cancelled}" not in again.stdout  # only what was left
    for table in ("table4.csv", "table5.csv"):
        assert (tmp_path / "slurm" / "tables" / table).read_text() == (tmp_path / "local" / "tables" / table).read_text()
