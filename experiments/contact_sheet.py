"""Contact sheet of a suite: for every task, the initial scene and the final state after the oracle (seed 0),
labelled with the task name and its description, so a person can check that scenes look like what the
descriptions say. Writes outputs/figures/contact_sheet_<suite>.png.

    python experiments/contact_sheet.py [--suite gensim] [--seed 0] [--size 200]
"""

from __future__ import annotations

import textwrap
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from simeval.cli import OneLineParser

ROOT = Path(__file__).resolve().parents[1]


def tile(args) -> tuple[str, str, str, np.ndarray, np.ndarray, bool]:
    from simeval.sim.rollout import RecordSettings, run_episode
    from simeval.sim.tasks.spec import load_spec

    path, seed, size = args
    spec = load_spec(path)
    ep = run_episode(spec, seed, RecordSettings(cameras=(), scene_view_size=(size, size)),
                     final_frame_size=(size, size))
    return spec.name, spec.group, ep.description, ep.scene_views[0], ep.final_view, ep.success


def main() -> None:
    from PIL import Image, ImageDraw

    from simeval.sim.tasks.spec import suite_dir
    from simeval.sim.tasks.splits import SPLITS_FILE

    ap = OneLineParser()
    ap.add_argument("--suite", default="gensim")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--size", type=int, default=200)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    paths = sorted(p for p in (suite_dir(args.suite)).glob("*.yaml") if p.name != SPLITS_FILE)  # task specs only
    with ProcessPoolExecutor(args.workers) as pool:
        tiles = sorted(pool.map(tile, [(str(p), args.seed, args.size) for p in paths]), key=lambda t: (t[1], t[0]))
    s, label_h, cols = args.size, 58, 4
    cell_w, cell_h = 2 * s + 8, s + label_h
    rows = -(-len(tiles) // cols)
    sheet = Image.new("RGB", (cols * cell_w, rows * cell_h), "white")
    draw = ImageDraw.Draw(sheet)
    for i, (name, group, desc, start, end, ok) in enumerate(tiles):
        x, y = (i % cols) * cell_w, (i // cols) * cell_h
        sheet.paste(Image.fromarray(start), (x, y + label_h))
        sheet.paste(Image.fromarray(end), (x + s + 4, y + label_h))
        draw.text((x + 3, y + 2), f"{group} / {name}  [{'solved' if ok else 'NOT solved'}]", fill="black")
        for k, line in enumerate(textwrap.wrap(desc, width=2 * s // 6)[:3]):
            draw.text((x + 3, y + 16 + 13 * k), line, fill=(60, 60, 60))
    out = ROOT / "outputs" / "figures" / f"contact_sheet_{args.suite}.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(out)
    print(out)


if __name__ == "__main__":
    main()
