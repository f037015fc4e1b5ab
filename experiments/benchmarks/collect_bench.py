"""Benchmark: collection speed against the TinyRenderer bound, worker scaling, bytes on disk, window reads.

- render bound: the same scene and cameras rendered in a loop with nothing else (per control step: one frame of
  each recorded camera), measured in this run;
- collection: oracle episodes with the same cameras, control steps recorded per second in one process;
  target >= 70% of the render bound;
- both of the above for the arm drawn with its visual meshes (pybullet_data's STLs, as before) and with its
  collision meshes (simeval's default render URDF), side by side in the same run;
- scaling: the same episodes with 1 and 2 worker processes (near-linear on an idle 2-core machine);
- bytes per frame on disk, and read throughput of 40-step windows (the paper's GenSim chunk length).
Writes outputs/bench/collect.json.

`--suite bbsea` measures the BBSEA suite instead (the Panda under ee_pose control at 4 Hz, 60 physics substeps per
recorded step): render bound, collection rate and ratio for one task per group, 1 and 2 workers on 2 episodes of
each, bytes on disk. Writes outputs/bench/collect_bbsea.json.

    python experiments/benchmarks/collect_bench.py [--suite gensim|bbsea]
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
from common import machine, save

from simeval.cli import OneLineParser
from simeval.collect import collect
from simeval.episodes.store import EpisodeStore, WindowSpec, iter_windows, read_meta
from simeval.sim.core.articulated import set_joint_fraction
from simeval.sim.core.objects import make_object
from simeval.sim.core.world import OBS_CAMERAS, TABLE_Z, World
from simeval.sim.env import find_task
from simeval.sim.robots import panda, xarm
from simeval.sim.robots.xarm import Arm
from simeval.sim.rollout import RecordSettings, run_episode
from simeval.sim.tasks.spec import suite_dir, load_spec, sample_instance

BBSEA_TASKS = ["bbsea-block-in-bin", "bbsea-stack-three-blocks", "bbsea-open-drawer-put-block",
               "bbsea-put-block-in-drawer-and-close"]  # two per group of the BBSEA suite (--suite bbsea)
# one per group of each suite: GenSim's 4 groups (oracle, pick-and-place), RoboGen's 2 (controller, ee_delta)
TASKS = ["put-block-in-zone", "stack-block-tower", "sweep-pile-into-zone", "build-bridge",
         "open-laptop", "close-the-oven-door"]
CAMERAS = ("top", "front")
MESHES = ("visual", "collision")


def render_bound(spec, size: tuple[int, int], mesh: str, n: int = 60, *, bbsea: bool = False) -> float:
    """Observation renders per second in the task's first scene: the most a collection at `size` could record.
    `spec`: a task name of the GenSim/RoboGen suites, or (bbsea) a BBSEA spec file's stem (its Panda, 4 Hz world)."""
    spec = load_spec(suite_dir("bbsea") / f"{spec}.yaml") if bbsea else find_task(spec)
    inst = sample_instance(spec, 0)
    with World(4.0) if bbsea else World() as w:
        panda.Panda(w, render_mesh=mesh) if bbsea else Arm(w, spec.end_effector, render_mesh=mesh)
        rng = np.random.default_rng(0)
        for o in inst.objects:
            make_object(w.c, o, *inst.poses[o.id], rng, TABLE_Z)
            for k, f in enumerate(inst.joints.get(o.id, ())):  # articulated objects as the episode starts
                set_joint_fraction(w.c, o.body_ids[0], k, f)
        w.settle(30)
        t0 = time.perf_counter()
        for _ in range(n):
            for cam in CAMERAS:
                w.render(OBS_CAMERAS[cam], size)
        return n / (time.perf_counter() - t0)


def collection_rate(spec_name: str, size: tuple[int, int], mesh: str) -> tuple[float, int]:
    spec = find_task(spec_name)
    default, xarm.RENDER_MESH = xarm.RENDER_MESH, mesh  # run_episode builds its own Arm: set its default
    try:
        t0 = time.perf_counter()
        ep = run_episode(spec, 0, RecordSettings(cameras=CAMERAS, image_size=size, scene_view_size=(64, 64)))
        return ep.n_steps / (time.perf_counter() - t0), ep.n_steps
    finally:
        xarm.RENDER_MESH = default


def bbsea_main() -> None:
    out: dict = {"benchmark": "collect_bbsea", "machine": machine(), "cameras": list(CAMERAS), "control_hz": 4.0,
                 "physics_substeps_per_step": 60}
    size = (64, 64)
    out["render_mesh_default"] = panda.RENDER_MESH
    for mesh in MESHES:  # the Panda drawn with its visual meshes and with its collision meshes (the default)
        rows = {}
        default, panda.RENDER_MESH = panda.RENDER_MESH, mesh
        try:
            for task in BBSEA_TASKS:
                spec = load_spec(suite_dir("bbsea") / f"{task}.yaml")
                bound = render_bound(task, size, mesh, bbsea=True)
                t0 = time.perf_counter()
                ep = run_episode(spec, 0, RecordSettings(cameras=CAMERAS, image_size=size, scene_view_size=(64, 64)),
                                 pipeline="bbsea")
                rate = ep.n_steps / (time.perf_counter() - t0)
                rows[task] = {"render_bound_steps_per_s": round(bound, 1), "collect_steps_per_s": round(rate, 1),
                              "ratio": round(rate / bound, 3), "episode_steps": ep.n_steps, "success": bool(ep.success)}
        finally:
            panda.RENDER_MESH = default
        out[f"{mesh}_64x64"] = {"tasks": rows, "mean_ratio": round(float(np.mean([r["ratio"] for r in rows.values()])), 3),
                                "mean_collect_steps_per_s": round(float(np.mean(
                                    [r["collect_steps_per_s"] for r in rows.values()])), 1)}
    specs = [load_spec(suite_dir("bbsea") / f"{t}.yaml") for t in BBSEA_TASKS]
    settings = RecordSettings(cameras=CAMERAS, image_size=size, scene_view_size=(64, 64))
    timing = {}
    with tempfile.TemporaryDirectory() as tmp:
        for workers in (1, 2):
            store = EpisodeStore(Path(tmp) / f"w{workers}")
            t0 = time.perf_counter()
            summary = collect(specs, range(2), store, settings, pipeline="bbsea", workers=workers, progress=False)
            timing[workers] = time.perf_counter() - t0
        steps = sum(r["steps"] for r in summary["new"])
        size_bytes = sum(r["bytes"] for r in summary["new"])
    out["scaling"] = {"episodes": len(specs) * 2, "seconds_1_worker": round(timing[1], 2),
                      "seconds_2_workers": round(timing[2], 2), "speedup": round(timing[1] / timing[2], 2)}
    out["disk"] = {"bytes_per_step_all_cameras": round(size_bytes / steps), "steps": steps}
    save("collect_bbsea", out)


def main() -> None:

    ap = OneLineParser()
    ap.add_argument("--suite", choices=("gensim", "bbsea"), default="gensim")
    if ap.parse_args().suite == "bbsea":
        return bbsea_main()
    out: dict = {"benchmark": "collect", "machine": machine(),
                 "cameras": list(CAMERAS), "per_size": {}}
    out["render_mesh_default"] = xarm.RENDER_MESH
    for size in ((64, 64), (128, 128)):
        per_mesh = {}
        for mesh in MESHES:
            rows = {}
            for task in TASKS:
                bound = render_bound(task, size, mesh)
                rate, steps = collection_rate(task, size, mesh)
                rows[task] = {"render_bound_steps_per_s": round(bound, 1), "collect_steps_per_s": round(rate, 1),
                              "ratio": round(rate / bound, 3), "episode_steps": steps,
                              "frames_per_s": round(rate * len(CAMERAS), 1)}
            ratios = [r["ratio"] for r in rows.values()]
            per_mesh[mesh] = {"tasks": rows, "mean_ratio": round(float(np.mean(ratios)), 3), "target_ratio": 0.7,
                              "meets_target": float(np.mean(ratios)) >= 0.7,
                              "mean_render_bound_steps_per_s": round(float(np.mean(
                                  [r["render_bound_steps_per_s"] for r in rows.values()])), 1),
                              "mean_collect_steps_per_s": round(float(np.mean(
                                  [r["collect_steps_per_s"] for r in rows.values()])), 1)}
        speedup = {k: round(per_mesh["collision"][k] / per_mesh["visual"][k], 2)
                   for k in ("mean_render_bound_steps_per_s", "mean_collect_steps_per_s")}
        out["per_size"][f"{size[0]}x{size[1]}"] = {**per_mesh, "collision_over_visual": speedup}
    specs = [find_task(t) for t in TASKS]
    settings = RecordSettings(cameras=CAMERAS, image_size=(64, 64), scene_view_size=(64, 64))
    timing = {}
    with tempfile.TemporaryDirectory() as tmp:
        for workers in (1, 2):
            store = EpisodeStore(Path(tmp) / f"w{workers}")
            t0 = time.perf_counter()
            summary = collect(specs, range(2), store, settings, workers=workers, progress=False)
            timing[workers] = time.perf_counter() - t0
        steps = sum(r["steps"] for r in summary["new"])
        size_bytes = sum(r["bytes"] for r in summary["new"])
        # windows of one action space (a training set never mixes them): the joint-target (GenSim-style) episodes
        paths = [p for p in store.paths() if read_meta(p)["action_space"]["kind"] == "joint_pos+suction"]
        t0 = time.perf_counter()
        windows = sum(1 for _ in iter_windows(paths, WindowSpec(length=40), camera="top"))
        read_s = time.perf_counter() - t0
    out["scaling"] = {"episodes": len(specs) * 2, "seconds_1_worker": round(timing[1], 2),
                      "seconds_2_workers": round(timing[2], 2), "speedup": round(timing[1] / timing[2], 2)}
    out["disk"] = {"bytes_per_step_all_cameras": round(size_bytes / steps), "bytes_per_frame": round(
        size_bytes / steps / len(CAMERAS)), "raw_bytes_per_frame": 64 * 64 * 3, "compression": "gzip per frame"}
    out["windows"] = {"length": 40, "windows": windows, "windows_per_s": round(windows / read_s, 1),
                      "frames_per_s": round(windows * 40 / read_s, 1)}
    save("collect", out)


if __name__ == "__main__":
    main()
