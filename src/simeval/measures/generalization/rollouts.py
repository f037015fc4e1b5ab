"""Evaluation of a trained Diffusion Policy: closed-loop rollouts per task and split, and the offline comparison of
samplers on held-out windows.

    rollout_task(policy, task, seeds, ...) -> {"task", "split", "episodes": [{"seed", "start", "success",
        "progress", "steps"}], "success": {"k", "n", "rate", "ci"}, "mean_progress", "unvaried"} (Wilson 95%
        interval, see simeval.stats.intervals); optionally the frames of each episode for a video. "start": the
        first observation's digest (observation_digest). With `unvaried_if` ({seed: the train split's start}), a
        seed whose scene the variation left as it was is not rolled out: its episode is {"seed", "start",
        "unvaried": true} and the success, progress and counts are over the other seeds ("unvaried": how many).
    summarize(rows) -> per split and per group: pooled successes with a Wilson interval, mean progress, and the
        unvaried rollouts left out.
    sampler_action_error(policy, dataset, ...) -> {sampler: mean squared error of the executed actions, in the
        normalised [-1, 1] action units, against the demonstrations}: how close DDIM with k steps comes to DDPM
        with all steps without rollouts.
Both run the policy where it is (simeval.runtime.device): the simulator steps on the CPU, and each action chunk is
one policy call on the policy's device whose actions come back to the CPU.
"""

from __future__ import annotations

import hashlib
import logging
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import torch

from simeval.media import write_video
from simeval.stats.intervals import success_summary
from simeval.runtime.device import module_device, to_device
from simeval.models.diffusion_policy import DiffusionPolicy, RecedingHorizonRunner
from simeval.results import rolled_out
from simeval.sim.closed_loop import act_until_done

log = logging.getLogger(__name__)


def _make_env(task: str, action_space: str, variation, image_size, cameras, max_steps):
    """simeval's own suites' environment (simeval.sim.make_env); a pipeline with its own gives `make_env=`."""
    from simeval.sim import make_env

    kwargs = {"max_steps": max_steps} if max_steps else {}
    return make_env(task, action_space=action_space, variation=variation, image_size=tuple(image_size),
                    cameras=tuple(cameras), **kwargs)


def observation_digest(obs: Mapping) -> str:
    """16 hex digits of SHA-256 over an observation's images (every camera, by name) and its state: two rollouts
    with one digest start from the same scene as the policy sees it. How the eval split tells a variation that
    changed nothing (GenSim's task.mode in most of its tasks) from one that changed the scene."""
    h = hashlib.sha256()
    for camera in sorted(obs["rgb"]):
        image = np.ascontiguousarray(obs["rgb"][camera])
        h.update(f"{camera}:{image.dtype}:{image.shape}".encode())
        h.update(image.tobytes())
    if obs.get("state") is not None:
        h.update(np.ascontiguousarray(obs["state"], dtype=np.float64).tobytes())
    return h.hexdigest()[:16]


def first_observations(policy, task: str, seeds: Sequence[int], *, variation: Mapping | None = None,
                       max_steps: int | None = None, make_env=None) -> dict[int, str]:
    """{seed: observation_digest of the first observation} of `task` under `variation`, nothing rolled out (for a
    train split rolled out before rollouts recorded their start)."""
    cfg = policy.cfg
    env = (make_env or _make_env)(task, cfg.action_space, dict(variation or {}), cfg.image_size, list(cfg.cameras),
                                  max_steps)
    try:
        return {int(seed): observation_digest(env.reset(seed=int(seed))[0]) for seed in seeds}
    finally:
        env.close()


def rollout_task(policy: DiffusionPolicy, task: str, seeds: Sequence[int], *, split: str = "train",
                 variation: Mapping | None = None, max_steps: int | None = None, keep_frames: bool = False,
                 video_camera: str | None = None, scheduler: str | None = None, steps: int | None = None,
                 make_env=None, unvaried_if: Mapping[int, str] | None = None, on_episode=None) -> dict:
    """`make_env(task, action_space, variation, image_size, cameras, max_steps)`: the pipeline's environment
    (simeval.pipelines.base.Pipeline.make_env); default simeval's suites'. `unvaried_if`: {seed: start digest} of
    the same task's train rollouts; a seed that starts from the same observation here is left out (a rollout from a
    train scene says nothing about the variation). `on_episode(episode)`: called as each seed's rollout ends (the
    caller's cache: a killed evaluation keeps the rollouts it finished)."""
    cfg = policy.cfg
    cams = list(dict.fromkeys([*cfg.cameras, *([video_camera] if video_camera else [])]))
    env = (make_env or _make_env)(task, cfg.action_space, dict(variation or {}), cfg.image_size, cams, max_steps)
    unvaried_if = {int(k): v for k, v in (unvaried_if or {}).items()}
    # a trained policy acts through receding-horizon chunks; a baseline (random_baseline.RandomActions) brings its own
    runner = policy.runner(env) if hasattr(policy, "runner") else RecedingHorizonRunner(policy, scheduler=scheduler,
                                                                                         steps=steps)
    episodes, videos = [], {}
    try:
        for seed in seeds:
            obs, info = env.reset(seed=int(seed))
            start = observation_digest({"rgb": {c: obs["rgb"][c] for c in cfg.cameras}, "state": obs.get("state")})
            if unvaried_if.get(int(seed)) == start:
                episodes.append({"seed": int(seed), "start": start, "unvaried": True})
                if on_episode is not None:
                    on_episode(episodes[-1])
                continue
            runner.reset(seed=int(seed))
            camera = video_camera or cfg.cameras[0]
            frames = [obs["rgb"][camera]] if keep_frames else None
            done = act_until_done(env, runner.act, obs,
                                  (lambda o, _: frames.append(o["rgb"][camera])) if keep_frames else None)
            info = done["info"]
            episodes.append({"seed": int(seed), "start": start, "success": done["success"],
                             "progress": done["progress"], "steps": done["steps"],
                             **({"error": str(info["error"])} if info.get("error") else {})})  # the env's own failure
            if frames is not None:
                videos[int(seed)] = np.stack(frames)
            if on_episode is not None:
                on_episode(episodes[-1])
    finally:
        env.close()
    out = {"task": task, "split": split, **episodes_summary(episodes)}
    if keep_frames:
        out["frames"] = videos
    return out


def episodes_summary(episodes: Sequence[Mapping]) -> dict:
    """A task row's episodes with their success (Wilson interval), mean progress and unvaried count, the unvaried
    ones left out of both."""
    ran = rolled_out(episodes)
    return {"episodes": list(episodes), "success": success_summary(e["success"] for e in ran),
            "mean_progress": _mean_progress(ran),
            "unvaried": len(episodes) - len(ran)}


def _mean_progress(episodes: Sequence[Mapping]) -> float | None:
    """None where there is no episode, or where the environment reports no progress (a Gymnasium env whose adapter
    reads none): an unknown progress is not a progress of 0."""
    progress = [e["progress"] for e in episodes]
    return None if not progress or None in progress else float(np.mean(progress))


def mark_unvaried(row: Mapping, train_starts: Mapping[int, str], starts: Mapping[int, str]) -> dict:
    """An eval row rolled out before its seeds were compared (a cached one; `starts`: its first observations where
    its episodes lack them) with every episode that started from its train rollout's observation marked unvaried
    (its outcome dropped) and its summary recomputed."""
    episodes = []
    for e in row["episodes"]:
        start = e.get("start", starts.get(int(e["seed"])))
        if e.get("unvaried") or start is None or start != train_starts.get(int(e["seed"])):
            episodes.append(e if start is None or "start" in e else {**e, "start": start})
        else:
            episodes.append({"seed": int(e["seed"]), "start": start, "unvaried": True})
    return dict(row) if episodes == list(row["episodes"]) else {**row, **episodes_summary(episodes)}


def summarize(rows: Sequence[Mapping]) -> dict:
    """rows: rollout_task results (without frames). Per split: every rolled-out episode of the split's tasks pooled;
    "unvaried": the episodes left out because the variation changed nothing (see rollout_task)."""
    out = {}
    for split in dict.fromkeys(r["split"] for r in rows):
        pooled = episodes_summary([e for r in rows if r["split"] == split for e in r["episodes"]])
        out[split] = {"success": pooled["success"], "mean_progress": pooled["mean_progress"],
                      "tasks": len([r for r in rows if r["split"] == split]), "unvaried": pooled["unvaried"]}
    return out


@torch.no_grad()
def sampler_action_error(policy: DiffusionPolicy, dataset, samplers: Mapping[str, tuple[str, int]],
                         max_windows: int = 64, seed: int = 0) -> dict:
    """samplers: {label: (scheduler, steps)}. Each sampler predicts the same windows from the same observations
    and the same initial noise; the error is over the executed actions (indices To-1 .. To-1+Ta-1). Runs where the
    policy is."""
    cfg = policy.cfg
    rows = np.random.default_rng(seed).permutation(len(dataset))[:max_windows]
    batch = to_device(dataset.window(rows), module_device(policy))
    target = policy.action_norm(batch["action"].float())
    sl = slice(cfg.n_obs_steps - 1, cfg.n_obs_steps - 1 + cfg.n_action_steps)
    out = {}
    for label, (kind, steps) in samplers.items():
        gen = torch.Generator().manual_seed(seed)
        pred = policy.predict_action(batch, kind, steps, gen)
        err = (policy.action_norm(pred) - target)[:, sl]
        out[label] = {"scheduler": kind, "steps": int(steps), "mse": float((err**2).mean()), "windows": len(rows)}
    return out


def best_and_worst_videos(policy: DiffusionPolicy, rows: Sequence[Mapping], seed: int, max_steps: int | None,
                          camera: str, out_dir: str | os.PathLike, make_env=None) -> dict:
    """Roll out the best and the worst task (by success rate, then mean progress) of the first split again at
    `seed` with frames kept, and write `videos/<best|worst>_<split>_<task>.mp4`. Returns {which: path}."""
    split = rows[0]["split"]
    ranked = sorted((r for r in rows if r["split"] == split),
                    key=lambda r: (r["success"]["rate"] or 0.0, r["mean_progress"] or 0.0))
    out = {}
    for which, row in (("worst", ranked[0]), ("best", ranked[-1])):
        if which == "best" and row is ranked[0] and "worst" in out:
            out["best"] = out["worst"]  # one task only
            continue
        rec = rollout_task(policy, row["task"], [seed], split=split, variation=row.get("variation") or None,
                           max_steps=max_steps, keep_frames=True, video_camera=camera, make_env=make_env)
        out[which] = str(write_video(rec["frames"][seed], Path(out_dir) / "videos" / f"{which}_{split}_{row['task']}.mp4"))
    return out
