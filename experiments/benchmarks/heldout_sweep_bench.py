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
    from simeval.models.prediction import evaluate_prediction, task_mean_images
    from simeval.models.synthetic import make_physics_group
    from simeval.models.training import collate, epoch_batches, evaluate, to_torch
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
    torch.manual_seed(0)
    model = WorldModel(cfg, len(stats.state_mean), len(stats.action_mean))
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    batches = epoch_batches(train.windows(0), 8, 0, 0)
    times = []
    for i in range(a.steps + 2):
        batch = to_torch(collate([train[w] for w in batches[i % len(batches)]]))
        t0 = time.perf_counter()
        loss, _ = model.loss(batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
        times.append(time.perf_counter() - t0)
    step_s = float(np.median(times[2:]))

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
        groups[name] = {"tasks": tasks, "rows": rows, "paper_steps": paper_steps, "paper_minutes": paper_s / 60,
                        "heldout_steps": 9 * protocol["steps"], "heldout_minutes": (held_train + held_eval) / 60,
                        "heldout_eval_share": held_eval / (held_train + held_eval),
                        "heldout_over_paper": (held_train + held_eval) / paper_s}
    save("heldout_sweep", {
        "what": "cost of a 10/20/40 dynamics-diversity sweep per protocol at the cpu preset (heldout: 3 seeds)",
        "machine": machine(), "threads": a.threads, "load_average": os.getloadavg()[0],
        "step_s": step_s, "heldout_eval_s_per_frame": heldout_frame_s, "paper_eval_s_per_frame": paper_frame_s,
        "heldout_eval_over_paper_eval_per_frame": heldout_frame_s / paper_frame_s,
        "protocol_steps": protocol["steps"], "groups": groups})


if __name__ == "__main__":
    main()
