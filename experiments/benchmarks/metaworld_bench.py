"""Benchmark: collection speed per episode of Meta-World (pipeline=metaworld), on the same tasks and seeds, in one
run, one process at a time (so the ratios are per core):

- record_fast: what src/collect.py pipeline=metaworld records (64x64 top + front frames and robot masks at every
  80 Hz step, 4 scene views of 128x128), render_quality=fast (no multisampling, shadows, reflections);
- record_full: the same with render_quality=full (Meta-World's models as they are);
- expert_only: the expert and the physics with no frame at all (Meta-World itself, what the frames cost on top);
- suite: simeval's GenSim-style suite (place-red-in-green, 64x64 top + front at 30 Hz), for scale.
Writes outputs/bench/metaworld.json.

    python experiments/benchmarks/metaworld_bench.py [--seeds 3]
"""

from __future__ import annotations

import time

from common import machine, save

from simeval.cli import OneLineParser
from simeval.pipelines.metaworld.native import (
    MetaworldSettings,
    expert_action,
    import_metaworld,
    make_task_env,
    record_episode,
)
from simeval.sim.rollout import RecordSettings, run_episode
from simeval.sim.tasks.spec import suite_dir, load_spec

TASKS = ("reach-v3", "push-v3", "door-open-v3")


def expert_only(task: str, seed: int, max_steps: int) -> tuple[int, bool]:
    _, _, experts = import_metaworld()
    env, obs = make_task_env(task, seed)
    expert, steps, success = experts[task](), 0, False
    while steps < max_steps and not success:
        obs, _, _, _, info = env.step(expert_action(expert, obs))
        steps, success = steps + 1, bool(info["success"])
    env.close()
    return steps + 1, success


def main() -> None:
    ap = OneLineParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    fast, full = MetaworldSettings(render_quality="fast"), MetaworldSettings(render_quality="full")
    out = {"machine": machine(), "seeds": args.seeds, "tasks": {}}
    record_episode("reach-v3", 0, fast, ["top", "front"], (64, 64))  # MuJoCo's first GL context is not timed
    for task in TASKS:
        rows = {"record_fast": [], "record_full": [], "expert_only": []}
        for seed in range(args.seeds):
            for name, settings in (("record_fast", fast), ("record_full", full)):
                t0 = time.perf_counter()
                ep = record_episode(task, seed, settings, ["top", "front"], (64, 64), (128, 128))
                rows[name].append({"seconds": time.perf_counter() - t0, "frames": ep.n_steps, "success": ep.success})
            t0 = time.perf_counter()
            frames, success = expert_only(task, seed, fast.max_steps)
            rows["expert_only"].append({"seconds": time.perf_counter() - t0, "frames": frames, "success": success})
        summary = {k: {"s_per_episode": sum(r["seconds"] for r in v) / len(v),
                       "frames_per_episode": sum(r["frames"] for r in v) / len(v),
                       "successes": sum(r["success"] for r in v), "episodes": v} for k, v in rows.items()}
        fast_s = summary["record_fast"]["s_per_episode"]
        summary["s_per_frame_fast"] = fast_s / summary["record_fast"]["frames_per_episode"]
        summary["ratio_full_to_fast"] = summary["record_full"]["s_per_episode"] / fast_s
        summary["ratio_fast_to_expert_only"] = fast_s / summary["expert_only"]["s_per_episode"]
        out["tasks"][task] = summary
    suite = []
    for seed in range(args.seeds):
        t0 = time.perf_counter()
        ep = run_episode(load_spec(suite_dir("gensim") / "place-red-in-green.yaml"), seed,
                         RecordSettings(cameras=("top", "front"), image_size=(64, 64)))
        suite.append({"seconds": time.perf_counter() - t0, "frames": ep.n_steps, "success": ep.success})
    out["suite_place_red_in_green"] = {"s_per_episode": sum(r["seconds"] for r in suite) / len(suite),
                                       "s_per_frame": sum(r["seconds"] for r in suite) / sum(r["frames"] for r in suite),
                                       "episodes": suite}
    save("metaworld", out)


if __name__ == "__main__":
    main()
