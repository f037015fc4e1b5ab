"""A real one-node SLURM cluster on this machine, from Debian's packages (slurm-wlm 22.05, slurmdbd, munge, and
MariaDB for accounting, which submitit's status polls read through `sacct`): for the tests of the `slurm` launcher
and for trying the cluster path before a real cluster.

    python -m simeval.devcluster up [--dir /tmp/simeval-slurm]     # prints `export SLURM_CONF=...`
    python -m simeval.devcluster down [--dir /tmp/simeval-slurm]
    export SLURM_CONF=/tmp/simeval-slurm/slurm.conf
    python src/text_diversity.py -m hydra/launcher=slurm hydra.launcher.partition=debug \\
        hydra.launcher.gpus_per_node=0 hydra.launcher.mem_gb=1 hydra.launcher.cpus_per_task=1 ...

Needs root (the daemons run as root, munged on its default socket) and the packages; `up` installs them with
apt-get when they are missing and it may (root, apt-get present, SIMEVAL_SLURM_INSTALL not 0). Everything else
lives under --dir: the munge key, the MariaDB data, slurm.conf / slurmdbd.conf, state, spool and logs; the daemons
listen on free local ports. The partition `debug` holds the one node with this machine's CPUs and memory;
EnforcePartLimits=ALL makes sbatch refuse a job that asks for more than the node has (instead of leaving it
pending forever), as a well-run cluster does. `down` stops what `up` started and removes --dir.

Why by hand and not a container (slurm-docker-cluster): no container runtime here; and the daemons are the same
Debian binaries a cluster runs.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from simeval.cli import OneLineParser

PACKAGES = ("slurm-wlm", "slurmdbd", "munge", "mariadb-server")
BINARIES = ("munged", "munge", "unmunge", "slurmctld", "slurmd", "slurmdbd", "sbatch", "sinfo", "sacct", "sacctmgr",
            "scontrol", "mariadbd", "mariadb-install-db", "mariadb")
MUNGE_SOCKET = Path("/run/munge/munge.socket.2")  # sacct/sacctmgr reach slurmdbd through the default socket only
PARTITION = "debug"
DB_PASSWORD = "simeval-local"  # a throwaway database on 127.0.0.1 of a test machine


class Unavailable(RuntimeError):
    """The cluster cannot be brought up here (not root, no packages and no way to install them)."""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run(*cmd: str, env: dict | None = None, timeout: float = 60, check: bool = True) -> subprocess.CompletedProcess:
    res = subprocess.run(list(cmd), env=env, capture_output=True, text=True, timeout=timeout)
    if check and res.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {res.returncode}: {(res.stderr or res.stdout).strip()[-500:]}")
    return res


def missing_binaries() -> list[str]:
    return [b for b in BINARIES if shutil.which(b) is None]


def ensure_packages() -> None:
    """Install the packages when a binary is missing; Unavailable with the reason when that cannot be done."""
    if not missing_binaries():
        return
    if os.geteuid() != 0:
        raise Unavailable(f"needs root to install {' '.join(PACKAGES)} (missing: {', '.join(missing_binaries())})")
    if os.environ.get("SIMEVAL_SLURM_INSTALL") == "0" or shutil.which("apt-get") is None:
        raise Unavailable(f"missing {', '.join(missing_binaries())} and not installing them (apt-get "
                          f"{'absent' if shutil.which('apt-get') is None else 'disabled by SIMEVAL_SLURM_INSTALL=0'})")
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    res = subprocess.run(["apt-get", "install", "-y", "--no-install-recommends", *PACKAGES], env=env,
                         capture_output=True, text=True, timeout=900)
    if res.returncode != 0 or missing_binaries():
        raise Unavailable(f"apt-get install {' '.join(PACKAGES)} failed: {(res.stderr or res.stdout).strip()[-300:]}")


def _munge_answers() -> bool:
    if not MUNGE_SOCKET.exists():
        return False
    cred = subprocess.run(["munge", "-n"], capture_output=True, timeout=10)
    return cred.returncode == 0 and subprocess.run(["unmunge"], input=cred.stdout, capture_output=True,
                                                   timeout=10).returncode == 0


def _pid(path: Path) -> int | None:
    try:
        return int(path.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None


def _wait(what: str, ok, timeout: float = 60) -> None:
    deadline = time.time() + timeout
    while time.time() < deadline:
        if ok():
            return
        time.sleep(0.3)
    raise RuntimeError(f"local SLURM: {what} did not come up within {timeout:.0f} s")


def _node() -> tuple[str, int, int]:
    """(hostname, CPUs, memory in MB that jobs may ask for: the node's less 512 MB for the daemons)."""
    total_kb = next(int(line.split()[1]) for line in Path("/proc/meminfo").read_text().splitlines()
                    if line.startswith("MemTotal:"))
    return socket.gethostname().split(".")[0], os.cpu_count() or 1, max(512, total_kb // 1024 - 512)


def up(state: str | os.PathLike) -> dict[str, str]:
    """Bring the cluster up under `state`; returns the environment its clients need ({"SLURM_CONF": ...})."""
    ensure_packages()
    if os.geteuid() != 0:
        raise Unavailable("the local cluster's daemons run as root")
    d = Path(state).resolve()
    if (d / "slurm.conf").exists():
        down(d)
    for sub in ("log", "state", "spool", "db"):
        (d / sub).mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "SLURM_CONF": str(d / "slurm.conf")}
    _start_munge(d)
    db_port, dbd_port, ctld_port, slurmd_port = (_free_port() for _ in range(4))
    _start_mariadb(d, db_port)
    _write_configs(d, db_port=db_port, dbd_port=dbd_port, ctld_port=ctld_port, slurmd_port=slurmd_port)
    _run("slurmdbd", env=env)
    _wait("slurmdbd", lambda: _run("sacctmgr", "-n", "list", "cluster", env=env, check=False).returncode == 0)
    _run("sacctmgr", "-i", "add", "cluster", "simeval", env=env)
    _run("slurmctld", env=env)
    _run("slurmd", env=env)
    _wait("the node", lambda: "idle" in _run("sinfo", "-h", "-o", "%T", env=env, check=False).stdout)
    return {"SLURM_CONF": env["SLURM_CONF"]}


def _start_munge(d: Path) -> None:
    if _munge_answers():  # a munged already answers (the machine's, or one started earlier): the daemons use it
        return
    key = d / "munge.key"
    key.write_bytes(os.urandom(1024))
    key.chmod(0o600)
    MUNGE_SOCKET.parent.mkdir(parents=True, exist_ok=True)
    _run("munged", f"--key-file={key}", f"--pid-file={d / 'munged.pid'}", f"--log-file={d / 'log' / 'munged.log'}",
         f"--seed-file={d / 'munged.seed'}", "--force")
    _wait("munged", _munge_answers, 20)


def _start_mariadb(d: Path, port: int) -> None:
    """slurmdbd's database, with its user: MariaDB on `port` with its data under `d`/db."""
    _run("mariadb-install-db", "--no-defaults", f"--datadir={d / 'db'}", "--user=root", "--skip-test-db",
         "--auth-root-authentication-method=normal", timeout=120)
    mariadbd = ["mariadbd", "--no-defaults", f"--datadir={d / 'db'}", f"--socket={d / 'mysql.sock'}",
                f"--port={port}", "--bind-address=127.0.0.1", "--user=root", f"--pid-file={d / 'mariadb.pid'}",
                f"--log-error={d / 'log' / 'mariadb.log'}", "--innodb-buffer-pool-size=32M"]
    # started by a shell that exits at once: the daemon is init's child, not a zombie of the caller when it stops
    _run("sh", "-c", " ".join(f"'{a}'" for a in mariadbd) + " >/dev/null 2>&1 &")
    sql = (f"CREATE USER 'slurm'@'127.0.0.1' IDENTIFIED BY '{DB_PASSWORD}'; "
           "GRANT ALL ON slurm_acct_db.* TO 'slurm'@'127.0.0.1';")
    _wait("MariaDB", lambda: _run("mariadb", "--no-defaults", "-S", str(d / "mysql.sock"), "-u", "root", "-e",
                                  "SELECT 1", check=False).returncode == 0)
    _run("mariadb", "--no-defaults", "-S", str(d / "mysql.sock"), "-u", "root", "-e", sql)


def _write_configs(d: Path, *, db_port: int, dbd_port: int, ctld_port: int, slurmd_port: int) -> None:
    """slurmdbd.conf and slurm.conf under `d`: one node (this machine, all its cores and memory), one partition."""
    host, cpus, mem_mb = _node()
    dbd = d / "slurmdbd.conf"
    dbd.write_text("\n".join([
        "AuthType=auth/munge", "DbdHost=localhost", "DbdAddr=127.0.0.1", f"DbdPort={dbd_port}", "SlurmUser=root",
        f"PidFile={d / 'slurmdbd.pid'}", f"LogFile={d / 'log' / 'slurmdbd.log'}",
        "StorageType=accounting_storage/mysql", "StorageHost=127.0.0.1", f"StoragePort={db_port}",
        "StorageUser=slurm", f"StoragePass={DB_PASSWORD}", "StorageLoc=slurm_acct_db", ""]))
    dbd.chmod(0o600)
    (d / "slurm.conf").write_text("\n".join([
        "ClusterName=simeval", f"SlurmctldHost={host}(127.0.0.1)", "SlurmUser=root", "SlurmdUser=root",
        "AuthType=auth/munge", "CredType=cred/munge", f"StateSaveLocation={d / 'state'}",
        f"SlurmdSpoolDir={d / 'spool'}", f"SlurmctldPidFile={d / 'slurmctld.pid'}",
        f"SlurmdPidFile={d / 'slurmd.pid'}", f"SlurmctldLogFile={d / 'log' / 'slurmctld.log'}",
        f"SlurmdLogFile={d / 'log' / 'slurmd.log'}", f"SlurmctldPort={ctld_port}", f"SlurmdPort={slurmd_port}",
        "ProctrackType=proctrack/linuxproc", "TaskPlugin=task/none", "SwitchType=switch/none", "MpiDefault=none",
        "ReturnToService=2", "SchedulerType=sched/backfill", "SelectType=select/cons_tres",
        "SelectTypeParameters=CR_Core_Memory", "EnforcePartLimits=ALL", "JobAcctGatherType=jobacct_gather/none",
        "AccountingStorageType=accounting_storage/slurmdbd", "AccountingStorageHost=127.0.0.1",
        f"AccountingStoragePort={dbd_port}", "JobCompType=jobcomp/none", "KillWait=5", "MinJobAge=30",
        # the daemons share this machine's cores with the jobs and the test suite: a starved slurmd may take longer
        # than the defaults (10 s each) to launch a batch job or to answer, which would end the job without a result
        "BatchStartTimeout=60", "MessageTimeout=30",
        f"NodeName={host} NodeAddr=127.0.0.1 CPUs={cpus} RealMemory={mem_mb} State=UNKNOWN",
        f"PartitionName={PARTITION} Nodes={host} Default=YES MaxTime=INFINITE State=UP", ""]))


def down(state: str | os.PathLike) -> None:
    """Stop what `up` started under `state` (jobs cancelled first) and remove the folder."""
    d = Path(state).resolve()
    env = {**os.environ, "SLURM_CONF": str(d / "slurm.conf")}
    if (d / "slurm.conf").exists():
        subprocess.run(["scancel", "--full", "-u", "root"], env=env, capture_output=True, timeout=30)
        subprocess.run(["scontrol", "shutdown"], env=env, capture_output=True, timeout=30)
    for name in ("slurmd.pid", "slurmctld.pid", "slurmdbd.pid", "mariadb.pid", "munged.pid"):
        pid = _pid(d / name)
        if pid is None:
            continue
        try:
            os.kill(pid, signal.SIGTERM)
        except ProcessLookupError:
            continue
        for _ in range(50):  # a daemon that holds its port would stop the next `up` from binding it
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                break
            time.sleep(0.1)
    _kill_steps_of(d / "slurm.conf")
    shutil.rmtree(d, ignore_errors=True)


def _kill_steps_of(conf: Path) -> None:
    """The job-step daemons (slurmstepd) this cluster's slurmd started: once slurmd is gone they wait for it
    forever; those of any other cluster (another SLURM_CONF) are left alone."""
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            if not (proc / "cmdline").read_bytes().startswith(b"slurmstepd"):
                continue
            environ = (proc / "environ").read_bytes().split(b"\0")
        except OSError:
            continue
        if f"SLURM_CONF={conf}".encode() in environ:
            try:
                os.kill(int(proc.name), signal.SIGKILL)
            except ProcessLookupError:
                pass


def main(argv: list[str] | None = None) -> int:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("action", choices=["up", "down"])
    ap.add_argument("--dir", default="/tmp/simeval-slurm", help="where the cluster's files live")
    a = ap.parse_args(argv)
    try:
        if a.action == "up":
            env = up(a.dir)
            print(f"export SLURM_CONF={env['SLURM_CONF']}")
        else:
            down(a.dir)
    except Unavailable as e:
        print(f"error: local SLURM cluster unavailable: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
