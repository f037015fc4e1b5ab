"""GenSim's own render beside simeval's GenSim-style render of the tasks both have by name: the initial and final
front frame of one oracle episode each (same seed, same frame size), so what simeval's suite re-creates and what it
does not can be seen. GenSim's episode comes from its own code in the checkout (simeval.pipelines.gensim.native).

    python experiments/gensim_own_compare.py --root ../shared/gensim [--seed 0] [--size 128]
      -> outputs/figures/gensim_own_vs_suite.png, outputs/tables/gensim_own_vs_suite.md
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from simeval.cli import OneLineParser
from simeval.pipelines.gensim.native import GensimSettings, check_checkout, run_worker
from simeval.sim.rollout import RecordSettings, run_episode
from simeval.sim.tasks.spec import SUITES_DIR, load_suite
from simeval.tasks.gensim import registered_names


def shared_tasks(root: Path) -> list:
    """The suite's tasks whose names GenSim's registry also has (same name, re-created by simeval)."""
    names = set(registered_names(root))
    return [s for s in load_suite(SUITES_DIR / "gensim") if s.name in names]


def main() -> None:
    ap = OneLineParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", required=True, help="a GenSim checkout")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--figure", default="outputs/figures/gensim_own_vs_suite.png")
    ap.add_argument("--table", default="outputs/tables/gensim_own_vs_suite.md")
    args = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    root = check_checkout(args.root)
    specs = shared_tasks(root)
    size = (args.size, args.size)
    fig, axes = plt.subplots(len(specs), 4, figsize=(8, 2.1 * len(specs)), squeeze=False)
    rows = ["| task | group | GenSim's own: rows, success | simeval suite: rows, success |", "|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as scratch:
        for i, spec in enumerate(specs):
            arrays, meta = run_worker(spec.name, args.seed, GensimSettings(root=str(root)), size, ["front"],
                                      Path(scratch))
            own = arrays["rgb/front"]
            ep = run_episode(spec, args.seed, RecordSettings(cameras=("front",), image_size=size,
                                                             scene_view_size=(32, 32)))
            suite = ep.rgb["front"]
            for j, (img, title) in enumerate([(own[0], "GenSim: initial"), (own[-1], "GenSim: final"),
                                              (suite[0], "simeval: initial"), (suite[-1], "simeval: final")]):
                ax = axes[i, j]
                ax.imshow(img)
                ax.set_xticks([])
                ax.set_yticks([])
                if i == 0:
                    ax.set_title(title, fontsize=9)
            axes[i, 0].set_ylabel(spec.name, fontsize=8)
            rows.append(f"| {spec.name} | {spec.group} | {len(own)}, {bool(meta['success'])} | "
                        f"{ep.n_steps}, {ep.success} |")
    fig.suptitle(f"GenSim's own code vs simeval's GenSim-style suite (front camera, seed {args.seed}, "
                 f"{args.size}x{args.size})", fontsize=10)
    fig.tight_layout()
    Path(args.figure).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.figure, dpi=110)
    Path(args.table).parent.mkdir(parents=True, exist_ok=True)
    Path(args.table).write_text("\n".join(rows) + "\n")
    print(f"wrote {args.figure} and {args.table}")
    print("\n".join(rows))


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    main()
