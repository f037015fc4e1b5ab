"""Benchmark: milliseconds per control step of pile episodes, before and after the pile speed-ups, in one run.

Configurations (each a set of module settings, switched in this process, everything else the same):
- before: Bullet's solver residual (1e-7: all 50 iterations), particles as one-link multibodies, blade at 4 mm;
- physics: the new physics only (World's solver_residual = PILE_SOLVER_RESIDUAL, particles as rigid bodies),
  blade at 4 mm: the same oracle, so the same kind of pushes;
- after: the new physics and the blade at 1 mm (xarm.BLADE_Z): the current code.
For each, the oracle runs the first `--primitives` pushes of seeds 0..`--seeds`-1 of each pile task through
make_env (no cameras, low-level steps recorded as collection does: progress and poses every control step);
configurations alternate seed by seed so that a change in the machine's load hits them alike. Reported per
configuration: control steps, ms per control step (all of it, and physics alone: World.step), and for `after`
also the particles' worst penetration into the table. Writes outputs/bench/pile.json.

    python experiments/benchmarks/pile_bench.py [--seeds 2] [--primitives 5]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from common import machine, save

import simeval.sim.env as env_mod
from simeval.cli import OneLineParser
from simeval.sim.core import objects
from simeval.sim.core.world import PILE_SOLVER_RESIDUAL, World
from simeval.sim.env import make_env
from simeval.sim.experts.pick_place import next_primitive
from simeval.sim.robots import xarm
from simeval.sim.tasks.spec import suite_dir, load_spec

TASKS = ["sweep-pile-into-zone", "sweep-two-piles", "sweep-pile-into-matching-zone"]
CONFIGS = {  # (solver residual for pile worlds, particles in maximal coordinates, blade height)
    "before": (None, False, 0.004),
    "physics": (PILE_SOLVER_RESIDUAL, True, 0.004),
    "after": (PILE_SOLVER_RESIDUAL, True, xarm.BLADE_Z),
}


def run(task: str, seed: int, primitives: int) -> dict:
    spec = load_spec(suite_dir("gensim") / f"{task}.yaml")
    env = make_env(spec, "pick_place", cameras=(), record_low_level=True)
    physics = [0.0]
    step = World.step

    def timed(self, n=None):
        t = time.perf_counter()
        step(self, n)
        physics[0] += time.perf_counter() - t

    World.step = timed
    try:
        env.reset(seed=seed)
        steps, low_z = 0, np.inf
        pile = [o.shape == "pile" for o in env.inst.objects for _ in o.body_ids]  # rows of object_poses
        physics[0] = 0.0
        t0 = time.perf_counter()
        for _ in range(primitives):
            prim = next_primitive(env.world, env.inst)
            if prim is None:
                break
            _, _, term, trunc, info = env.step(prim.pose14(env.world))
            steps += len(info["low_level"]["action"])
            low_z = min(low_z, min(float(p[pile, 2].min()) for p in info["low_level"]["object_poses"]))
            if term or trunc:
                break
        return {"steps": steps, "seconds": time.perf_counter() - t0, "physics_s": physics[0], "min_z": low_z}
    finally:
        World.step = step
        env.close()


def main() -> None:
    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--primitives", type=int, default=5)
    args = ap.parse_args()
    saved = (env_mod.PILE_SOLVER_RESIDUAL, objects.PARTICLE_MAXIMAL, xarm.BLADE_Z)
    runs: dict[str, list[dict]] = {c: [] for c in CONFIGS}
    try:
        for seed in range(args.seeds):
            for task in TASKS:
                for name, (residual, maximal, blade) in CONFIGS.items():
                    env_mod.PILE_SOLVER_RESIDUAL, objects.PARTICLE_MAXIMAL, xarm.BLADE_Z = residual, maximal, blade
                    r = run(task, seed, args.primitives)
                    runs[name].append({"task": task, "seed": seed, **r})
                    print(f"{name:8s} {task} seed {seed}: {r['steps']} steps, "
                          f"{1e3 * r['seconds'] / max(r['steps'], 1):.1f} ms/step", flush=True)
    finally:
        env_mod.PILE_SOLVER_RESIDUAL, objects.PARTICLE_MAXIMAL, xarm.BLADE_Z = saved
    half = objects.PARTICLE / 2
    summary = {}
    for name, rs in runs.items():
        n = sum(r["steps"] for r in rs)
        summary[name] = {
            "control_steps": n,
            "ms_per_step": round(1e3 * sum(r["seconds"] for r in rs) / n, 2),
            "physics_ms_per_step": round(1e3 * sum(r["physics_s"] for r in rs) / n, 2),
            # the table's top is at -1 mm (sim/core/world.py); below that a particle sinks into it
            "max_penetration_mm": round(1e3 * max(0.0, -1e-3 + half - min(r["min_z"] for r in rs)), 2),
        }
    save("pile", {"machine": machine(), "seeds": args.seeds, "primitives": args.primitives, "tasks": TASKS,
                  "configs": {k: dict(zip(("solver_residual", "particle_maximal", "blade_z"), v))
                              for k, v in CONFIGS.items()},
                  "summary": summary, "speedup_after_vs_before": round(
                      summary["before"]["ms_per_step"] / summary["after"]["ms_per_step"], 2), "runs": runs})


if __name__ == "__main__":
    main()
