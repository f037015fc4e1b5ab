"""The one-disk diagnosis (docs/results/controls.md, "Why the model did not learn one disk"): the one-disk control
(simeval.measures.dynamics_diversity.controls.random_draws.one_disk_control), its varied group, 10 training episodes,
scored on episodes 41-50 under the held-out protocol (conf/protocol/heldout.yaml: 1,000 steps, lr 1e-3, the gate) at
the cpu preset, with the pixels raw (`pixel_norm: none`, the world model's default) or standardised (the held-out
protocol's).

    python src/controls.py plateau                  # the five rows of the table (~20 min, one core)
    python src/controls.py plateau --rows 2 4        # some rows
    python src/controls.py plateau --replot          # the table again from the saved runs

Per row: the image loss and KL every 50 steps; where the image loss left the plateau (the first 50-step block whose
mean is below PLATEAU_EXIT of the plateau's level, the mean of steps 50-150, where the model draws the mean image);
the reconstruction of the held-out frames beside the task's mean image's; the object-focused one-step skill against
the last frame and the mean image; the gate's verdict. Runs are saved under OUT/controls/plateau/ (a killed run
resumes from its checkpoint, under OUT/checkpoints/plateau/); the table goes to
outputs/tables/plateau_diagnosis.{md,json}, replaced only with --overwrite.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

from simeval.cli import OneLineParser
from simeval.measures.dynamics_diversity.controls.common import (add_output_options, fail, preset,
                                                                write_table)

FAINT = (170, 110, 100)  # a low-contrast disk on the grey background (128, 128, 128)
# (colour, training seed, pixel_norm): the table's rows, in its order
ROWS = ((None, 0, "none"), (None, 1, "none"), (FAINT, 0, "none"), (None, 1, "standardise"), (FAINT, 0, "standardise"))
PLATEAU_EXIT = 0.7
LOG_EVERY = 50


def describe(row: int) -> str:
    colour, seed, norm = ROWS[row]
    return f"{'faint' if colour else 'red'} disk, seed {seed}, pixel_norm: {norm}"


def run_row(row: int, checkpoints: Path, conf_dir: Path) -> dict:
    import numpy as np
    import torch

    from simeval.episodes.dataset import WindowSpec
    from simeval.measures.dynamics_diversity.run import Evaluation, Execution, Training, fit_and_evaluate
    from simeval.measures.dynamics_diversity.gate import GateConfig
    from simeval.measures.dynamics_diversity.controls.random_draws import Look, make_control_group, one_disk_control
    from simeval.models.world_model_training import TrainConfig
    from simeval.models.world_model import WorldModelConfig

    torch.set_num_threads(1)
    colour, seed, norm = ROWS[row]
    draw = one_disk_control()
    if colour is not None:
        draw = replace(draw, look=Look((colour,), draw.look.background, draw.look.texture))
    p = preset(conf_dir, "protocol", "heldout")
    wm = preset(conf_dir, "world_model", "cpu")
    src = make_control_group(draw, "varied", size=wm["model"]["image_size"])
    curve: dict[int, list] = {}
    started = time.perf_counter()
    training = Training(WorldModelConfig.from_dict({**wm["model"], "pixel_norm": norm}),
                        TrainConfig.from_dict({**wm["train"], "seed": seed}), WindowSpec(**wm["window"]),
                        steps=p["steps"], lr=p["lr"], exclude_robot_from_loss=p["exclude_robot_from_loss"])
    evaluation = Evaluation(protocol="heldout", episodes=(40, 50), seed=0, context=5, horizon=p["horizon"],
                            mask_margin=p["mask_margin"], gate=GateConfig.from_dict(p["gate"]))
    execution = Execution(checkpoint_dir=checkpoints, device="cpu", progress=False,
                          log_metrics=lambda m, step: curve.setdefault(step // LOG_EVERY, []).append(
                              (m["train"]["image_se"], m["train"]["kl_dyn"])))
    values = fit_and_evaluate(src, 10, training, evaluation, execution)
    blocks = {b * LOG_EVERY: (float(np.mean([x[0] for x in v])), float(np.mean([x[1] for x in v])))
              for b, v in sorted(curve.items())}
    summary = values["prediction"]["summary"]
    one, rec = summary["one_step"], summary["reconstruction"]
    return {"row": row, "describe": describe(row), "colour": colour, "seed": seed, "pixel_norm": norm,
            "curve": {str(k): v for k, v in blocks.items()}, "reconstruction": rec["model"]["error"],
            "reconstruction_mean_image": rec["mean"]["error"], "skill_vs_last": one["object_skill_vs_last"],
            "skill_vs_mean": one["object_skill_vs_mean"], "gate": values["gate"]["verdict"],
            "steps": values["train"]["steps"], "seconds": round(time.perf_counter() - started, 1),
            "resumed": not curve}


def plateau_exit(curve: dict[str, list], steps: int) -> str:
    """Where the image loss left the plateau (see the module docstring), in words; `steps`: the steps trained."""
    blocks = sorted((int(k), v[0]) for k, v in curve.items())
    level = [v for k, v in blocks if LOG_EVERY <= k <= 3 * LOG_EVERY]
    if not level:
        return "n/a (no loss curve: the run resumed from a finished checkpoint)"
    plateau = sum(level) / len(level)
    for k, v in blocks:
        if k > 3 * LOG_EVERY and v < PLATEAU_EXIT * plateau:
            return f"left by step ~{k + LOG_EVERY}"
    return f"never left it in {steps} steps"


def markdown(records: list[dict]) -> str:
    lines = ["# The one-disk control: where the world model leaves the mean-image plateau", "",
             "Built by `python src/controls.py plateau` (its docstring says how each column is read). Varied "
             "group of `one_disk_control()`, 10 training episodes, held-out episodes 41-50, cpu preset, 1,000 steps, "
             "lr 1e-3.", "",
             "| row | image loss | KL on the plateau (steps 50-150) | reconstruction (mean image) | one-step skill vs "
             "last frame / mean image | gate |", "|---|---|---|---|---|---|"]
    for r in records:
        kl = [v[1] for k, v in sorted(r["curve"].items(), key=lambda kv: int(kv[0]))
              if LOG_EVERY <= int(k) <= 3 * LOG_EVERY]
        kl_text = f"{min(kl):.1f}-{max(kl):.1f}" if kl else "n/a"
        exit_text = plateau_exit(r["curve"], r["steps"])
        lines.append(f"| {r['describe']} | {exit_text} | {kl_text} | {r['reconstruction']:.2f} "
                     f"({r['reconstruction_mean_image']:.2f}) | {r['skill_vs_last']:.2f} / {r['skill_vs_mean']:.2f} "
                     f"| {r['gate']} |")
    return "\n".join(lines) + "\n"


def main(argv=None, conf_dir: Path = Path("conf")) -> None:
    ap = OneLineParser(prog="controls.py plateau", description=__doc__.split("\n\n")[0],
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rows", type=int, nargs="+", default=list(range(len(ROWS))),
                    help=f"rows 0-{len(ROWS) - 1} of the table (default: all)")
    add_output_options(ap, "controls/plateau", "the table under TABLES/tables")
    args = ap.parse_args(argv)
    bad = sorted(set(args.rows) - set(range(len(ROWS))))
    if bad:
        fail(f"error: --rows {' '.join(map(str, bad))}: rows are 0..{len(ROWS) - 1}")
    runs = args.out / "controls" / "plateau"
    runs.mkdir(parents=True, exist_ok=True)
    if not args.replot:
        for row in args.rows:
            path = runs / f"row{row}.json"
            if path.exists():
                continue
            record = run_row(row, args.out / "checkpoints" / "plateau" / f"row{row}", conf_dir)
            path.write_text(json.dumps(record, indent=1))
            print(f"{record['describe']}: {plateau_exit(record['curve'], record['steps'])}; reconstruction "
                  f"{record['reconstruction']:.2f} ({record['reconstruction_mean_image']:.2f}); {record['gate']} "
                  f"({record['seconds']:.0f} s)", flush=True)
    records = [json.loads(p.read_text()) for p in sorted(runs.glob("row*.json"))]
    text = markdown(records)
    write_table(args.tables, "plateau_diagnosis", text, records, args.overwrite)
    print(text)
