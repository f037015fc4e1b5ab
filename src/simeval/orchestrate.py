"""The paper's measurements for some pipelines, stage after stage or as SLURM jobs (src/paper.py is its command
line; conf/paper.yaml and conf/profile/ configure it).

    run_profile(profile, pipelines, stages, out, suites=..., entries=..., cwd=...)

First, two stages that need no episodes:
    table3/         src/text_diversity.py -m experiment=table3 pipeline.source=suite: Table 3's layout on simeval's
                    own suites' task descriptions -> tables/table3.* (the paper's task lists: `make table3`, which
                    `make paper` runs when GENSIM_DESCS=/ROBOGEN_ROOT=/BBSEA_ROOT= name them)
    figures/figure3/  src/agreement.py on the paper's appendix score tables (simeval/writing/paper_human_eval.json;
                    SIMEVAL_HUMAN_SCORES=file for yours): the paper's Figure 3
Then for each pipeline with a simeval suite (conf/pipeline/<name>.yaml `suite:`), it runs the entrypoints a user
would type, as subprocesses, each into its own folder under `out`:
    collect/        src/collect.py: the profile's episodes of the first `tasks_per_group` tasks of every group
    quality/        src/quality.py judge=oracle on those episodes (a VLM judge: run quality.py yourself)
    table4/         src/diversity.py per group and training-episode count (the paper's 10/20/40, scaled)
    table5/         src/generalization.py per group: train, eval (varied) and held-out splits
then rebuilds, from the result.json files only (src/report.py report=all, as `make report` does), tables/table4.*,
tables/table5.*, figures/table4.*, figures/table5.*, figures/figure4.* and the HTML report, and prints where they are.

Resumable: a stage whose result.json exists is skipped, and the entrypoints resume their own work (collection
per episode, training from checkpoints under out/checkpoints/). A failing stage stops the run with its exit
status; rerun the same command after fixing the cause.

With launcher "slurm" every stage is one batch job (`sbatch --wrap` of the same command, its log the same file),
submitted at once with its dependencies: a group's world models and policy after its collection, a pipeline's
quality after its collections, the report after everything; a job whose dependency failed is cancelled
(--kill-on-invalid-dep). It waits for the jobs (`sacct`), prints each one's end and, when one failed, its log and
exits 1; rerun the same command: finished stages are skipped as above. While jobs of the same output folder are
still queued or running, a rerun refuses with one line (two jobs writing one run would mix them).
"""

from __future__ import annotations

import hashlib
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from simeval.errors import REFUSAL_FILE_ENV, USER_ERROR_EXIT, UserError, read_refusal

STAGES = ("table3", "figure3", "collect", "quality", "table4", "table5", "report")
# Figure 3 from the paper's own appendix score tables, shipped with the package;
# SIMEVAL_HUMAN_SCORES points it at a table of your own
PAPER_HUMAN_SCORES = Path(__file__).resolve().parent / "writing" / "paper_human_eval.json"
SUITE_TABLE3_CAPTION = ("Text diversity (paper Eq. 1) of simeval's own suites' task descriptions, not the paper's "
                        "task lists (make table3 with GENSIM_DESCS=/ROBOGEN_ROOT=/BBSEA_ROOT= for those)")


def groups_of(suite: str, tasks_per_group: int | None) -> dict[str, list[str]]:
    """{group: task names}: all of them when `tasks_per_group` is None, else the first `tasks_per_group` tasks by
    name that the policy trains on, plus the group's first held-out task (splits.yaml), so a subset still trains
    on that many tasks and still has a held-out split."""
    from simeval.sim.tasks.spec import suite_dir, load_suite
    from simeval.sim.tasks.splits import load_heldout

    specs = sorted(load_suite(suite_dir(suite)), key=lambda s: s.name)
    heldout = load_heldout(suite_dir(suite), specs)
    groups: dict[str, list[str]] = {}
    for spec in specs:
        groups.setdefault(spec.group, []).append(spec.name)
    if not tasks_per_group:
        return dict(sorted(groups.items()))
    out = {}
    for g, names in sorted(groups.items()):
        held = [n for n in names if n in heldout.get(g, [])]
        out[g] = [n for n in names if n not in held][:tasks_per_group] + held[:1]
    return out


def _stop_with_parent() -> None:
    """In a stage's process, before it starts: SIGTERM when this script dies, however it dies (kill -9 too), so an
    orphaned stage never keeps writing beside the rerun that resumes it. Linux only (prctl PR_SET_PDEATHSIG)."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # 1 = PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass


def run(cmd: list[str], log: Path, cwd: Path, echo: bool = False) -> None:
    """Run one stage; its output goes to `log` (and the last lines to the console if it fails; all of it with
    `echo`)."""
    log.parent.mkdir(parents=True, exist_ok=True)
    print(f"  $ {shlex.join(cmd)}", flush=True)
    t0 = time.monotonic()
    refusal = log.with_suffix(".refusal.json")  # where the stage says which value it refused, if it does
    refusal.unlink(missing_ok=True)
    with log.open("w") as f:
        p = subprocess.run(cmd, cwd=cwd, stdout=f, stderr=subprocess.STDOUT, preexec_fn=_stop_with_parent,
                           env={**os.environ, REFUSAL_FILE_ENV: str(refusal)})
    said = read_refusal(refusal) if p.returncode == USER_ERROR_EXIT else None
    if said:  # a value the stage refused: its one line is the whole story, as when the user runs it alone
        print(f"error: {log.stem}: {said['error']} (log: {log})", file=sys.stderr)
        raise SystemExit(USER_ERROR_EXIT)
    if p.returncode != 0:
        tail = log.read_text().splitlines()[-15:]
        print("\n".join(f"    | {line}" for line in tail), file=sys.stderr)
        print(f"error: stage failed with exit status {p.returncode} (log: {log}); fix the cause and rerun the "
              "same command: finished stages are kept", file=sys.stderr)
        raise SystemExit(p.returncode)
    if echo:
        print("\n".join(f"    {line}" for line in log.read_text().splitlines()))
    print(f"    done in {time.monotonic() - t0:.0f} s ({log.stem})", flush=True)


def finished(run_dir: Path, done: bool | None = None) -> bool:
    """Whether a stage is kept: its run folder has its result.json (or `done`, the stage's own test), as an earlier
    run of the same command left it. The console says so: a rerun after an interruption shows what it resumes from."""
    if done is None:
        done = (run_dir / "result.json").exists()
    if done:
        print(f"  kept: {run_dir} (finished earlier; delete the folder to run it again)", flush=True)
        return True
    return False


class Local:
    """Stages run here, one after the other, in the order they are given (which respects their dependencies), from
    `cwd` (the project root)."""

    def __init__(self, cwd: Path) -> None:
        self.cwd = cwd

    def stage(self, cmd: list[str], log: Path, after: tuple = (), echo: bool = False) -> None:
        run(cmd, log, self.cwd, echo)

    def finish(self) -> None:
        pass


FINAL_STATES = {"COMPLETED", "FAILED", "CANCELLED", "TIMEOUT", "OUT_OF_MEMORY", "NODE_FAIL", "PREEMPTED",
                "BOOT_FAIL", "DEADLINE"}


class Slurm:
    """Stages as SLURM batch jobs with dependencies (see the module docstring). `stage` returns the job id, which
    later stages name in `after`; `finish` waits for every job and reports. Jobs are named after the output
    folder, so a rerun can see that jobs of the same run are still on the cluster."""

    def __init__(self, out: Path, sbatch_args: list[str], cwd: Path, poll_s: float = 2.0) -> None:
        self.cwd = cwd
        self.name = f"simeval-paper-{hashlib.sha1(str(out.resolve()).encode()).hexdigest()[:8]}"
        self.sbatch_args, self.poll_s = sbatch_args, poll_s
        self.jobs: dict[str, tuple[Path, bool]] = {}  # job id -> (log, echo)
        for tool in ("sbatch", "squeue", "sacct"):
            if shutil.which(tool) is None:
                raise UserError(f"launcher=slurm: `{tool}` is not on PATH (no SLURM client here); use "
                                "launcher=local")
        queued = subprocess.run(["squeue", "-h", "-n", self.name, "-o", "%i"], capture_output=True, text=True)
        if queued.returncode != 0:
            said = [line.strip().removeprefix("squeue: ") for line in (queued.stderr or queued.stdout).splitlines()
                    if line.strip()]
            raise UserError("launcher=slurm: no SLURM controller answers here (squeue: "
                            f"{said[-1] if said else queued.returncode}); run it on the cluster's login node, or "
                            "point SLURM_CONF at its slurm.conf")
        if queued.stdout.split():
            raise UserError(f"jobs of this run ({out}) are still queued or running: "
                            f"{', '.join(queued.stdout.split())}; wait "
                            f"for them (squeue -n {self.name}) or cancel them (scancel -n {self.name}), then rerun")

    def stage(self, cmd: list[str], log: Path, after: tuple = (), echo: bool = False) -> str:
        log.parent.mkdir(parents=True, exist_ok=True)
        deps = [j for j in after if j]
        sbatch = ["sbatch", "--parsable", f"--job-name={self.name}", f"--output={log}", f"--chdir={self.cwd}",
                  "--kill-on-invalid-dep=yes", *([f"--dependency=afterok:{':'.join(deps)}"] if deps else []),
                  *self.sbatch_args, f"--wrap={shlex.join(cmd)}"]
        p = subprocess.run(sbatch, capture_output=True, text=True)
        if p.returncode != 0:
            said = (p.stderr or p.stdout).strip().splitlines()
            raise UserError(f"sbatch refused the stage {log.stem}: {said[-1] if said else p.returncode} "
                            f"(sbatch_args={shlex.join(self.sbatch_args) or '(none)'})")
        job = p.stdout.strip().split(";")[0]
        print(f"  job {job}{' after ' + ','.join(deps) if deps else ''}: {shlex.join(cmd)}", flush=True)
        self.jobs[job] = (log, echo)
        return job

    def states(self) -> dict[str, str]:
        p = subprocess.run(["sacct", "-n", "-X", "-P", "-o", "JobID,State", "-j", ",".join(self.jobs)],
                           capture_output=True, text=True)
        out = {}
        for line in p.stdout.splitlines():
            job, _, state = line.partition("|")
            out[job] = state.split()[0] if state else "UNKNOWN"  # "CANCELLED by 0" -> CANCELLED
        return out

    def finish(self) -> None:
        if not self.jobs:
            return
        print(f"waiting for {len(self.jobs)} jobs (squeue -n {self.name})", flush=True)
        t0, seen = time.monotonic(), {}
        while True:
            states = self.states()
            for job, state in states.items():
                if job in self.jobs and state in FINAL_STATES and job not in seen:
                    seen[job] = state
                    print(f"    job {job} {state} after {time.monotonic() - t0:.0f} s ({self.jobs[job][0].stem})",
                          flush=True)
            if len(seen) == len(self.jobs):
                break
            time.sleep(self.poll_s)
        for job, (log, echo) in self.jobs.items():
            if echo and seen[job] == "COMPLETED":
                print("\n".join(f"    {line}" for line in log.read_text().splitlines()))
        failed = [j for j, st in seen.items() if st != "COMPLETED"]
        if failed:
            first = ([j for j in failed if seen[j] != "CANCELLED"] or failed)[0]  # the cause, not its dependents
            log = self.jobs[first][0]
            tail = log.read_text().splitlines()[-15:] if log.is_file() else []
            print("\n".join(f"    | {line}" for line in tail), file=sys.stderr)
            print(f"error: {len(failed)} of {len(self.jobs)} jobs did not complete; the first, {first} "
                  f"({log.stem}), ended {seen[first]} (log: {log}); the others depending on it were cancelled. Fix "
                  "the cause and rerun the same command: finished stages are kept", file=sys.stderr)
            raise SystemExit(1)


@dataclass
class Plan:
    """Where a profile's stages run and write: `entries`, the folder of the src/*.py entrypoints; `cwd`, the
    project root they run from; `out`, the run's folder; `launcher`, Local or Slurm."""

    profile: dict
    out: Path
    entries: Path
    cwd: Path
    launcher: object
    human_scores: Path

    @property
    def store(self) -> Path:
        return self.out / "episodes"

    @property
    def logs(self) -> Path:
        return self.out / "logs"

    def entry(self, name: str) -> list[str]:
        return [sys.executable, str(self.entries / f"{name}.py")]

    def overrides(self, pipeline: str) -> dict[str, list[str]]:
        """Each entrypoint's overrides of the profile, with the pipeline's own appended."""
        extra = (self.profile.get("pipeline_overrides") or {}).get(pipeline, {})
        return {stage: [*args, *extra.get(stage, [])] for stage, args in self.profile["overrides"].items()}


def run_profile(prof: dict, pipelines: list[str], stages: set[str], out: Path, suites: dict[str, str | None],
                entries: Path, cwd: Path, launcher_name: str = "local", sbatch_args: list[str] = (),
                human_scores: Path | None = None) -> None:
    """Every stage in `stages` for `pipelines` at the profile's cost (conf/profile/<name>.yaml, as a mapping), into
    `out`; `suites`: {pipeline: its simeval suite or None} for every known pipeline; launcher_name: local | slurm."""
    t_start = time.monotonic()
    check_profile(prof)
    unknown_pipelines = [p for p in pipelines if p not in suites]
    if unknown_pipelines:
        raise UserError(f"pipelines: {unknown_pipelines[0]}: no conf/pipeline/{unknown_pipelines[0]}.yaml; "
                        f"pipelines: {', '.join(sorted(suites))}")
    unknown = sorted(stages - set(STAGES))
    if unknown:
        raise UserError(f"stages: {','.join(unknown)}: unknown; stages: {','.join(STAGES)}")
    if launcher_name not in ("local", "slurm"):
        raise UserError(f"launcher={launcher_name}: unknown; local (stage after stage here) or slurm (batch jobs)")
    with_suite = [p for p in pipelines if suites[p]]
    if not with_suite:  # every stage but Figure 3 runs on a suite's episodes: nothing would run
        have = ", ".join(sorted(p for p, s in suites.items() if s))
        raise UserError(f"pipelines: {','.join(pipelines)}: no simeval suite to collect episodes from "
                        f"(pipeline.suite is null); pipelines with one: {have}. For your own pipeline, import its "
                        "episodes with src/import_data.py and run the entrypoints on them")
    launcher = Slurm(out, list(sbatch_args), cwd) if launcher_name == "slurm" else Local(cwd)
    human = Path(human_scores or os.environ.get("SIMEVAL_HUMAN_SCORES") or PAPER_HUMAN_SCORES)
    plan = Plan(prof, out, entries, cwd, launcher, human)
    jobs = _paper_wide_stages(plan, stages, with_suite)
    for pipeline in pipelines:
        if not suites[pipeline]:
            print(f"{pipeline}: no simeval suite (pipeline.suite is null): import its episodes with "
                  "src/import_data.py and run the entrypoints on them; skipped here")
            continue
        jobs += _pipeline_stages(plan, stages, pipeline, suites[pipeline])
    if "report" in stages:
        _report_stage(plan, jobs)
    launcher.finish()
    _list_outputs(plan, stages, time.monotonic() - t_start)


PROFILE_KEYS = ("name", "tasks_per_group", "episodes", "world_model_episodes", "overrides", "pipeline_overrides")


def check_profile(prof: dict) -> None:
    """A profile's values (conf/profile/<name>.yaml), checked before any stage runs, whichever stages use them:
    one UserError naming `profile.<key>`."""
    from simeval.errors import require_whole

    unknown = sorted(set(prof) - set(PROFILE_KEYS))
    missing = [k for k in PROFILE_KEYS[:-1] if k not in prof]  # pipeline_overrides may be left out
    if unknown or missing:
        what = f"unknown key(s) {', '.join(unknown)}" if unknown else f"missing {', '.join(missing)}"
        raise UserError(f"profile: {what}; a profile has {', '.join(PROFILE_KEYS)} (conf/profile/quick.yaml)")
    if prof["tasks_per_group"] is not None:
        require_whole("profile.tasks_per_group", prof["tasks_per_group"], 1)
    require_whole("profile.episodes", prof["episodes"], 1)
    counts = prof["world_model_episodes"]
    if not isinstance(counts, list) or not counts:
        raise UserError(f"profile.world_model_episodes={counts!r}: expected a list of episode counts, e.g. [10,20,40]")
    for count in counts:
        require_whole("profile.world_model_episodes[]", count, 1)
    if max(counts) > prof["episodes"]:
        raise UserError(f"profile.world_model_episodes={counts}: {max(counts)} is more than the "
                        f"profile.episodes={prof['episodes']} collected per task")
    if not isinstance(prof["name"], str) or not prof["name"]:
        raise UserError(f"profile.name={prof['name']!r}: expected a name (it names the output folder)")
    overrides = prof["overrides"] or {}
    per_pipeline = prof.get("pipeline_overrides") or {}
    if not isinstance(overrides, dict) or not isinstance(per_pipeline, dict) or not all(
            isinstance(v, dict) for v in per_pipeline.values()):
        raise UserError("profile.overrides / profile.pipeline_overrides: expected mappings of entrypoint to a list "
                        "of overrides (conf/profile/quick.yaml)")
    for where, args in [*((f"overrides.{k}", v) for k, v in overrides.items()),
                        *((f"pipeline_overrides.{p}.{k}", v) for p, d in per_pipeline.items() for k, v in d.items())]:
        if not isinstance(args, list) or not all(isinstance(a, str) for a in args):
            raise UserError(f"profile.{where}={args!r}: expected a list of overrides, e.g. "
                            f"\"profile.{where}=['episodes=4']\"")


def _paper_wide_stages(plan: Plan, stages: set[str], with_suite: list[str]) -> list:
    """Table 3 on the suites' own task descriptions (needs no checkout of the pipelines) and Figure 3."""
    stage, out, jobs = plan.launcher.stage, plan.out, []
    if "table3" in stages:
        runs, texts = out / "table3" / "runs", None
        # two embedding models per pipeline
        if not finished(runs, done=len(list(runs.glob("*/result.json"))) >= 2 * len(with_suite)):
            texts = stage([*plan.entry("text_diversity"), "-m", "experiment=table3",
                           f"pipeline={','.join(with_suite)}", "pipeline.source=suite", f"hydra.sweep.dir={runs}"],
                          plan.logs / "table3.log")
        jobs += [texts, stage([*plan.entry("report"), "report=table3", f"report.runs_dir={runs}",
                               f"report.out_dir={out / 'tables'}", f'report.caption="{SUITE_TABLE3_CAPTION}"'],
                              plan.logs / "report_table3.log", after=(texts,))]
    if "figure3" in stages and not finished(out / "figures" / "figure3"):
        jobs.append(stage([*plan.entry("agreement"), f"scores_path={plan.human_scores}",
                           f"hydra.run.dir={out / 'figures' / 'figure3'}"], plan.logs / "figure3.log"))
    return jobs


def _pipeline_stages(plan: Plan, stages: set[str], pipeline: str, suite: str) -> list:
    """One pipeline's collections, world models, policies and quality, each after what it reads."""
    prof, out, stage, logs = plan.profile, plan.out, plan.launcher.stage, plan.logs
    ov = plan.overrides(pipeline)
    groups = groups_of(suite, prof["tasks_per_group"])
    if stages & {"collect", "quality", "table4", "table5"}:  # what uses these groups (table3 reads every task)
        print(f"{pipeline} ({prof['name']}): groups "
              f"{', '.join(f'{g} ({len(t)} tasks)' for g, t in groups.items())}")
    jobs, collected = [], []  # collected: this pipeline's collections, which its quality stage reads
    for group, tasks in groups.items():
        sel, collect = f"tasks=[{','.join(tasks)}]", None
        if "collect" in stages:
            collect = stage([*plan.entry("collect"), f"pipeline={pipeline}", sel, f"episodes={prof['episodes']}",
                             f"store={plan.store}", *ov["collect"],
                             f"hydra.run.dir={out / 'collect' / pipeline / group}"],
                            logs / f"collect_{pipeline}_{group}.log")
            collected.append(collect)
        for k in prof["world_model_episodes"] if "table4" in stages else []:
            run_dir = out / "table4" / pipeline / group / f"episodes_{k}"
            if not finished(run_dir):
                jobs.append(stage([*plan.entry("diversity"), f"pipeline={pipeline}", f"task_group={group}",
                                   f"episodes={k}", f"store={plan.store}",
                                   f"checkpoint_dir={out / 'checkpoints' / 'world_model'}", *ov["diversity"],
                                   f"hydra.run.dir={run_dir}"], logs / f"table4_{pipeline}_{group}_{k}.log",
                                  after=(collect,)))
        run_dir = out / "table5" / pipeline / group
        if "table5" in stages and not finished(run_dir):
            jobs.append(stage([*plan.entry("generalization"), f"pipeline={pipeline}", f"task_group={group}", sel,
                               f"store={plan.store}", f"checkpoint_dir={out / 'checkpoints' / 'policy'}",
                               *ov["generalization"], f"hydra.run.dir={run_dir}"],
                              logs / f"table5_{pipeline}_{group}.log", after=(collect,)))
    jobs += collected
    run_dir = out / "quality" / pipeline
    if "quality" in stages and not finished(run_dir):
        jobs.append(stage([*plan.entry("quality"), f"episodes.store={plan.store}", f"episodes.pipeline={pipeline}",
                           *ov["quality"], f"cache_dir={out / 'cache'}", f"hydra.run.dir={run_dir}"],
                          logs / f"quality_{pipeline}.log", after=tuple(collected)))
    return jobs


def _report_stage(plan: Plan, jobs: list) -> None:
    """Tables and figures from the result.json files only, as `make report` builds them, after every other job."""
    out = plan.out
    plan.launcher.stage([*plan.entry("report"), "report=all", "report.steps=[table4,table5,figure4,html]",
                         f"report.table4.runs_dir={out / 'table4'}",
                         f"report.table4.episodes=[{','.join(map(str, plan.profile['world_model_episodes']))}]",
                         f"report.table5.runs_dir={out / 'table5'}", f"report.figure4.runs_dir={out / 'quality'}",
                         f"report.html.runs_dir={out}", f"paths.root={out}", f"paths.tables={out / 'tables'}",
                         f"paths.figures={out / 'figures'}"],  # paths.root: a stage folder not made yet is "skipped"
                        plan.logs / "report.log", after=tuple(jobs), echo=True)


def _list_outputs(plan: Plan, stages: set[str], seconds: float) -> None:
    out = plan.out
    print(f"\n{plan.profile['name']} profile finished in {seconds:.0f} s. Outputs in {out}:")
    if "report" not in stages:
        print("  (Tables 4, 5 and the HTML report are built by the report stage: stages=[...,report])")
    for sub in ("tables", "figures", "report"):
        for p in sorted((out / sub).rglob("*")) if (out / sub).is_dir() else []:
            if (p.is_file() and ".hydra" not in p.parts and "assets" not in p.parts
                    and p.suffix in (".csv", ".md", ".tex", ".png", ".pdf", ".html")):
                print(f"  {p.relative_to(plan.cwd) if p.is_relative_to(plan.cwd) else p}")
