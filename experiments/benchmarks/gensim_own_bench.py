"""Benchmark: collection speed per episode of GenSim's own code (pipeline=gensim_own) against GenSim's demos.py loop
and simeval's GenSim-style suite, on the same tasks and seeds, in one run.

- gensim_own: simeval's worker process per episode (start, GenSim's imports, the episode at 240 Hz with a 64x64
  front + top frame every 8th physics step), as src/collect.py pipeline=gensim_own runs it;
- demos_loop: the same worker with no per-step frames at demos.py's 480 Hz: GenSim's own loop as cliport/demos.py
  runs it (its three 480x640 observations per primitive are rendered either way: they are GenSim's), so the ratio
  says what simeval's frames cost on top of GenSim itself;
- suite: simeval's GenSim-style suite, the task of the same name, 64x64 front + top at 30 Hz, in this process;
- import: a worker process that only imports GenSim (what every episode pays once).
One process at a time (no parallel workers), so the ratios are per core. Writes outputs/bench/gensim_own.json.

    python experiments/benchmarks/gensim_own_bench.py --root ../shared/gensim [--seeds 3]
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import machine, save

from simeval.cli import OneLineParser
from simeval.pipelines.gensim_own.native import GensimSettings, check_checkout, run_worker
from simeval.sim.rollout import RecordSettings, run_episode
from simeval.sim.tasks.spec import suite_dir, load_spec

TASKS = ("place-red-in-green", "stack-block-pyramid")  # in GenSim's registry and in simeval's suite


def import_seconds(root: Path) -> float:
    code = ("import time; t = time.perf_counter(); from simeval.pipelines.gensim_own.worker import load_gensim; "
            f"load_gensim({str(root)!r}); print(time.perf_counter() - t)")
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    return time.perf_counter() - t0


def main() -> None:
    ap = OneLineParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", required=True)
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    root = check_checkout(args.root)
    own = GensimSettings(root=str(root))
    demos = GensimSettings(root=str(root), hz=480, frame_every=10**9)
    out = {"machine": machine(), "seeds": args.seeds, "tasks": {}, "import_s": import_seconds(root)}
    with tempfile.TemporaryDirectory() as scratch:
        for task in TASKS:
            rows = {"gensim_own": [], "demos_loop": [], "suite": []}
            for seed in range(args.seeds):
                for name, settings in (("gensim_own", own), ("demos_loop", demos)):
                    t0 = time.perf_counter()
                    arrays, meta = run_worker(task, seed, settings, (64, 64), ["top", "front"], Path(scratch))
                    rows[name].append({"seconds": time.perf_counter() - t0, "frames": len(arrays["state"]),
                                       "success": bool(meta["success"]), "physics_steps": meta["physics_steps"]})
                t0 = time.perf_counter()
                ep = run_episode(load_spec(suite_dir("gensim") / f"{task}.yaml"), seed,
                                 RecordSettings(cameras=("top", "front"), image_size=(64, 64)))
                rows["suite"].append({"seconds": time.perf_counter() - t0, "frames": ep.n_steps,
                                      "success": ep.success})
            summary = {k: {"s_per_episode": sum(r["seconds"] for r in v) / len(v),
                           "frames_per_episode": sum(r["frames"] for r in v) / len(v),
                           "successes": sum(r["success"] for r in v), "episodes": v} for k, v in rows.items()}
            own_s = summary["gensim_own"]["s_per_episode"]
            summary["ratio_own_to_demos_loop"] = own_s / summary["demos_loop"]["s_per_episode"]
            summary["ratio_own_to_suite"] = own_s / summary["suite"]["s_per_episode"]
            out["tasks"][task] = summary
    save("gensim_own", out)


if __name__ == "__main__":
    main()
