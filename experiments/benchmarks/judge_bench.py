"""Benchmark: judge client throughput against the loopback OpenAI-compatible server at ~300 ms latency.

20 task bundles x 5 repeats x 2 metrics = 200 calls through the real entrypoint (src/quality.py) in a subprocess.
Ideal throughput = min(concurrency / latency, rate limit); target >= 90% of it (the client adds almost nothing).
Then the same run again, fully cached: target < 2 s. Writes outputs/bench/judge.json.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from common import ROOT, machine, save

from simeval.devserver import LoopbackOpenAI
from simeval.judges.providers import Image

LATENCY_S, CONCURRENCY, RATE_PER_MIN, TASKS, REPEATS = 0.3, 16, 6000, 20, 5


def make_bundles(root: Path) -> None:
    rng = np.random.default_rng(0)
    for t in range(TASKS):
        d = root / f"task{t:02d}"
        (d / "scene").mkdir(parents=True)
        (d / "frames").mkdir()
        (d / "task.yaml").write_text(yaml.safe_dump({"description": f"stack the blocks of task {t}"}))
        for v in range(4):
            (d / "scene" / f"{v}.png").write_bytes(Image.from_array(rng.integers(0, 255, (64, 64, 3))).png)
        for f in range(16):
            (d / "frames" / f"{f:03d}.png").write_bytes(Image.from_array(rng.integers(0, 255, (64, 64, 3))).png)


def run(args: list[str]) -> float:
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, str(ROOT / "src" / "quality.py"), *args], cwd=ROOT, capture_output=True,
                         text=True)
    if res.returncode != 0:
        raise SystemExit(res.stderr[-3000:])
    return time.perf_counter() - t0


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp, LoopbackOpenAI(latency_s=LATENCY_S) as srv:
        tmp = Path(tmp)
        make_bundles(tmp / "bundles")
        common = [f"bundles_dir={tmp / 'bundles'}", f"judge.provider.base_url={srv.base_url}", f"repeats={REPEATS}",
                  f"judge.concurrency={CONCURRENCY}", f"judge.rate_limit_per_min={RATE_PER_MIN}",
                  f"cache_dir={tmp / 'cache'}"]
        startup = run([*common, "dry_run=true", f"hydra.run.dir={tmp / 'dry'}"])  # process + imports, no calls
        cold = run([*common, f"hydra.run.dir={tmp / 'cold'}"])
        calls = len(srv.requests)
        span = srv.requests[-1]["t"] - srv.requests[0]["t"] + LATENCY_S  # first request in .. last reply out
        warm = min(run([*common, f"hydra.run.dir={tmp / f'warm{i}'}"]) for i in range(3))
        assert len(srv.requests) == calls, "the cached re-run made HTTP calls"
    ideal = min(CONCURRENCY / LATENCY_S, RATE_PER_MIN / 60)
    measured = calls / span
    result = {
        "benchmark": "judge",
        "machine": machine(),
        "setup": {"latency_s": LATENCY_S, "concurrency": CONCURRENCY, "rate_limit_per_min": RATE_PER_MIN,
                  "tasks": TASKS, "repeats": REPEATS, "metrics": 2, "calls": calls},
        "throughput": {"ideal_calls_per_s": round(ideal, 2), "measured_calls_per_s": round(measured, 2),
                       "ratio": round(measured / ideal, 3), "target_ratio": 0.9,
                       "meets_target": measured / ideal >= 0.9,
                       "note": "measured over the server-side span of the calls (first request to last reply)"},
        "wall_s": {"cold_run": round(cold, 2), "process_startup_dry_run": round(startup, 2),
                   "cached_rerun": round(warm, 2), "cached_target_s": 2.0, "cached_meets_target": warm < 2.0},
    }
    save("judge", result)


if __name__ == "__main__":
    main()
