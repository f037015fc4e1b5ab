"""Command-line conveniences shared by the Hydra entrypoints under `src/`.

Every entrypoint is written as::

    @hydra.main(version_base="1.3", config_path="../conf", config_name="NAME")
    @exit_cleanly_on_user_error
    def main(cfg): ...

    if __name__ == "__main__":
        launch(main)
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import typing
from collections.abc import Callable
from dataclasses import is_dataclass
from pathlib import Path
from typing import Any

from simeval.errors import REFUSAL_FILE_ENV, TYPE_WORDS, USER_ERROR_EXIT, EpisodesUnfit, UserError
from simeval.runtime.preemption import requeue_deaf_to_sigterm
from simeval.secrets import key_shaped_overrides

MULTIRUN_FLAGS = ("-m", "--multirun")


def move_multirun_flag_first(argv: list[str]) -> list[str]:
    """Return argv with `-m`/`--multirun` moved right after the program name.

    Users type `python src/diversity.py pipeline=bbsea -m episodes=10,20,40`; Hydra's argparse rejects a flag
    after an override. Only whole tokens move, so an override whose value is "-m" (`key=-m`) is untouched.
    """
    program, rest = argv[:1], argv[1:]
    if "--" in rest:  # everything after a bare `--` is positional by convention
        cut = rest.index("--")
        head, tail = rest[:cut], rest[cut:]
    else:
        head, tail = rest, []
    flags = [a for a in head if a in MULTIRUN_FLAGS]
    if not flags:
        return list(argv)
    others = [a for a in head if a not in MULTIRUN_FLAGS]
    return program + ["--multirun"] + others + tail


def allow_multirun_anywhere() -> None:
    """Rewrite sys.argv in place; call before the `@hydra.main` function."""
    sys.argv[:] = move_multirun_flag_first(sys.argv)


def _print_error(message: str) -> None:
    """`error: <message>` on stderr in one write: jobs of a parallel sweep share the terminal, and print() makes
    two writes (text, then newline) when stderr is unbuffered (PYTHONUNBUFFERED=1), so their lines interleaved."""
    sys.stderr.write(f"error: {message}\n")
    sys.stderr.flush()


def _fail(message: str, episodes_unfit: bool = False) -> None:
    """Stop on a user error: its one line on stderr, recorded for the process that ran this one, exit 2."""
    _record_refusal(message, episodes_unfit)
    _print_error(message)
    sys.exit(USER_ERROR_EXIT)


def refuse_secrets_on_command_line(argv: list[str]) -> None:
    """Stop before Hydra writes the overrides to `.hydra/`: a key typed as a value would be stored in clear."""
    for key, why in key_shaped_overrides(argv[1:]):
        _fail(f"override {key}=... looks like a secret ({why}); put the secret in an environment variable and give "
              f"its name (e.g. judge.provider.api_key_env=OPENAI_API_KEY), never the value")


def _user_error_in(exc: BaseException) -> BaseException | None:
    """The UserError (or config error) behind exc: `hydra.utils.instantiate` wraps what a constructor raises in
    an InstantiationException, so a provider's validation message would otherwise arrive as a traceback."""
    from omegaconf.errors import OmegaConfBaseException

    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, (UserError, OmegaConfBaseException)):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def scrub_saved_config_of_secrets(cfg: Any) -> None:
    """Refuse a config that holds a key-shaped value (e.g. a key pasted into a YAML file as `api_key_env`), after
    redacting it from the `.hydra/*.yaml` files Hydra has already written for this job."""
    from omegaconf import OmegaConf

    from simeval.secrets import find_key_shaped, redact_secrets

    hits = find_key_shaped(OmegaConf.to_container(cfg, resolve=False))
    if not hits:
        return
    try:
        from hydra.core.hydra_config import HydraConfig

        saved = Path(HydraConfig.get().runtime.output_dir) / ".hydra"
    except (ImportError, ValueError):
        saved = None
    if saved is not None and saved.is_dir():
        import yaml

        for path in saved.glob("*.yaml"):
            path.write_text(yaml.safe_dump(redact_secrets(yaml.safe_load(path.read_text())), sort_keys=False))
    key, why = hits[0]
    raise UserError(f"config key {key} holds what looks like a secret ({why}); put the secret in an environment "
                    f"variable and give its name (e.g. judge.provider.api_key_env=OPENAI_API_KEY), never the value")


HYDRA_SAVED = {"config.yaml", "hydra.yaml", "overrides.yaml"}


def remove_refused_run_folder() -> None:
    """Delete the folder Hydra made for this run when the run was refused before it made anything: it holds only
    Hydra's saved config (`.hydra/`) and logs, which this run wrote (in a sweep, the sweep's folder too when only its
    multirun.yaml is left), and then its parents under the runs root when they are left empty. Otherwise every
    mistyped command would leave a folder that a reader (or `report.runs_dir`) could take for a run. Only a
    folder named with this process's ${run_suffix:} goes: one the user named (hydra.run.dir=...) stays, as does
    one holding anything else."""
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        hc = HydraConfig.get()
        out, multirun = Path(hc.runtime.output_dir), hc.mode == RunMode.MULTIRUN
    except (ImportError, ValueError):  # not under Hydra
        return
    from simeval.results import SUFFIXES_MADE

    made = out.parent if multirun else out  # the folder whose name this process chose
    if not any(made.name.endswith(f"_{s}") for s in SUFFIXES_MADE) or not _only_hydra_files(out):
        return
    import shutil

    shutil.rmtree(out, ignore_errors=True)
    if multirun:
        if {p.name for p in made.iterdir()} - {"multirun.yaml"}:
            return
        shutil.rmtree(made, ignore_errors=True)
    for parent in (made.parent, made.parent.parent):  # <runs root>/<entrypoint>, then the runs root
        try:
            parent.rmdir()  # only when empty
        except OSError:
            return


def _only_hydra_files(folder: Path) -> bool:
    if not folder.is_dir() or folder.is_symlink():
        return False
    for entry in folder.iterdir():
        if entry.name == ".hydra" and entry.is_dir() and not entry.is_symlink():
            if not {p.name for p in entry.iterdir()} <= HYDRA_SAVED:
                return False
        # a log may hold lines this run wrote before it was refused (no metrics, results or videos: those stay)
        elif not (entry.suffix == ".log" and entry.is_file() and not entry.is_symlink()):
            return False
    return True


def in_multirun() -> bool:
    """True inside a job of a Hydra sweep (`-m`), whichever launcher runs it."""
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        return HydraConfig.get().mode == RunMode.MULTIRUN
    except (ImportError, ValueError):
        return False


def _log_failed_job(exc: BaseException) -> None:
    """A sweep's job that raised (not a user error): its traceback into the job's log and the console now. Hydra's
    launchers keep the exception in the job's result and start the next job with nothing said; the sweep's end
    names every failed job (stop_sweep_on_failed_jobs)."""
    import logging

    logging.getLogger("simeval").error("this job failed (%s: %s); the sweep goes on with its next job and exits 1 "
                                       "at the end", type(exc).__name__, exc, exc_info=exc)


def in_submitit_job() -> bool:
    """True inside a job of a Hydra sweep that submitit runs in a process of its own (`hydra/launcher=
    submitit_local`, `slurm`, `submitit_slurm`). Such a job cannot end the sweep by exiting: submitit only sees a
    job that left no result and the launching process prints its own traceback."""
    return bool(os.environ.get("SUBMITIT_EXECUTOR")) and in_multirun()


def exit_cleanly_on_user_error(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Decorate a Hydra task function (under `@hydra.main`): a UserError or a config-access error, also one
    raised inside `instantiate`, becomes one line on stderr and exit status 2. HYDRA_FULL_ERROR=1 re-raises
    for the full traceback. A config holding a key-shaped value is refused before anything runs.

    In a submitit job the line goes to the job's log and the error is raised as a plain UserError holding that
    line: Hydra stores it in the job's result, which submitit carries back to the launching process, where
    `stop_sweep_on_user_errors` (called by the sweeper of conf/hydra/default.yaml) prints it and exits 2."""

    @functools.wraps(fn)
    def wrapper(cfg: Any, *args: Any, **kwargs: Any) -> Any:
        try:
            scrub_saved_config_of_secrets(cfg)
            requeue_deaf_to_sigterm()
            return fn(cfg, *args, **kwargs)
        except Exception as e:
            cause = _user_error_in(e)
            if cause is None and in_multirun():
                _log_failed_job(e)
            if cause is None or os.environ.get("HYDRA_FULL_ERROR") == "1":
                raise
            text = str(cause).strip()
            line = text.splitlines()[0] if text else type(cause).__name__
            if in_submitit_job():
                _record_refusal(line, isinstance(cause, EpisodesUnfit))
                _print_error(line)
                raise UserError(line) from None  # picklable, unlike some config errors and their chained causes
            remove_refused_run_folder()
            _fail(line, isinstance(cause, EpisodesUnfit))

    return wrapper


def _record_refusal(line: str, episodes_unfit: bool) -> None:
    """When the process that started this one asked (REFUSAL_FILE_ENV), tell it why this run stopped and whether the
    episodes, not a setting, were at fault (simeval.errors.EpisodesUnfit)."""
    path = os.environ.get(REFUSAL_FILE_ENV)
    if path:
        Path(path).write_text(json.dumps({"error": line, "episodes_unfit": episodes_unfit}))


def stop_sweep_on_user_errors(results: Any) -> None:
    """In the launching process of a sweep, given the launcher's JobReturns: when any job stopped on a UserError
    (see exit_cleanly_on_user_error), print each distinct one as one `error: ...` line and exit 2, as a run
    without a launcher does, instead of Hydra's traceback of the first failed job. The other jobs of the batch
    have finished by then (the submitit launchers wait for all of them); their results are kept."""
    from hydra.core.utils import JobStatus

    if os.environ.get("HYDRA_FULL_ERROR") == "1":  # the job raised the original error: Hydra shows its traceback
        return
    # JobReturn._return_value is the exception itself: `return_value` re-raises it and Hydra 1.3 has no accessor
    lines = [str(r._return_value) for r in results
             if r.status == JobStatus.FAILED and isinstance(r._return_value, UserError)]
    if lines:
        recorded = os.environ.get(REFUSAL_FILE_ENV)
        if recorded and not Path(recorded).is_file():  # a job on another machine could not record it here
            _record_refusal(lines[0], False)
        for line in dict.fromkeys(lines):
            _print_error(line)
        sys.exit(USER_ERROR_EXIT)


def stop_sweep_on_failed_jobs(results: Any) -> None:
    """In the launching process, after the user errors and unrequeued jobs: where a job raised any other exception,
    print one line per failed job (its overrides, the exception, the log holding its traceback) and exit 1, in
    place of Hydra's traceback of the first failed job only. The sweep's other jobs have run and kept their
    results. HYDRA_FULL_ERROR=1 leaves Hydra's traceback."""
    from hydra.core.utils import JobStatus

    if os.environ.get("HYDRA_FULL_ERROR") == "1":
        return
    failed = [r for r in results if r.status == JobStatus.FAILED]
    if not failed:
        return
    for r in failed:
        exc = r._return_value  # the exception itself: `return_value` would raise it
        job = " ".join(r.overrides) if r.overrides else "a job"
        first = (str(exc).strip().splitlines() or [""])[0]
        _print_error(f"the sweep's job [{job}] failed: {type(exc).__name__}: {first} (traceback in {_job_log(r)})")
    _print_error(f"{len(failed)} of {len(results)} jobs failed; the others' results are kept")
    sys.exit(1)


def _job_log(result: Any) -> str:
    """The log file of a finished job (Hydra's job logging writes <output_dir>/<job name>.log)."""
    try:
        hydra = result.hydra_cfg.hydra
        return str(Path(hydra.runtime.output_dir) / f"{hydra.job.name}.log")
    except AttributeError:  # a launcher that returned no Hydra config
        return "the job's log"


def stop_sweep_on_unrequeued_jobs(results: Any, params: dict | None = None) -> None:
    """In the launching process: a job that submitit did not requeue again (it reached its time limit more often
    than max_num_timeout allows, or cannot be checkpointed) raised submitit's UncompletedJobError inside the job;
    print one line per such job, naming the settings that bound it and that its checkpoint is kept, and exit 1
    (the other jobs have finished by then) instead of Hydra's traceback."""
    from hydra.core.utils import JobStatus

    if os.environ.get("HYDRA_FULL_ERROR") == "1":
        return
    try:
        from submitit.core.utils import UncompletedJobError
    except ImportError:
        return
    failed = [r for r in results if r.status == JobStatus.FAILED and isinstance(r._return_value, UncompletedJobError)]
    if not failed:
        return
    params = params or {}
    limits = ", ".join(f"hydra.launcher.{k}={params[k]}" for k in ("timeout_min", "max_num_timeout") if k in params)
    for r in failed:
        why = str(r._return_value).strip().removeprefix("Job not requeued because: ").rstrip(".")
        job = " ".join(r.overrides) if r.overrides else "a job"
        _print_error(f"the sweep's job [{job}] stopped and was not requeued again ({why}; {limits or 'see the launcher'}"
                     "): its last checkpoint is kept; run the same command again to resume it, with a larger "
                     "hydra.launcher.timeout_min or max_num_timeout so it can finish")
    sys.exit(1)


SLURM_END_STATES = ("BOOT_FAIL", "CANCELLED", "COMPLETED", "DEADLINE", "FAILED", "NODE_FAIL", "OUT_OF_MEMORY",
                    "PREEMPTED", "TIMEOUT")  # sacct's states of a job that has ended


def dead_job_line(exc: BaseException) -> str:
    """One line for submitit's UncompletedJobError (a job of the sweep died without a result: killed, out of
    memory, a node lost), naming the job and its log instead of submitit's traceback and the log's tail."""
    import re

    text = str(exc)
    first = text.splitlines()[0] if text.strip() else type(exc).__name__
    m = re.search(r"Job (\S+) \(task: (\d+)\) with path (\S+)_result\.pkl", text)
    state = re.search(r"has not produced any output \(state: ([^)]+)\)", text)
    # SLURM's last word on the job (OUT_OF_MEMORY, TIMEOUT, NODE_FAIL, CANCELLED by <uid>...) tells what ended it;
    # the local executor's (FINISHED, INTERRUPTED: of its controller, not of the job) would mislead
    said = f" (state: {state.group(1)})" if state and state.group(1).startswith(SLURM_END_STATES) else ""
    where = (f"job {m.group(1)} (task {m.group(2)}) left no result{said}; its log: {m.group(3)}_log.err and _log.out"
             if m else first)
    return (f"a job of the sweep died without a result (killed, out of memory?): {where}. Run the same command "
            "again: finished runs are kept and a training resumes from its last checkpoint")


def refused_submission_line(exc: BaseException) -> str | None:
    """One line when sbatch refused a job of the sweep (more memory, CPUs or GPUs than a node of the partition
    has, an unknown partition or account): what sbatch said and what to change. None for any other failure."""
    text = str(exc)
    if "Batch job submission failed" not in text and "sbatch: error" not in text:
        return None
    said = "; ".join(dict.fromkeys(line.split("error:", 1)[1].strip() for line in text.splitlines()
                                   if "sbatch: error:" in line)) or text.strip().splitlines()[0]
    return (f"sbatch refused the sweep's jobs: {said}; ask for what a node of the partition has "
            "(hydra.launcher.mem_gb, cpus_per_task, gpus_per_node; `sinfo -o '%P %c %m %G'` lists each partition's "
            "CPUs, memory in MB and GPUs) or name another partition (hydra.launcher.partition)")


def stop_sweep_on_dead_jobs(launch: Callable[[], Any]) -> Any:
    """Call `launch` (a submitit launcher's launch); a job that died without a result ends the sweep with one
    `error:` line and exit 1 (not a user error; the other jobs have finished by then), a job sbatch refused with
    one line and exit 2 (a setting to change). HYDRA_FULL_ERROR=1 keeps submitit's exception."""
    try:
        from submitit.core.utils import UncompletedJobError
    except ImportError:  # no submitit installed: no submitit launcher either
        return launch()
    try:
        return launch()
    except UncompletedJobError as e:
        if os.environ.get("HYDRA_FULL_ERROR") == "1":
            raise
        refused = refused_submission_line(e)
        if refused is not None:  # nothing ran: a setting to change, not a job to rerun
            _fail(refused)
        _print_error(dead_job_line(e))
        sys.exit(1)


def entry_conf_dir() -> Path:
    """The conf/ folder of the running entrypoint: where `hydra.main(config_path="../conf")` beside it looks (the
    library itself reads no config from its own source tree)."""
    return Path(sys.argv[0]).resolve().parent.parent / "conf"


# Hydra's flags that choose what the command does, of which it takes one (flag -> the mode it chooses)
HYDRA_MODE_FLAGS = {"-m": "multirun", "--multirun": "multirun", "--cfg": "cfg", "-c": "cfg", "--info": "info",
                    "-i": "info", "--shell-completion": "shell", "-sc": "shell", "--run": "run", "-r": "run"}

# Hydra's own flags whose value is the next argument (`--cfg job`), not an override
HYDRA_FLAGS_WITH_VALUE = {"--cfg", "-c", "--package", "-p", "--info", "-i", "--config-path", "-cp", "--config-name",
                          "-cn", "--config-dir", "-cd", "--experimental-rerun"}


def config_mistakes(args: list[str], conf_dir: Path, config_name: str | None = None) -> str | None:
    """One line for what Hydra would report as a multi-line block and exit 1 on: an override it cannot parse, a
    config-group choice with no file (`world_model=nope`), or a chosen group file that is not valid YAML. None
    when it finds nothing (Hydra still checks everything else). Group files are also looked up in the
    `file://` folders of a `hydra.searchpath=[...]` override; with a `pkg://` entry the group check is left
    to Hydra, which can see inside packages. With `config_name` (the primary config), also a setting of a section
    the chosen option lacks (`protocol=paper +protocol.pixels=false`): with '+' Hydra would compose it and the run
    would stop on it only after Hydra made its folder."""
    import yaml
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import OverrideParseException

    overrides = [a for i, a in enumerate(args)
                 if not a.startswith("-") and not (i and args[i - 1] in HYDRA_FLAGS_WITH_VALUE)]
    try:
        parsed = OverridesParser.create().parse_overrides(overrides)
    except OverrideParseException as e:
        bad = next((o for o in overrides if _unparseable(o)), None)
        first = str(e).strip().splitlines()[0] if str(e).strip() else "cannot parse"
        return (f"override {bad!r}: {first}" if bad else first) + " (quote values with spaces, commas or braces: "\
            "key='{a: 1}')"
    conf_dirs = [conf_dir]
    for o in parsed:
        if o.key_or_group == "hydra.searchpath" and not o.is_delete():
            entries = o.value() if isinstance(o.value(), list) else [o.value()]
            if any(not str(e).startswith("file://") for e in entries):
                return None
            conf_dirs += [Path(str(e)[len("file://"):]) for e in entries]
    for o in parsed:
        groups = [d / o.key_or_group for d in conf_dirs if (d / o.key_or_group).is_dir()]
        # hydra/* groups (launchers, sweepers) also come from installed plugins, not only from conf/
        if o.is_delete() or not groups or o.package is not None or o.key_or_group.startswith("hydra/"):
            continue
        options = sorted({p.stem for g in groups for p in g.glob("*.yaml")})
        values = _choices(o, options)
        for v in values:
            if v == "null":
                continue
            path = next((g / f"{v}.yaml" for g in groups if (g / f"{v}.yaml").is_file()), None)
            if path is None:
                missing = (conf_dir / o.key_or_group / f"{v}.yaml").relative_to(conf_dir.parent)
                return f"{o.key_or_group}={v}: no {missing}; valid: {', '.join(options)}"
            try:
                yaml.safe_load(path.read_text())
            except yaml.YAMLError as e:
                mark = getattr(e, "problem_mark", None)
                where = f" line {mark.line + 1}, column {mark.column + 1}" if mark else ""
                return f"{path}:{where} is not valid YAML ({getattr(e, 'problem', None) or e})"
    if config_name is not None:
        return _section_of_another_option(parsed, conf_dir, config_name)
    return None


def _choices(o: Any, options: list[str]) -> list[str]:
    """The values an override gives its key or group: one, or each of a sweep's; a glob() sweep matched against the
    group's `options` (Hydra expands it with its config loader, which does not exist before Hydra runs)."""
    from hydra.core.override_parser.types import Glob

    if isinstance(o.value(), Glob):
        return o.value().filter(options)
    return [str(v) for v in o.sweep_iterator()] if o.is_sweep_override() else [str(o.value())]


def _section_of_another_option(parsed: list[Any], conf_dir: Path, config_name: str) -> str | None:
    """`group.key...=v` where the group's chosen option (its override, else the primary config's default; in a sweep
    over the group, any of its options) has no `key` and another option of the group has it: one line that names
    that option and the override as it would take it. In a sweep, a job of the other option would take it and the
    first job of this one refuse it only after the jobs before it had run."""
    chosen = {o.key_or_group: _choices(o, sorted(p.stem for p in (conf_dir / o.key_or_group).glob("*.yaml")))
              for o in parsed if (conf_dir / o.key_or_group).is_dir() and o.package is None and not o.is_delete()}
    for o in parsed:
        group, _, rest = o.key_or_group.partition(".")
        key = rest.partition(".")[0]
        if o.is_delete() or not key or group not in CHECKED_GROUPS or not (conf_dir / group).is_dir():
            continue
        options = chosen.get(group) or [_default_choice(conf_dir / f"{config_name}.yaml", group)]
        keys = {v: _option_keys(conf_dir / group, v) for v in options if v is not None and v != "null"}
        option = next((v for v, have in keys.items() if have is not None and key not in have), None)
        if option is None:
            continue
        every = {p.stem: _option_keys(conf_dir / group, p.stem) for p in sorted((conf_dir / group).glob("*.yaml"))}
        owners = [name for name, have in every.items() if have and key in have]
        if not owners:
            continue
        owner = f"{group}={owners[0]}"
        value = o.input_line.split("=", 1)[1]
        what = "a section" if isinstance(every[owners[0]][key], dict) else "a setting"
        given = f"{'++' if o.is_force_add() else '+' if o.is_add() else ''}{o.key_or_group}={value}"
        if len(options) > 1:
            return (f"{given}: {group}={option} has no {key} ({what} of {owner}), and this sweep runs {group}="
                    f"{option}; drop it, or sweep {owner} alone: {owner} {owner_form(conf_dir, owner, o.key_or_group)}"
                    f"{value}")
        return (f"{given}: {group}={option} has no {key} ({what} of {owner}); drop it, or run it with {owner}: "
                f"{owner} {owner_form(conf_dir, owner, o.key_or_group)}{value}")
    return None


# the config groups whose options' keys _section_of_another_option compares before Hydra composes: those whose
# options differ in sections a run reads (protocol=paper has no gate); any other group is left to Hydra
CHECKED_GROUPS = ("protocol",)


def _option_keys(group_dir: Path, option: str, seen: tuple[str, ...] = ()) -> dict[str, Any] | None:
    """A group option's top-level keys and their values, with those of the options of the same group its defaults
    list takes (judge=replay's `- openai`); None where it cannot tell without Hydra (a default from another group
    or package, a file that is not there or not a mapping, a cycle)."""
    import yaml

    try:
        data = yaml.safe_load((group_dir / f"{option}.yaml").read_text()) or {}
    except (OSError, yaml.YAMLError):
        return None
    if not isinstance(data, dict) or option in seen:
        return None
    keys = {k: v for k, v in data.items() if k != "defaults"}
    for entry in data.get("defaults") or []:
        if entry == "_self_":
            continue
        if not isinstance(entry, str) or entry.startswith(("/", "override ", "optional ")) or "@" in entry:
            return None
        base = _option_keys(group_dir, entry, (*seen, option))
        if base is None:
            return None
        keys = {**base, **keys}
    return keys


def _defaults_entries(config: Path) -> list:
    """A config file's defaults list ([] for a file that is not there, not YAML or without one)."""
    import yaml

    try:
        return (yaml.safe_load(config.read_text()) or {}).get("defaults") or []
    except (OSError, yaml.YAMLError, AttributeError):
        return []


def _default_choice(primary: Path, group: str) -> str | None:
    """The option the primary config's defaults list chooses for `group` (None when it chooses none there)."""
    return next((str(e[group]) for e in _defaults_entries(primary) if isinstance(e, dict) and group in e), None)


def owner_form(conf_dir: Path, owner: str, key: str) -> str:
    """`key=` as the option `owner` (protocol=heldout) takes it: plain where its yaml lists the key, with a leading
    '+' where it leaves it to the settings' default (SETTINGS_SECTIONS)."""
    group, _, option = owner.partition("=")
    node: Any = _option_keys(conf_dir / group, option)
    if node is None:
        return f"{key}="
    for part in key.split(".")[1:]:
        if not isinstance(node, dict) or part not in node:
            return f"+{key}="
        node = node[part]
    return f"{key}="


def _unparseable(override: str) -> bool:
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import OverrideParseException

    try:
        OverridesParser.create().parse_overrides([override])
    except OverrideParseException:
        return True
    return False


def defaults_groups(config: Path) -> list[str]:
    """The config groups a primary config's defaults list chooses from (hydra/* and optional overlays left out)."""
    names = [next(iter(e)) for e in _defaults_entries(config) if isinstance(e, dict) and e]
    return [n for n in names if not n.startswith(("hydra", "optional ", "override "))]


def composition_error_line(exc: BaseException, config_name: str | None = None,
                           conf_dir: Path | None = None) -> str:
    """One line for a config Hydra could not compose: the override of a key the config lacks (typo'd or not
    there) names the valid keys at that level and the closest one; any other failure is its first line and its
    cause's first line."""
    import difflib

    text = [ln for ln in str(exc).strip().splitlines() if ln.strip()]
    cause = exc.__cause__
    cause_text = [ln for ln in str(cause or "").strip().splitlines() if ln.strip()]
    parent = getattr(cause, "parent_node", None)
    key = getattr(cause, "key", None)
    # "not in struct": a key missing from a plain config; "not in '<Schema>'": from a typed one (config_schemas)
    not_there = bool(cause_text) and ("not in struct" in cause_text[0] or " not in '" in cause_text[0])
    if text and text[0].startswith("Could not override") and not_there and parent is not None and key is not None:
        full_key = getattr(cause, "full_key", None) or key
        valid = [str(k) for k in parent.keys() if k != "hydra"]
        prefix = str(full_key)[: -len(str(key))]  # "world_model." of "world_model.unimix"
        if str(full_key) in SETTINGS_SECTIONS:  # a section the chosen option (protocol=paper) does not have
            owner = SETTINGS_SECTIONS[str(full_key)][2]
            group, _, _ = owner.partition("=")
            override = text[0].removeprefix("Could not override ").strip(" .'")
            form = owner_form(conf_dir, owner, override) if conf_dir is not None else f"{override}="
            return (f"override {override}: {group}={parent.get('name')} has no {key} (a section of {owner}); drop "
                    f"it, or run it with {owner}: {owner} {form}...")
        append = next((ln.split(" use ", 1)[1] for ln in text[1:] if ln.startswith("To append")), f"+{full_key}=...")
        defaults = _settings_defaults(prefix.rstrip("."))
        unlisted = [f for f in defaults if f not in valid]
        if str(key) in unlisted:  # read by the section's settings dataclass at its default: the yaml leaves it out
            return (f"override {full_key}: a setting the config does not list (default {defaults[str(key)]!r}); "
                    f"to set it, write {append}")
        also = f"; with a leading +: {', '.join(unlisted)}" if unlisted else ""
        close = difflib.get_close_matches(str(key), valid + unlisted, n=2, cutoff=0.6)
        close = [f"+{prefix}{k}" if k in unlisted else k for k in close]
        close = close or [f"{prefix}{k}.{key}" for k in _holding(parent, str(key))]  # a level left out
        mean = f"did you mean {' or '.join(close)}? " if close else ""
        if close or unlisted:  # a typo, or a section whose settings refuse other keys: '+key=...' would add a key
            # nothing reads and the run would go on without it, or stop later on it
            return f"override {full_key}: no such key ({mean}valid here: {', '.join(valid)}{also})"
        return (f"override {full_key}: no such key ({mean}valid here: {', '.join(valid)}); to add a new key, "
                f"write {append}")
    typed = _type_mistake(cause)
    if typed is not None:
        return typed
    if text and text[0].startswith("Error merging override ") and cause_text and \
            cause_text[0].startswith("Cannot merge DictConfig with"):  # a value given for a whole section
        override = text[0].removeprefix("Error merging override ")
        section = str(getattr(cause, "full_key", None) or override.split("=", 1)[0].lstrip("+~"))
        keys = [str(k) for k in parent.keys()] if hasattr(parent, "keys") else []
        return (f"override {override}: {section} is a section of settings, not one value; set its keys one by one "
                f"({section}.<key>=...; keys: {', '.join(keys) if keys else 'see conf/ or --cfg job'})")
    head = text[0] if text else type(exc).__name__
    if head.startswith("Could not append to config"):  # '+key=' of a key the config has: Hydra's advice, one line
        plain = next((ln.split(": ", 1)[1] for ln in text[1:] if ln.startswith("Either remove + prefix")), None)
        return f"{head.removesuffix('.')}; to set it, drop the +: {plain.strip(chr(39))}" if plain else head
    if head.startswith("Ambiguous value for argument"):  # Hydra's numbered advice is on the lines this drops
        head += "; to sweep over the values add -m (a run per value), for a list write key=[a,b]"
    if (head.startswith("Could not override") and "No match in the defaults list" in head and config_name
            and conf_dir is not None):
        groups = defaults_groups(conf_dir / f"{config_name}.yaml")
        if groups:
            head += f" (this command's config groups: {', '.join(groups)})"
    options = getattr(exc, "options", None)  # MissingConfigException: the group's options (plugins' included)
    if options:
        head = f"{head}; valid: {', '.join(sorted(str(o) for o in options))}"
    return f"{head} {cause_text[0]}" if cause_text else head


# Config sections read by a settings dataclass (errors.settings_from_dict) whose yaml lists only the settings a run
# records: the others (the gate's bootstrap size and seed, the state model's width, rate, ...) stay at their defaults
# and are set with a leading '+'. Listing them in the yaml would change every committed run's recorded protocol.
SETTINGS_SECTIONS = {  # section -> (module, settings dataclass, the config choice that has the section)
    "protocol.gate": ("simeval.measures.dynamics_diversity.gate", "GateConfig", "protocol=heldout"),
    "protocol.state_model": ("simeval.measures.dynamics_diversity.state_reading", "StateModelConfig",
                             "protocol=heldout"),
}


def _settings_defaults(section: str) -> dict[str, Any]:
    """Field -> default of the settings dataclass that reads config `section` ({} for a section without one)."""
    import dataclasses
    import importlib

    if section not in SETTINGS_SECTIONS:
        return {}
    module, name, _ = SETTINGS_SECTIONS[section]
    fields = dataclasses.fields(getattr(importlib.import_module(module), name))
    return {f.name: f.default if f.default is not dataclasses.MISSING else f.default_factory() for f in fields}


def _holding(parent: Any, key: str) -> list[str]:
    """The keys of `parent` whose own mapping has `key`: where a key given one level too high lives."""
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    out = []
    for k in parent.keys():
        try:
            child = parent[k]
        except OmegaConfBaseException:  # an interpolation that cannot resolve here: not where the key lives
            continue
        if OmegaConf.is_dict(child) and key in child:
            out.append(str(k))
    return out


_EXPECTED = (("to Integer", TYPE_WORDS[int]), ("valid bool", TYPE_WORDS[bool]), ("to Float", TYPE_WORDS[float]),
             ("to string", TYPE_WORDS[str]), ("is not a ListConfig", "a list in brackets, e.g. [a,b]"))


def _type_mistake(cause: BaseException | None) -> str | None:
    """`key='value': expected ...` for a value of the wrong type for its schema (simeval.config_schemas), as the
    checks after composition word it; None for any other failure."""
    from omegaconf.errors import ValidationError

    if not isinstance(cause, ValidationError) or not getattr(cause, "full_key", None):
        return None
    message = str(getattr(cause, "msg", cause))
    if "is not Optional" in message:  # null for a typed key: word its type as a wrong value's line would
        hints = typing.get_type_hints(cause.object_type) if is_dataclass(cause.object_type) else {}
        kind = hints.get(str(cause.key))
        message = {int: "to Integer", bool: "valid bool", float: "to Float"}.get(kind, message)
    expected = next((words for marker, words in _EXPECTED if marker in message), None)
    if expected is None:
        return None
    value = getattr(cause, "value", None)
    return f"{cause.full_key}={'null' if value is None else repr(value)}: expected {expected}"


def _one_line_composition_errors() -> None:
    """Hydra prints a config it could not compose (an override of a key the config lacks, a value of the wrong
    type) as a block and exits 1, in its `run_and_report`, which `hydra.main` looks up at call time. Wrapped here,
    a composition error becomes one `error:` line and exit 2 like every other user error; anything else reaches
    Hydra's own printer unchanged. HYDRA_FULL_ERROR=1 keeps Hydra's traceback. Why a patch and not a hook: Hydra 1.3
    composes the config before any Callback or plugin runs (on_run_start already receives the composed config), so
    no documented hook sees a composition error."""
    import hydra._internal.utils as hydra_utils
    from hydra.errors import ConfigCompositionException

    original = hydra_utils.run_and_report
    if getattr(original, "simeval_one_line", False):
        return

    def run_and_report(func: Callable[[], Any]) -> Any:
        def guarded() -> Any:
            try:
                return func()
            except ConfigCompositionException as e:
                if os.environ.get("HYDRA_FULL_ERROR") == "1":
                    raise
                # SystemExit: not an Exception, so Hydra's printer lets it pass
                _fail(composition_error_line(e, Path(sys.argv[0]).stem, entry_conf_dir()))
            except OSError as e:  # Hydra makes the run or sweep folder before any simeval code runs
                if os.environ.get("HYDRA_FULL_ERROR") == "1" or not _hydra_making_a_folder(e):
                    raise  # a run's own: its traceback, not words about folders it is not about
                if isinstance(e, (FileExistsError, NotADirectoryError)):  # e.g. hydra.run.dir naming a file
                    _fail(f"{e.filename}: {e.strerror}; a folder is needed there (paths.root, hydra.run.dir or "
                          "hydra.sweep.dir names a file?)")
                _fail(f"{e.filename}: {e.strerror}; the run's folder cannot be made there: set paths.root "
                      "(or hydra.run.dir / hydra.sweep.dir) to a folder you can write")

        return original(guarded)

    run_and_report.simeval_one_line = True
    hydra_utils.run_and_report = run_and_report


def _hydra_making_a_folder(e: BaseException) -> bool:
    """Whether `e` came from a mkdir that Hydra called (its run or sweep folder, made before any simeval code runs),
    not from a run's own work: the frames after the last of Hydra's are pathlib's."""
    import traceback

    frames = traceback.extract_tb(e.__traceback__)
    last = next((i for i in range(len(frames) - 1, -1, -1) if not frames[i].filename.endswith("pathlib.py")), None)
    return (last is not None and last < len(frames) - 1 and f"{os.sep}hydra{os.sep}" in frames[last].filename
            and frames[-1].name == "mkdir")


def launch(main: Callable[[], Any]) -> None:
    """Run an entrypoint's `main` after the argv fixes and checks every entrypoint shares."""
    from simeval.results import register_run_suffix_resolver

    refuse_secrets_on_command_line(sys.argv)
    modes = [a for a in sys.argv[1:] if a.split("=", 1)[0] in HYDRA_MODE_FLAGS]
    if len({HYDRA_MODE_FLAGS[m.split("=", 1)[0]] for m in modes}) > 1:  # Hydra raises a ValueError's traceback
        _fail(f"{' and '.join(modes)}: one at a time (to see a sweep's config, give --cfg job with one value of "
              f"each swept key, without -m)")
    allow_multirun_anywhere()
    custom_search_path = any(a.startswith(("--config-dir", "-cd", "--config-path", "-cp")) for a in sys.argv[1:])
    if not custom_search_path and os.environ.get("HYDRA_FULL_ERROR") != "1":
        mistake = config_mistakes(sys.argv[1:], entry_conf_dir(), Path(sys.argv[0]).stem)
        if mistake:
            _fail(mistake)
    register_run_suffix_resolver()  # ${run_suffix:} in conf/hydra/default.yaml: unique run folders
    _one_line_composition_errors()
    try:
        main()
    except BrokenPipeError:  # stdout closed early (`--help | head`): end quietly, as a Unix filter does
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # the interpreter's final flush would raise once more
        sys.exit(1)


class OneLineParser(argparse.ArgumentParser):
    """argparse for the argparse commands (the subcommands of src/controls.py and src/generalization_tools.py, the
    experiment scripts), with a user error as one line (exit 2) instead of the usage block: `--help` still prints
    the usage."""

    def error(self, message: str) -> None:  # type: ignore[override]
        _fail(f"{self.prog}: {message} (see --help)")


def run_subcommand(argv: list[str] | None, doc: str, names: tuple[str, ...], what: str, command: str,
                   run: Callable[[str, list[str]], None]) -> None:
    """An entrypoint of named subcommands (src/controls.py, src/generalization_tools.py): `--help` prints `doc`; no
    name, or one not in `names`, is one line on stderr naming them (`what`: "control", "tool"; `command`: how the
    entrypoint is typed), exit 2; else run(name, the arguments after it), a UserError it raises one line, exit 2."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] in ("-h", "--help"):
        print(doc)
        return
    if not argv:
        _fail(f"name a {what}: {', '.join(names)} ({command} --help)")
    if argv[0] not in names:
        _fail(f"{what} {argv[0]!r}: expected one of {', '.join(names)}")
    try:
        run(argv[0], argv[1:])
    except UserError as e:
        _fail(str(e))
