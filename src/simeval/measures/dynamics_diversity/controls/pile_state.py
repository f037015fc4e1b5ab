"""A pile whose particles' friction varies: can the state reading (simeval.measures.dynamics_diversity.state_reading)
read a pile, and how?

    python src/controls.py pile                      # collect (frameless, resumable), read, table and figure
    python src/controls.py pile --replot             # table and figure again from the saved runs

GenSim-style sweep-pile-into-zone (simeval's suite: 50 particles pushed by a spatula) collected without frames at
four levels of how much its particles' friction varies per episode: drawn from 0.425 +- level x 0.375 (0 to 1; the
dose_push control's range), seeds 0 .. 29 at every level (the same starting layouts; the pushes follow the pile, so
the actions part after the first). Each level is one group: the state reading is trained on seeds 0 .. --episodes-1
and scored on the held-out episodes --heldout (1-based: default 11-30, seeds 10-29), with the heldout protocol's
state model, seeds and gate (conf/protocol/heldout.yaml), read twice: as the protocol reads it (every particle's
pose, its quaternion too) and with the particles read by their position alone (read_states(particles_by_position=
True), the alternative this control was built to test).

The criterion, the random controls' dynamics family (random_sweep.verdict_of), fixed before the first run: the
relative one-step error (model / last state; gate.relative_error) of the top level minus the bottom level's, with
its 95% interval over resamples of seeds and of each level's held-out episodes, drawn independently (the levels share
starts, not actions): right where it lies above 0, wrong below 0, "no order" within +-ORDER_MARGIN, "too wide"
where it holds 0 and reaches past the margin (no reading), "gated" where either level's gate fails. The neighbouring
levels' differences are shown, not judged.

Outputs: runs under OUT/controls/pile/runs/ (one JSON per level x reading: a killed run resumes), episodes under
OUT/control_episodes/ (beside the dose controls'), outputs/tables/control_pile_state.{json,md},
outputs/figures/control_pile_state.png.
Committed tables and figures are not replaced unless --overwrite is given.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from simeval.cli import OneLineParser
from simeval.measures.dynamics_diversity.controls.common import (add_output_options, fail, preset, require_folders,
                                                                tracked, write_outputs)
from simeval.measures.dynamics_diversity.controls.random_sweep import ORDER_MARGIN, VERDICTS, verdict_of

TASK = ("gensim", "sweep-pile-into-zone")
LEVELS = {"friction000": 0.0, "friction033": 1 / 3, "friction067": 2 / 3, "friction100": 1.0}
FRICTION = (0.425, 0.375)  # the middle and the half-width at level 1 (0.05 to 0.8, as dose_push's block)
READS = {"position": "particles by position (not the protocol's)", "pose": "every particle's pose (the protocol's)"}


def variation(level: float) -> dict:
    mid, half = FRICTION
    return {"pile": {"friction": [mid - level * half, mid + level * half]}}


def collect_levels(out: Path, episodes: int, workers: int) -> dict:
    """{level: StoreSource of seeds 0 .. episodes-1}, collected once without frames (the store keeps them)."""
    from simeval.collect import collect
    from simeval.episodes.dataset import StoreSource
    from simeval.episodes.store import EpisodeStore
    from simeval.sim.rollout import RecordSettings
    from simeval.sim.tasks.spec import load_suite, suite_dir

    pipeline, task = TASK
    spec = next(s for s in load_suite(suite_dir(pipeline)) if s.name == task)
    store = EpisodeStore(out / "control_episodes")  # beside the dose controls' (not committed)
    sources = {}
    for name, level in LEVELS.items():
        seeds = list(range(episodes))
        done = collect([spec], seeds, store, RecordSettings(cameras=(), robot_masks=False), pipeline=pipeline,
                       workers=workers, progress=False, variation=variation(level))
        print(f"{name}: {len(done['new'])} episodes collected, {done['skipped']} in the store; oracle success "
              f"{done['tasks'][task]['rate']:.2f}", flush=True)
        sources[name] = StoreSource([store.path_for(pipeline, task, s, variation(level)) for s in seeds], None)
    return sources


def read_level(source, reads: str, episodes: int, heldout: tuple[int, int], protocol: dict) -> dict:
    """One level's state reading, by position or with the particles' quaternions: the record the table needs."""
    from simeval.measures.dynamics_diversity.gate import GateConfig
    from simeval.measures.dynamics_diversity.state_reading import (StateModelConfig, read_states, robot_dims,
                                                                   state_reading)

    train = [e for e, i in enumerate(source.infos) if i.seed < episodes]
    held = [e for e, i in enumerate(source.infos) if heldout[0] - 1 <= i.seed < heldout[1]]
    by_position = reads == "position"
    particles = max(len(source.infos[e].extra.get("particles") or ()) for e in train + held) if by_position else 0
    started = time.perf_counter()
    r = state_reading(read_states(source, train + held, by_position), [i.task for i in source.infos], train, held,
                      StateModelConfig.from_dict(protocol["state_model"]), GateConfig.from_dict(protocol.get("gate")),
                      robot_dims=robot_dims(source, train + held), particles=particles)
    rows = r["per_episode"]
    return {"model": [[row["model"][s] for row in rows] for s in range(len(r["seeds"]))],
            "baseline": [row["last_state"] for row in rows], "tasks": [row["task"] for row in rows],
            "gate": {k: r["gate"][k] for k in ("passes", "verdict")}, "summary": r["summary"], "line": r["line"],
            "read_dims": r["read_dims"] - 4 * particles, "seconds": round(time.perf_counter() - started, 1)}


def settings(args) -> dict:
    from simeval.measures.dynamics_diversity.state_reading import VERSION

    protocol = preset(args.conf_dir, "protocol", "heldout")
    return {"episodes": args.episodes, "heldout": list(args.heldout), "state_version": VERSION,
            "protocol": {k: protocol.get(k) for k in ("gate", "state_model")}}


def run_all(args) -> None:
    from simeval.results import atomic_write_text

    runs = args.out / "controls" / "pile" / "runs"
    want = settings(args)
    saved = {}
    for name in LEVELS:
        for reads in READS:
            path = runs / f"{name}_{reads}.json"
            saved[path] = path.exists() and json.loads(path.read_text()).get("settings") == want
            if path.exists() and not saved[path] and not args.overwrite and tracked(path):  # before any work
                fail(f"error: {path} is a committed run of other settings (--episodes, --heldout or the protocol's "
                     "state model); write elsewhere with --out DIR, or replace the committed runs with --overwrite")
    sources = collect_levels(args.out, args.heldout[1], args.workers)
    for name in LEVELS:
        for reads in READS:
            path = runs / f"{name}_{reads}.json"
            if saved[path]:
                print(f"{name} {reads}: saved already ({path.name}), reused", flush=True)
                continue
            record = {"level": name, "reads": reads, "settings": want,
                      **read_level(sources[name], reads, args.episodes, tuple(args.heldout), want["protocol"])}
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(path, json.dumps(record, indent=1))
            print(f"{name} {reads}: {record['gate']['verdict']} ({record['seconds']:.0f} s)", flush=True)


def build(args) -> dict:
    import numpy as np

    from simeval.measures.dynamics_diversity.gate import order_between_groups, relative_error
    from simeval.stats import resample

    runs = args.out / "controls" / "pile" / "runs"
    want = settings(args)
    records = {(r["level"], r["reads"]): r for r in (json.loads(p.read_text()) for p in sorted(runs.glob("*.json")))
               if r.get("settings") == want}

    def arrays(r):
        model = np.asarray(r["model"], float)
        return model, np.tile(np.asarray(r["baseline"], float), (len(model), 1)), r["tasks"]

    def interval(r, seed: int) -> list[float]:  # a level's own, over resamples of its seeds and held-out episodes
        model, base, tasks = arrays(r)
        return resample.percentile(resample.replicates(model, base, resample.draws(len(model), tasks, 2000, seed)))

    names = list(LEVELS)
    missing = [f"{n}_{reads}" for reads in READS for n in names if (n, reads) not in records]
    if missing:  # a table of some levels or one reading would read as the control's verdict
        fail(f"error: no run {', '.join(missing)} under {runs} with these settings (--episodes {args.episodes} "
             f"--heldout {args.heldout[0]} {args.heldout[1]}): run python src/controls.py pile with them")
    out = {"task": "/".join(TASK), "levels": LEVELS, "settings": want, "readings": {}}
    for reads in READS:
        recs = [records[(n, reads)] for n in names]
        top, bottom = recs[-1], recs[0]
        order = order_between_groups(arrays(top), arrays(bottom))
        steps = {f"{b}_minus_{a}": order_between_groups(arrays(rb), arrays(ra))
                 for (a, ra), (b, rb) in zip(zip(names, recs), zip(names[1:], recs[1:]))}
        out["readings"][reads] = {
            "by_level": {n: {"relative_error": relative_error(*arrays(r)[:2]), "interval": interval(r, 1 + i),
                             "gate": r["gate"]["verdict"], "passes": r["gate"]["passes"], "read_dims": r["read_dims"],
                             **{k: r["summary"][k] for k in ("model", "last_state", "constant_velocity",
                                                             "skill_vs_last_state", "skill_vs_constant_velocity")}}
                         for i, (n, r) in enumerate(zip(names, recs))},
            "top_minus_bottom": {"difference": order["difference"], "interval": order["interval"]},
            "steps": {k: {"difference": v["difference"], "interval": v["interval"]} for k, v in steps.items()},
            "verdict": verdict_of("dynamics", top["gate"], bottom["gate"], order)}
    return out


def markdown(table: dict) -> str:
    names = list(table["levels"])
    lines = ["# Control: a pile whose particles' friction varies (state reading)", "",
             f"{table['task']}, four levels of the particles' friction spread per episode (0.425 +- level x 0.375), "
             f"trained on {table['settings']['episodes']} episodes, scored on held-out episodes "
             f"{table['settings']['heldout'][0]}-{table['settings']['heldout'][1]} (seeds "
             f"{table['settings']['heldout'][0] - 1}-{table['settings']['heldout'][1] - 1}); relative one-step error "
             "= model / last state. Verdict (criterion in simeval.measures.dynamics_diversity.controls.pile_state): "
             f"{', '.join(VERDICTS)}; right where the top level's relative error exceeds the bottom's (95% interval "
             f"above 0), no order within +-{ORDER_MARGIN}. Built by `python src/controls.py pile`.", "",
             "| reading | " + " | ".join(f"{n}: relative error [95%] (skill vs last state; gate)" for n in names)
             + " | top - bottom [95%] | verdict |", "|---|" + "---|" * len(names) + "---|---|"]
    for reads, r in table["readings"].items():
        cells = [f"{v['relative_error']:.3f} [{v['interval'][0]:.3f}, {v['interval'][1]:.3f}] "
                 f"({v['skill_vs_last_state']:.2f}; "
                 f"{'reads' if v['passes'] else 'no reading'})"
                 for v in r["by_level"].values()]
        d, (lo, hi) = r["top_minus_bottom"]["difference"], r["top_minus_bottom"]["interval"]
        lines.append(f"| {READS[reads]} | " + " | ".join(cells) + f" | {d:+.3f} [{lo:+.3f}, {hi:+.3f}] | "
                     f"{r['verdict']} |")
    lines += ["", "One-step errors per level (model / last state / constant velocity; the values read):", "",
              "| reading | values read | " + " | ".join(names) + " |", "|---|---|" + "---|" * len(names)]
    for reads, r in table["readings"].items():
        dims = sorted({v["read_dims"] for v in r["by_level"].values()})
        lines.append(f"| {READS[reads]} | {'/'.join(map(str, dims))} | " + " | ".join(
            f"{v['model']:.3g} / {v['last_state']:.3g} / {v['constant_velocity']:.3g}" for v in r["by_level"].values())
            + " |")
    lines += ["", "Neighbouring levels (shown, not judged):", ""]
    for reads, r in table["readings"].items():
        lines.append(f"- {READS[reads]}: " + "; ".join(
            f"{k.replace('_minus_', ' - ')} {v['difference']:+.3f} [{v['interval'][0]:+.3f}, {v['interval'][1]:+.3f}]"
            for k, v in r["steps"].items()))
    return "\n".join(lines) + "\n"


def plot(table: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 5))
    levels = list(table["levels"].values())
    for (reads, r), color in zip(table["readings"].items(), ("tab:blue", "tab:gray")):
        points = list(r["by_level"].values())
        ys = [v["relative_error"] for v in points]
        verdict = {"wrong": "a wrong order", "gated": "gated, no reading"}.get(r["verdict"], r["verdict"])
        ax.plot(levels, ys, "-", color=color, label=f"{READS[reads]}: {verdict}")
        for x, v in zip(levels, points):  # a level with no reading (its gate failed): a hollow marker
            lo, hi = v["interval"]
            ax.errorbar([x], [v["relative_error"]], yerr=[[v["relative_error"] - lo], [hi - v["relative_error"]]],
                        fmt="o", color=color, mfc=color if v["passes"] else "white", capsize=3)
    ax.plot([], [], "o", color="k", mfc="white", label="hollow: that level's gate fails (no reading)")
    ax.plot([], [], ":", color="k", lw=0.6, label="1: the model no better than the last state")
    ax.set_xlabel("particles' friction spread (level: 0.425 +- level x 0.375)")
    ax.set_ylabel("relative one-step error (model / last state)")
    ax.set_title(f"{table['task']}: state reading by friction spread\n(higher: harder to predict, more diverse)",
                 fontsize=9)
    from simeval.writing.figures import save_figure

    ax.axhline(1.0, color="k", lw=0.6, ls=":")  # the model no better than the last state
    fig.legend(loc="lower center", ncol=1, fontsize=8)  # below the axes: inside, it covered the error bars
    fig.tight_layout(rect=(0, 0.2, 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path, dpi=120)  # without dates: a rebuild from the same runs gives the same bytes
    plt.close(fig)


def main(argv=None, conf_dir: Path = Path("conf")) -> None:
    ap = OneLineParser(prog="controls.py pile", description=__doc__.split("\n\n")[0],
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=10, help="training episodes per level (default: 10)")
    ap.add_argument("--heldout", type=int, nargs=2, default=[11, 30], metavar=("FIRST", "LAST"),
                    help="held-out episodes, 1-based inclusive: seeds FIRST-1 .. LAST-1 (default: 11 30)")
    ap.add_argument("--workers", type=int, default=2,
                    help="collection processes, 0: one per core (default: 2); episodes go to OUT/control_episodes")
    add_output_options(ap, "controls/pile/runs", "the table under TABLES/tables, the figure under TABLES/figures")
    args = ap.parse_args(argv)
    args.conf_dir = conf_dir
    require_folders(out=args.out, tables=args.tables)  # before the collection and the readings, not after
    first, last = args.heldout
    if not 2 <= args.episodes < first <= last:
        fail(f"error: --episodes {args.episodes} --heldout {first} {last}: expected 2 <= episodes < first <= last "
             "(the held-out seeds past every training one)")
    if not args.replot:
        run_all(args)
    write_outputs(args, "control_pile_state", build(args), markdown, plot)
