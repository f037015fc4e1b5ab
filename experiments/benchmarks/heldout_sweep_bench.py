"""What a dynamics-diversity sweep costs under each protocol at the `cpu` preset, and where the time goes.

    python experiments/benchmarks/heldout_sweep_bench.py [--threads 2] [--steps 30]
Writes outputs/bench/heldout_sweep.json. Measured in one process on the dynamics-only control's data (4 tasks x 50
episodes of 41 rows, 64x64): the training step (median over --steps steps after two warm-up steps), the heldout
protocol's evaluation (one-step, open loop, reconstruction and both baselines on episodes 41-50) and the paper
protocol's (reconstruction and open loop on episodes 1-40), each per evaluated frame. From these, per group of
simeval's suites (tasks and mean rows per episode as collected), the cost of a 10/20/40 sweep:
    paper     sum over k of 10 epochs x ceil(windows(k) / 8) steps + 40 T episodes evaluated, one seed
    heldout   3 seeds x 3 counts x `protocol.steps` steps + 10 T episodes evaluated per run
windows(k) = k T episodes x (rows - 20) / 10 + 1 windows each (windows of 20 every 10 rows). The ratio heldout /
paper is measured in this one run; absolute seconds depend on the machine and its load (recorded).

Issue 50 changed the heldout protocol's model (`pixel_norm: standardise`) and added a state-space reading to every
run (simeval.measures.dynamics_diversity.state_reading), so both steps are timed here in one process, `before` (the
preset's model, `pixel_norm: none`, no state reading: the protocol until then) and `now` (the protocol's model, plus
the state reading of each run, timed on the same episodes' states at the protocol's settings: 3 seeds x the whole
3,000-step cap since state reading version 4, measured, not derived); `now_over_before` per group is the ratio of the two
sweep costs (the issue allows up to 2x).
"""

from __future__ import annotations

import math
import os
import time

from common import ROOT, machine, save

from simeval.cli import OneLineParser

# (pipeline/group: tasks, mean rows per episode), from the committed Table 4 runs (README, Dynamics diversity)
GROUPS = {"bbsea/drawer": (7, 40), "bbsea/table": (9, 40), "robogen/table_top": (6, 45), "robogen/ground": (7, 45),
          "gensim/placement": (6, 230), "gensim/piles": (3, 385), "gensim/assembling": (5, 407)}


def main(argv: list[str] | None = None) -> None:
    import numpy as np
    import torch
    import yaml

    from simeval.episodes.dataset import WindowDataset, WindowSpec, episode_ranks, rank_mask
    from simeval.measures.dynamics_diversity.prediction import evaluate_prediction, pixel_stats, task_mean_images
    from simeval.measures.dynamics_diversity.state_reading import StateModelConfig, read_states, state_reading
    from simeval.measures.dynamics_diversity.controls.synthetic import make_physics_group
    from simeval.models.world_model_training import collate, epoch_batches, evaluate, to_torch
    from simeval.models.world_model import WorldModel, WorldModelConfig

    ap = OneLineParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--steps", type=int, default=30)
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)
    wm = yaml.safe_load((ROOT / "conf" / "world_model" / "cpu.yaml").read_text())
    protocol = yaml.safe_load((ROOT / "conf" / "protocol" / "heldout.yaml").read_text())
    cfg = WorldModelConfig.from_dict(wm["model"])
    src = make_physics_group("varied", 4, 50, 40, cfg.image_size)
    ranks = episode_ranks([i.task for i in src.infos], [i.seed for i in src.infos])
    window = WindowSpec(**wm["window"])
    train = WindowDataset(src, window, rank_mask(ranks, 0, 10), image_size=cfg.image_size)
    train.stats = stats = train.fit_stats()
    batches = epoch_batches(train.windows(0), 8, 0, 0)

    def step_seconds(model_cfg: WorldModelConfig):
        torch.manual_seed(0)
        model = WorldModel(model_cfg, len(stats.state_mean), len(stats.action_mean))
        if model_cfg.pixel_norm != "none":
            model.set_pixel_stats(*pixel_stats(src, rank_mask(ranks, 0, 10), model_cfg.image_size))
        opt = torch.optim.Adam(model.parameters(), lr=1e-3)
        times = []
        for i in range(a.steps + 2):
            batch = to_torch(collate([train[w] for w in batches[i % len(batches)]]))
            t0 = time.perf_counter()
            loss, _ = model.loss(batch)
            opt.zero_grad()
            loss.backward()
            opt.step()
            times.append(time.perf_counter() - t0)
        return model, float(np.median(times[2:]))

    now_cfg = WorldModelConfig.from_dict({**wm["model"], **(protocol.get("model") or {})})
    model, step_s = step_seconds(cfg)
    _, now_step_s = step_seconds(now_cfg)
    states = read_states(src, range(len(src.infos)))
    tasks = [i.task for i in src.infos]
    t0 = time.perf_counter()
    reading = state_reading(states, tasks, np.flatnonzero(rank_mask(ranks, 0, 10)).tolist(),
                            np.flatnonzero(rank_mask(ranks, 40, 50)).tolist(),
                            StateModelConfig.from_dict(protocol["state_model"]))
    state_s = time.perf_counter() - t0

    context, horizon = 5, protocol["horizon"]

    def held(length: int) -> WindowDataset:
        return WindowDataset(src, WindowSpec(length, length, pad_end=True), rank_mask(ranks, 40, 50), stats=stats,
                             image_size=cfg.image_size, robot_masks=True)

    means = task_mean_images(src, rank_mask(ranks, 0, 10), cfg.image_size)
    t0 = time.perf_counter()
    pred = evaluate_prediction(model, held(window.length), held(context + horizon), means, context)
    heldout_eval_s = time.perf_counter() - t0
    heldout_frame_s = heldout_eval_s / pred["summary"]["reconstruction"]["frames"]
    paper = WindowDataset(src, WindowSpec(window.length, window.length, pad_end=True), rank_mask(ranks, 0, 40),
                          stats=stats, image_size=cfg.image_size)
    t0 = time.perf_counter()
    ev = evaluate(model, paper, context=context)
    paper_eval_s = time.perf_counter() - t0
    paper_frame_s = paper_eval_s / ev["frames"]

    def windows(k: int, tasks: int, rows: int) -> int:
        return k * tasks * (max(rows - window.length, 0) // window.stride + 1)

    groups = {}
    for name, (tasks, rows) in GROUPS.items():
        paper_steps = sum(wm["train"]["epochs"] * math.ceil(windows(k, tasks, rows) / 8) for k in (10, 20, 40))
        paper_s = paper_steps * step_s + 3 * 40 * tasks * rows * paper_frame_s
        held_train = 9 * protocol["steps"] * step_s
        held_eval = 9 * 10 * tasks * rows * heldout_frame_s
        # the state reading trains a fixed 3 seeds x max_steps per run whatever the rows (version 4), so its
        # measured seconds stand for every group's run (the wider states of a many-object group cost more: the
        # sweeps' own result.json files record each run's, e.g. 15-55 s, GenSim piles' 378 values about 130 s);
        # kept by its inputs (state_reading-<key>.json), it is read once per count, not once per seed
        now_s = 9 * protocol["steps"] * now_step_s + held_eval + 3 * state_s
        groups[name] = {"tasks": tasks, "rows": rows, "paper_steps": paper_steps, "paper_minutes": paper_s / 60,
                        "heldout_steps": 9 * protocol["steps"], "heldout_minutes": (held_train + held_eval) / 60,
                        "heldout_eval_share": held_eval / (held_train + held_eval),
                        "heldout_over_paper": (held_train + held_eval) / paper_s,
                        "now_minutes": now_s / 60, "now_over_before": now_s / (held_train + held_eval)}
    save("heldout_sweep", {
        "what": "cost of a 10/20/40 dynamics-diversity sweep per protocol at the cpu preset (heldout: 3 seeds)",
        "machine": machine(), "threads": a.threads, "load_average": os.getloadavg()[0],
        "step_s": step_s, "now_step_s": now_step_s, "now_step_over_before": now_step_s / step_s,
        "state_reading_s": state_s, "state_reading_steps_used": [t["steps_used"] for t in reading["training"]],
        "state_only_sweep_minutes": 3 * state_s / 60,  # protocol.pixels=false: one run per count
        "heldout_eval_s_per_frame": heldout_frame_s, "paper_eval_s_per_frame": paper_frame_s,
        "heldout_eval_over_paper_eval_per_frame": heldout_frame_s / paper_frame_s,
        "protocol_steps": protocol["steps"], "groups": groups})


if __name__ == "__main__":
    main()
