"""Benchmark: importing a LeRobotDataset (simeval.pipelines.lerobot_format) against lerobot 0.4.4's own loader
reading the same dataset, in one run. The dataset is written by lerobot's LeRobotDataset (tests/stand_ins/
lerobot_io.py; `make lerobot-env`): EPISODES episodes of FRAMES frames, one AV1 camera of SIZE x SIZE, an 8-d state
and a 7-d action. Timed, each the best of REPEATS:
  simeval read     import_lerobot's episodes, every frame decoded (PyAV, in order), nothing written
  simeval import   the same into a fresh store (HDF5, gzip): what `src/import_data.py format=lerobot` does
  lerobot read     LeRobotDataset(root)[i] for every frame (torchcodec decodes each), after loading the dataset
Writes outputs/bench/lerobot_import.json (frames per second and the ratios).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import ROOT, machine, save  # noqa: E402

STAND_INS = ROOT / "tests" / "stand_ins"


def lerobot(*args: str) -> str:
    env = {**os.environ, "PYTHONPATH": str(STAND_INS), "HF_HUB_OFFLINE": "1", "SVT_LOG": "1"}
    res = subprocess.run([sys.executable, str(STAND_INS / "lerobot_io.py"), *args], capture_output=True, text=True,
                         env=env)
    if res.returncode != 0:
        raise SystemExit(f"lerobot_io.py {args[0]} failed:\n{res.stderr[-2000:]}")
    return res.stdout


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--size", type=int, default=96)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    from simeval.episodes.store import EpisodeStore
    from simeval.pipelines.importers import import_into_store
    from simeval.pipelines.lerobot_format import import_lerobot

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        spec = {"episodes": args.episodes, "frames": args.frames, "height": args.size, "width": args.size,
                "fps": 10, "cameras": {"front": "video"}, "state": 8, "action": 7, "success": True,
                "tasks": ["pick the red cube", "push the blue block"], "seed": 0}
        (tmp / "spec.json").write_text(json.dumps(spec))
        lerobot("write", str(tmp / "ds"), str(tmp / "spec.json"))
        frames = args.episodes * args.frames
        read, imported, theirs = [], [], []
        for r in range(args.repeats):
            t0 = time.perf_counter()
            n = sum(ep.n_steps for ep in import_lerobot(tmp / "ds"))
            read.append(time.perf_counter() - t0)
            assert n == frames, (n, frames)
            t0 = time.perf_counter()
            import_into_store(import_lerobot, tmp / "ds", EpisodeStore(tmp / f"store{r}"), progress=False)
            imported.append(time.perf_counter() - t0)
            theirs.append(json.loads(lerobot("time", str(tmp / "ds")).strip().splitlines()[-1]))
    best = {"simeval_read": min(read), "simeval_import": min(imported),
            "lerobot_read": min(t["read_s"] for t in theirs), "lerobot_load": min(t["load_s"] for t in theirs)}
    fps = {k: frames / v for k, v in best.items() if k != "lerobot_load"}
    save("lerobot_import", {
        "benchmark": "lerobot_import", "machine": machine(), "load_average_1min": os.getloadavg()[0],
        "dataset": {**spec, "frames_total": frames, "codec": "av1 (lerobot's default: libsvtav1, crf 30, g 2)"},
        "seconds_best_of": args.repeats, "seconds": best, "frames_per_s": fps,
        "ratio_simeval_read_over_lerobot_read": fps["simeval_read"] / fps["lerobot_read"],
        "ratio_simeval_import_over_lerobot_read": fps["simeval_import"] / fps["lerobot_read"]})


if __name__ == "__main__":
    main()
