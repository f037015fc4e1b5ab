"""Benchmark: the paper chain at the `quick` profile for one pipeline, run here and as dependent SLURM jobs on the
local one-node cluster (python -m simeval.devcluster), wall time side by side in one run, and whether both end with the
same Tables 4 and 5.

    python experiments/benchmarks/slurm_chain_bench.py [--pipeline robogen] [--stages collect,table4,table5,report]
Needs root (the cluster's daemons) and Debian's slurm-wlm, slurmdbd, munge and MariaDB (installed when missing);
says so in one line otherwise. Writes outputs/bench/slurm_chain.json.

What the cluster adds on one node is its overhead (submission, dependencies, polling, each job's interpreter start);
what it buys is parallel stages across nodes, estimated in the README from per-stage costs.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import ROOT, machine, save

from simeval.cli import OneLineParser


def main() -> None:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pipeline", default="robogen")
    ap.add_argument("--stages", default="collect,table4,table5,report")
    a = ap.parse_args()
    common = [sys.executable, str(ROOT / "src" / "paper.py"), "profile=quick", f"pipelines=[{a.pipeline}]",
              f"stages=[{a.stages}]"]
    result = {"benchmark": "slurm_chain", "machine": machine(), "load_average_at_start": os.getloadavg(),
              "profile": "quick", "pipeline": a.pipeline, "stages": a.stages.split(",")}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cluster = [sys.executable, "-m", "simeval.devcluster", "--dir", str(tmp / "cluster")]
        started = subprocess.run([*cluster, "up"], capture_output=True, text=True, check=False)
        if started.returncode != 0:
            said = started.stderr.strip().splitlines()
            ap.error(said[-1] if said else "python -m simeval.devcluster up failed")
        conf = [ln for ln in started.stdout.splitlines() if ln.startswith("export SLURM_CONF=")][-1]
        env = {**os.environ, "SLURM_CONF": conf.split("=", 1)[1]}
        try:
            runs = {}
            for where, extra, run_env in (
                    ("local", [], {k: v for k, v in env.items() if k != "SLURM_CONF"}),
                    ("slurm", ["launcher=slurm", "sbatch_args='--partition=debug --mem=2G --cpus-per-task=1'"],
                     env)):
                t0 = time.perf_counter()
                r = subprocess.run([*common, f"out={tmp / where}", *extra], cwd=ROOT, env=run_env,
                                   capture_output=True, text=True, timeout=3600, check=False)
                if r.returncode != 0:
                    ap.error(f"the {where} chain failed: {r.stderr.strip().splitlines()[-1] if r.stderr else r.returncode}")
                runs[where] = {"seconds": round(time.perf_counter() - t0, 1),
                               "jobs": len(re.findall(r"^  job \d+", r.stdout, re.MULTILINE)) if where == "slurm" else None}
                print(where, runs[where], flush=True)
        finally:
            subprocess.run([*cluster, "down"], capture_output=True, check=False)
        same = {t: (tmp / "slurm" / "tables" / t).read_text() == (tmp / "local" / "tables" / t).read_text()
                for t in ("table4.csv", "table5.csv")}
    result.update(runs=runs, slurm_over_local=round(runs["slurm"]["seconds"] / runs["local"]["seconds"], 2),
                  same_tables=same)
    save("slurm_chain", result)


if __name__ == "__main__":
    main()
