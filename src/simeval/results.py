"""`result.json` beside `.hydra/`: the one record every run leaves, from which tables and figures are rebuilt.

Every record carries an `identity`: what the numbers are *of* (metric, version, pipeline, task source, task group,
model, settings) and which repeat they are (seed). A report uses it to put each record in its table cell, to
average repeated seeds, and to refuse to merge two records that claim one cell with different settings (see
simeval.measures.text_diversity.table3). Run folders are unique per process (`${run_suffix:}` in
conf/hydra/default.yaml), so two runs started in the same second never share a folder or overwrite each other's
result.json.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import glob
import json
import math
import os
import subprocess
import tempfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from simeval.errors import UserError
from simeval.secrets import redact_secrets

RESULT_FILE = "result.json"
RESULT_SCHEMA = 1
REPEAT_KEYS = ("seed",)  # identity keys that name a repeat of the same measurement, not a different one


SUFFIXES_MADE: set[str] = set()  # by this process: a folder named with one was made by it, not by the user


def run_suffix() -> str:
    """`<pid>-<6 random hex>`: with the microsecond timestamp in conf/hydra/default.yaml it makes a run folder
    unique even for runs started at once on several machines that share a filesystem."""
    suffix = f"{os.getpid()}-{os.urandom(3).hex()}"
    SUFFIXES_MADE.add(suffix)
    return suffix


def register_run_suffix_resolver() -> None:
    """Register `${run_suffix:}` for the run/sweep folder names. Cached like Hydra's `${now:}`: the run folder is
    resolved more than once per run and the sweep config copies the cache to every job, so all agree."""
    from omegaconf import OmegaConf

    if not OmegaConf.has_resolver("run_suffix"):
        OmegaConf.register_new_resolver("run_suffix", run_suffix, use_cache=True)


def make_identity(metric: str, version: str, seed: int | None = None, **fields: Any) -> dict:
    """The `identity` stored in result.json: metric, version and seed plus what the entrypoint names (pipeline,
    source, task_group, model, settings, ...). Values are made JSON-plain so two identities compare with ==."""
    return strict_json_value({"metric": metric, "version": version, **fields, "seed": seed})


def record_identity(rec: Mapping) -> dict:
    """A record's identity; for records written before identities existed, the fields that were there."""
    if isinstance(rec.get("identity"), Mapping):
        return dict(rec["identity"])
    legacy = {k: rec.get(k) for k in ("pipeline", "embedding", "label", "judge") if k in rec}
    return make_identity(rec.get("metric"), rec.get("version"), rec.get("seed"), **legacy)


def _flat(d: Mapping, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, Mapping):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def identity_difference(a: Mapping, b: Mapping) -> str:
    """`model ('x' vs 'y'), settings.n_boot (1000 vs 20)`: the keys where two identities differ."""
    fa, fb = _flat(a), _flat(b)
    keys = [k for k in sorted(set(fa) | set(fb)) if fa.get(k) != fb.get(k)]
    return ", ".join(f"{k} ({fa.get(k)!r} vs {fb.get(k)!r})" for k in keys)


def umask_file_mode() -> int:
    """The mode a plainly created file gets (0o666 less the umask). mkstemp makes 0o600 files; a shared store or
    outputs folder needs the mode other writers' files have."""
    return 0o666 & ~_process_umask()


def _process_umask() -> int:
    """The umask, read without changing it where Linux reports it: setting it to read it back (the only portable
    way) briefly gives any file another thread creates meanwhile the wrong mode."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass  # not Linux: fall back to set-and-restore
    mask = os.umask(0)
    os.umask(mask)
    return mask


def writer_tag() -> str:
    """`<pid>@<host>` in a temp file's name: whose it is, so a later writer can remove a killed writer's leftover
    and leave a live one's alone (a folder shared by several hosts: only this host's pids can be asked)."""
    import socket

    return f"{os.getpid()}@{socket.gethostname().split('.')[0]}"


def remove_leftovers_of_dead_writers(folder: str | os.PathLike, prefix: str, suffix: str = ".tmp") -> int:
    """Removes `<prefix><pid>@<host>.*<suffix>` files in `folder` that this host's dead processes left (a run
    killed -9 mid-write: the rename never came); returns how many. A live pid's file may be another run writing the
    same file right now, and another host's cannot be checked, so both stay; an untagged (older) one says nothing."""
    host = writer_tag().partition("@")[2]
    removed = 0
    for leftover in Path(folder).glob(f"{glob.escape(prefix)}*{suffix}"):
        pid, _, its_host = leftover.name.removeprefix(prefix).partition(".")[0].partition("@")
        if its_host != host or not pid.isdigit():
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            leftover.unlink(missing_ok=True)
            removed += 1
        except PermissionError:  # alive, another user's
            continue
    return removed


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, prefix: str | None = None) -> Iterator[Path]:
    """A temp file in `path`'s folder, with the mode a plainly created file gets (mkstemp makes 0600 files; a shared
    store or checkpoint folder needs the mode others' files get). Write it inside the block: it is renamed to `path`
    when the block ends, and removed when the block raises (a kill never leaves half a file at `path`). Its name
    carries its writer (`<prefix><pid>@<host>.<random>.tmp`), and the temp files of the same prefix that this host's
    killed writers left (kill -9: neither rename nor removal came) are removed first."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    prefix = prefix or f".{path.name}."
    remove_leftovers_of_dead_writers(path.parent, prefix)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f"{prefix}{writer_tag()}.", suffix=".tmp")
    try:
        os.fchmod(fd, umask_file_mode())
        os.close(fd)
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write via a temp file in the same folder and rename, so a reader never sees half a file."""
    with atomic_path(path) as tmp, tmp.open("w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    return Path(path)


def strict_json_value(obj: Any) -> Any:
    """obj with NaN/Infinity replaced by None and numpy scalars/arrays by Python values, so `json.dumps(...,
    allow_nan=False)` succeeds: result.json is read by tools (jq, JavaScript, W&B) that reject bare NaN."""
    if isinstance(obj, Mapping):
        return {str(k): strict_json_value(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set)):
        return [strict_json_value(v) for v in obj]
    if hasattr(obj, "tolist") and callable(obj.tolist):  # numpy scalars and arrays
        return strict_json_value(obj.tolist())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return obj
    return str(obj)


def dumps_strict(obj: Any, **kwargs: Any) -> str:
    """json.dumps that never writes NaN/Infinity (see strict_json_value)."""
    return json.dumps(strict_json_value(obj), allow_nan=False, **kwargs)


def git_sha(start: str | os.PathLike | None = None) -> str | None:
    """The commit of the checkout holding this package (with `-dirty` if it has local changes), or None."""
    where = Path(start) if start else Path(__file__).resolve().parent
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=where, capture_output=True, text=True, timeout=5, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"], cwd=where, capture_output=True, text=True,
            timeout=5, check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return f"{sha}-dirty" if dirty else sha


def hydra_run_info() -> dict:
    """Output dir, config choices and overrides of the current Hydra job ({} outside Hydra)."""
    try:
        from hydra.core.hydra_config import HydraConfig

        hc = HydraConfig.get()
    except (ImportError, ValueError):
        return {}
    from omegaconf import OmegaConf

    return {
        "output_dir": hc.runtime.output_dir,
        "choices": {k: v for k, v in OmegaConf.to_container(hc.runtime.choices).items() if not k.startswith("hydra/")},
        "overrides": list(hc.overrides.task),
    }


@dataclass
class RunFolder:
    """The skeleton every entrypoint shares: the current Hydra run's folder, config choices and overrides, and the
    resolved config; `logger()` opens the configured logger there (`cfg.logger`, simeval.loggers), `write(...)`
    writes its result.json with the config and choices filled in (write_result)."""

    output_dir: str
    choices: dict
    overrides: list
    config: dict
    logger_cfg: Any = None

    @classmethod
    def of(cls, cfg) -> RunFolder:
        from omegaconf import OmegaConf

        info = hydra_run_info()
        if not info:
            raise RuntimeError("RunFolder.of: not inside a Hydra run (call the library functions directly instead)")
        return cls(info["output_dir"], info["choices"], info["overrides"], OmegaConf.to_container(cfg, resolve=True),
                   cfg.get("logger"))

    def logger(self):
        from hydra.utils import instantiate

        return instantiate(self.logger_cfg, _partial_=True)(run_dir=self.output_dir, run_config=self.config)

    def write(self, *, metric: str, version: str, values: Any, **fields: Any) -> Path:
        return write_result(self.output_dir, metric=metric, version=version, values=values, config=self.config,
                            choices=self.choices, **fields)


def write_result(
    out_dir: str | os.PathLike,
    *,
    metric: str,
    version: str,
    values: Any,
    config: Mapping | None = None,
    choices: Mapping | None = None,
    seed: int | None = None,
    status: str = "ok",
    identity: Mapping | None = None,
    **extra: Any,
) -> Path:
    """Write `<out_dir>/result.json` atomically and return its path. `identity` (see make_identity) names what
    the values are of; metric, version and seed are filled in from the arguments."""
    record = {
        "schema": RESULT_SCHEMA,
        "metric": metric,
        "version": version,
        "status": status,
        "values": values,
        "choices": dict(choices or {}),
        "seed": seed,
        "identity": make_identity(metric, version, seed, **{k: v for k, v in (identity or {}).items()
                                                          if k not in ("metric", "version", "seed")}),
        "git_sha": git_sha(),
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        **extra,
        "config": redact_secrets(dict(config or {})),
    }
    return atomic_write_text(Path(out_dir) / RESULT_FILE, dumps_strict(record, indent=2) + "\n")


def read_results(root: str | os.PathLike, metric: str | None = None) -> list[dict]:
    """Every result.json under root (optionally of one metric), each with its `path`. Unreadable files are an
    error naming the file: a table silently missing a run is worse than no table."""
    records = []
    for path in sorted(Path(root).rglob(RESULT_FILE)):
        try:
            rec = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise UserError(f"cannot read {path}: {e}") from e
        if metric is None or rec.get("metric") == metric:
            rec["path"] = str(path)
            records.append(rec)
    return records


def rolled_out(episodes: list[Mapping]) -> list[Mapping]:
    """A generalization row's episodes that were rolled out: all but those left out as unvaried (the eval variation
    left their scene as the train split's: simeval.measures.generalization.rollouts.rollout_task)."""
    return [e for e in episodes if not e.get("unvaried")]
