"""What leaving the robot out of the training loss (protocol.exclude_robot_from_loss) costs per training step.

    python experiments/benchmarks/robot_loss_bench.py [--threads 2] [--steps 22] [--repeats 2]
Writes outputs/bench/robot_loss.json. One process, the `cpu` preset, the visual control's data (4 tasks x 10
episodes of 41 rows with robot masks, 64x64): per setting the median time of a training step (read the windows,
loss, backward, Adam step) over `--steps` batches of 8 windows after two warm-up steps, the two settings
interleaved `--repeats` times so that load drifts touch both. The ratio (robot out / full frame) is the figure to
read; seconds depend on the machine and its load (recorded).
"""

from __future__ import annotations

import time

from common import ROOT, machine, save

from simeval.cli import OneLineParser


def main() -> None:
    import numpy as np
    import torch
    import yaml

    from simeval.episodes.dataset import WindowDataset, WindowSpec
    from simeval.measures.dynamics_diversity.controls.synthetic import make_visual_group
    from simeval.models.world_model_training import collate, to_torch
    from simeval.models.world_model import WorldModel, WorldModelConfig

    ap = OneLineParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--steps", type=int, default=22)
    ap.add_argument("--repeats", type=int, default=2)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    wm = yaml.safe_load((ROOT / "conf" / "world_model" / "cpu.yaml").read_text())
    cfg, spec = WorldModelConfig.from_dict(wm["model"]), WindowSpec(**wm["window"])
    source = make_visual_group("varied", 4, 10, 40, cfg.image_size)
    medians: dict[str, list[float]] = {"full_frame": [], "robot_out_of_loss": []}
    for _ in range(a.repeats):
        for name, masked in (("full_frame", False), ("robot_out_of_loss", True)):
            ds = WindowDataset(source, spec, None, image_size=cfg.image_size, robot_masks=masked, mask_margin=2)
            ds.stats = ds.fit_stats()
            torch.manual_seed(0)
            model = WorldModel(cfg, len(ds.stats.state_mean), len(ds.stats.action_mean))
            opt = torch.optim.Adam(model.parameters(), 1e-3)
            windows = ds.windows(0)[: 8 * (a.steps + 2)]
            times = []
            for i in range(0, len(windows), 8):
                t0 = time.perf_counter()
                loss, _ = model.loss(to_torch(collate([ds[w] for w in windows[i:i + 8]])))
                opt.zero_grad()
                loss.backward()
                opt.step()
                times.append(time.perf_counter() - t0)
            medians[name].append(float(np.median(times[2:])))
    full, out = float(np.median(medians["full_frame"])), float(np.median(medians["robot_out_of_loss"]))
    save("robot_loss", {"machine": machine(), "threads": a.threads, "steps": a.steps, "repeats": a.repeats,
                        "seconds_per_step": medians, "median_full_frame": full, "median_robot_out_of_loss": out,
                        "ratio_robot_out_over_full": out / full})


if __name__ == "__main__":
    main()
