"""Dynamics-diversity controls drawn at random (simeval.measures.dynamics_diversity.controls.random_draws), for both
readings: the pixel world model of the heldout protocol and the state-space model
(simeval.measures.dynamics_diversity.state_reading).

    python src/controls.py random                        # every draw, both families, both readings
    python src/controls.py random --readings state       # the state reading alone (a minute)
    python src/controls.py random --draws 0 1 --jobs 2   # some draws, two runs at a time
    python src/controls.py random --replot               # table and figure again from the saved runs

A draw (its seed in DRAW_SEEDS, fixed before any was run) fixes 1-4 objects of 2-12% of the frame, colours,
background, texture, camera scale, action kind (force, velocity, pose) and the dynamics knobs. Per draw three groups
of 4 tasks x 50 episodes: "shared" (the base knobs and looks everywhere), "varied" (the draw's varied knobs drawn per
episode; the same looks) and "looks" (the base dynamics; colours, background and texture drawn per episode). Each
group is trained on the first `--episodes` episodes of each task and scored on episodes 41-50 (the protocol's
budget, learning rate, context and settings; conf/protocol/heldout.yaml), each group with its own gate.

The criterion, written down before the first draw ran. The order statistic is the relative one-step error, the
share of a physics-free predictor's error the model leaves (simeval.measures.dynamics_diversity.gate.relative_error):
pixels, the object-focused error over the last frame's; states, the error over the last state's (a group whose
objects move further has larger errors for every predictor; the ratio compares groups whose motions differ in
size). Changed once, after the first full run of the state reading: states were first divided by constant
velocity's error, and draw 8 read no order (STATE_NORMALISER says why); every draw was run again with the last
state. With the difference d = relative error of the varied (or looks) group - the shared group's, and its 95%
interval over resamples of each group's seeds and of the held-out episodes, drawn in pairs (episode e of task t has
the same start and actions in every group of a draw, random_draws.make_control_group;
simeval.stats.resample.paired_draws):
    dynamics family   right: d's interval above 0;  wrong: below 0;  no order: it lies within +-ORDER_MARGIN;
                      too wide: it contains 0 and reaches past +-ORDER_MARGIN (no reading: the held-out episodes
                      cannot tell an order from none)
    visual family     right: d's interval ends at or below +ORDER_MARGIN (the looks do not read as more diverse);
                      wrong: it lies above 0; too wide: it contains 0 and reaches past +ORDER_MARGIN
    gated             either group's reading fails its gate: "no reading", whatever d is
A draw that is wrong is a finding: report it, change the protocol, rerun every draw (never drop one).

Changed twice more, each time for every draw, after the pixel reading read no order on draws 1 and 6 (velocity
actions, gain varied) with one training seed. (1) 3 pixel seeds per group, Table 4's protocol: draw 1 then read the
right order; draw 6 did not (each of its seeds put the varied group above the shared one, by less than the spread of
its held-out episodes). (2) The episodes are resampled in pairs, as the groups were built; the first analysis drew
each group's independently, so what the episodes share entered the difference twice (the looks family's states,
identical in both groups, read +0.000 [-0.074, +0.073] on draw 6; paired, [-0.004, +0.003]). "No order" had been
any interval containing 0, however wide: the metric claimed the groups alike where it could not tell. It now needs
the interval within +-ORDER_MARGIN; a wider one is "too wide", a no reading. The table keeps the independent
interval beside.
A gated group stays gated with more seeds (every seed's gate must pass), so gated draws kept their one pixel seed.

Outputs: runs under OUT/controls/random/runs/ (one JSON per draw x group x reading x seed: a killed sweep resumes;
pixel models are checkpointed under OUT/checkpoints/random_controls), and outputs/tables/random_controls.{json,md},
outputs/figures/random_controls.png. Committed tables and figures are not replaced unless --overwrite is given.
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from simeval.cli import OneLineParser
from simeval.measures.dynamics_diversity.controls.common import (add_output_options, fail, preset, require_folders,
                                                                write_outputs)

DRAW_SEEDS = tuple(range(12))  # fixed before any draw was run; never drop one
GROUPS = {"shared": ("shared", "dynamics"), "varied": ("varied", "dynamics"), "looks": ("varied", "visual")}
FAMILIES = {"dynamics": "varied", "visual": "looks"}  # family -> the group compared with "shared"
READINGS = ("pixel", "state")
# the physics-free predictor the order statistic divides by, per reading: the copy of the last observation for both
# (the first criterion divided the state error by constant velocity's; draw 8 (pose actions, gain varied) then read
# no order although its model's raw error was 3.7x the shared group's: a varied gain moves the objects further, and
# constant velocity's error grew as much as the model's; the copy's error measures the motion itself)
STATE_NORMALISER = "last_state"
N_TASKS, EPISODES, N_ACTIONS, HELDOUT = 4, 50, 40, (41, 50)
# how far apart two groups' relative errors may be and still read as alike: the gate's margin (gate.GateConfig),
# 5% of the physics-free predictor's error, the least skill a model must have to be read at all
ORDER_MARGIN = 0.05
VERDICTS = ("right", "gated", "too wide", "no order", "wrong")


def protocol(conf_dir: Path) -> dict:
    return preset(conf_dir, "protocol", "heldout")


def settings(args) -> dict:
    """What a saved run's numbers depend on besides its draw, group, reading and seed."""
    from simeval.measures.dynamics_diversity.state_reading import VERSION as STATE_VERSION

    return {"preset": args.preset, "episodes": args.episodes, "protocol": protocol(args.conf_dir), "tasks": N_TASKS,
            "actions": N_ACTIONS, "heldout": list(HELDOUT), "state_version": STATE_VERSION}


def relevant(settings: dict, reading: str) -> dict:
    """The part of `settings` a reading's numbers depend on: the state reading does not read the pixel model's
    settings nor the preset, the pixel reading not the state model's, so changing one does not void the other's
    saved runs."""
    proto = dict(settings.get("protocol") or {})
    if reading == "state":
        proto = {k: proto.get(k) for k in ("eval_episodes", "gate", "state_model")}
        return {**{k: v for k, v in settings.items() if k != "preset"}, "protocol": proto}
    proto.pop("state_model", None)
    proto.pop("pixels", None)  # the controls run each reading on its own, whatever protocol.pixels says
    return {**{k: v for k, v in settings.items() if k != "state_version"}, "protocol": proto}


def group_source(draw_seed: int, group: str, size: int):
    from simeval.measures.dynamics_diversity.controls.random_draws import draw_control, make_control_group

    which, kind = GROUPS[group]
    return make_control_group(draw_control(draw_seed), which, n_tasks=N_TASKS, episodes=EPISODES,
                              n_actions=N_ACTIONS, size=size, kind=kind)


def run_one(job: dict) -> dict:
    """One draw x group x reading (x seed for pixels): its record (the per-episode sums the table needs)."""
    import numpy as np
    import torch

    from simeval.episodes.dataset import WindowSpec
    from simeval.measures.dynamics_diversity.run import Evaluation, Execution, Training, fit_and_evaluate
    from simeval.measures.dynamics_diversity.gate import GateConfig
    from simeval.measures.dynamics_diversity.state_reading import StateModelConfig, read_states, state_reading
    from simeval.models.world_model_training import TrainConfig
    from simeval.models.world_model import WorldModelConfig

    torch.set_num_threads(1)
    p = job["settings"]["protocol"]
    wm = job["world_model"]
    k = job["settings"]["episodes"]
    started = time.perf_counter()
    gate_cfg = GateConfig.from_dict(p.get("gate"))
    if job["reading"] == "state":
        src = group_source(job["draw"], job["group"], 16)  # the states do not depend on the frames' size
        tasks = [i.task for i in src.infos]
        train = [e for e, i in enumerate(src.infos) if i.seed < k]
        held = [e for e, i in enumerate(src.infos) if HELDOUT[0] - 1 <= i.seed < HELDOUT[1]]
        r = state_reading(read_states(src, train + held), tasks, train, held,
                          StateModelConfig.from_dict(p["state_model"]), gate_cfg)
        rows = r["per_episode"]
        record = {"model": [[row["model"][s] for row in rows] for s in range(len(r["seeds"]))],
                  "baseline": [row[STATE_NORMALISER] for row in rows], "normaliser": STATE_NORMALISER,
                  "baselines": {b: [row[b] for row in rows] for b in ("last_state", "mean_state",
                                                                     "constant_velocity")},
                  "tasks": [row["task"] for row in rows],
                  "gate": r["gate"], "summary": r["summary"], "training": r["training"]}
    else:
        src = group_source(job["draw"], job["group"], wm["model"]["image_size"])
        model_cfg = WorldModelConfig.from_dict({**wm["model"], **(p.get("model") or {})})
        training = Training(model_cfg, TrainConfig.from_dict({**wm["train"], "seed": job["seed"]}),
                            WindowSpec(**wm["window"]), steps=p["steps"], lr=p["lr"],
                            exclude_robot_from_loss=p["exclude_robot_from_loss"])
        evaluation = Evaluation(protocol="heldout", episodes=(HELDOUT[0] - 1, HELDOUT[1]), seed=job["seed"],
                                context=5, horizon=p["horizon"], mask_margin=p["mask_margin"], gate=gate_cfg)
        values = fit_and_evaluate(src, k, training, evaluation,
                                  Execution(checkpoint_dir=job["checkpoints"], device="cpu", progress=False))
        rows = sorted(values["prediction"]["per_episode"], key=lambda e: (e["task"], e["seed"]))
        summary = values["prediction"]["summary"]
        one, rec = summary["one_step"], summary["reconstruction"]
        record = {"model": [[row["sums"]["one_step/model/object"] for row in rows]],
                  "baseline": [row["sums"]["one_step/last/object"] for row in rows],
                  "tasks": [row["task"] for row in rows], "gate": values["gate"],
                  "summary": {"skill_vs_last": one["object_skill_vs_last"],
                              "skill_vs_mean": one["object_skill_vs_mean"], "moving_share": one["moving_share"],
                              "reconstruction": rec["model"]["error"], "reconstruction_mean": rec["mean"]["error"]},
                  "training": {"steps": values["train"]["steps"], "seconds": values["train"]["seconds"]}}
    record.update({key: job[key] for key in ("draw", "group", "reading", "seed")}, settings=job["settings"],
                  seconds=round(time.perf_counter() - started, 1))
    record["gate"] = {key: record["gate"][key] for key in ("passes", "verdict", "baselines", "tasks_passing", "tasks")}
    del np
    return record


def jobs_for(args) -> list[dict]:
    runs = args.out / "controls" / "random" / "runs"
    jobs = []
    for reading in args.readings:
        for draw in args.draws:
            groups = ["shared"] + [FAMILIES[f] for f in args.families]
            for group in groups:
                for seed in (args.seeds if reading == "pixel" else [0]):
                    path = runs / f"draw{draw:02d}_{group}_{reading}_s{seed}.json"
                    jobs.append({"draw": draw, "group": group, "reading": reading, "seed": seed, "path": str(path),
                                 "settings": settings(args),
                                 "checkpoints": str(args.out / "checkpoints" / "random_controls"),
                                 "world_model": preset(args.conf_dir, "world_model", args.preset)})
    return jobs


def run_and_save(job: dict) -> str:
    from simeval.results import atomic_write_text

    record = run_one(job)
    atomic_write_text(Path(job["path"]), json.dumps(record, indent=1))
    g = record["gate"]
    return (f"draw {job['draw']} {job['group']} {job['reading']} seed {job['seed']}: {g['verdict']} "
            f"({record['seconds']:.0f} s)")


def run_all(args) -> None:
    todo = []
    for job in jobs_for(args):
        path = Path(job["path"])
        if path.exists():
            stored = json.loads(path.read_text()).get("settings") or {}
            if relevant(stored, job["reading"]) != relevant(job["settings"], job["reading"]):
                fail(f"error: {path} was run with other settings; give another --out, or delete it to redo it")
            continue
        todo.append(job)
    Path(args.out / "controls" / "random" / "runs").mkdir(parents=True, exist_ok=True)
    print(f"{len(todo)} runs to do ({sum(j['reading'] == 'pixel' for j in todo)} pixel models, ~6 min each on "
          "one core)", flush=True)
    todo.sort(key=lambda j: (j["reading"] != "state", j["draw"]))  # the fast readings first
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as pool:
            for line in pool.map(run_and_save, todo):
                print(line, flush=True)
    else:
        for job in todo:
            print(run_and_save(job), flush=True)


def verdict_of(family: str, a: dict, b: dict, order: dict) -> str:
    """The criterion of the module docstring: a: the varied (or looks) group's gate, b: the shared group's."""
    if not (a["passes"] and b["passes"]):
        return "gated"
    lo, hi = order["interval"]
    if family == "dynamics":
        if lo > 0:
            return "right"
        if hi < 0:
            return "wrong"
        return "no order" if -ORDER_MARGIN <= lo and hi <= ORDER_MARGIN else "too wide"
    if lo > 0:
        return "wrong"
    return "right" if hi <= ORDER_MARGIN else "too wide"


def build(args) -> dict:
    import numpy as np

    from simeval.measures.dynamics_diversity.gate import order_between_groups

    runs = args.out / "controls" / "random" / "runs"
    records = [json.loads(p.read_text()) for p in sorted(runs.glob("*.json"))]
    by = {}
    for r in records:
        by.setdefault((r["draw"], r["group"], r["reading"]), []).append(r)
    from simeval.measures.dynamics_diversity.controls.random_draws import draw_control

    rows = []
    for draw in sorted({r["draw"] for r in records}):
        for family, group in FAMILIES.items():
            for reading in READINGS:
                a, b = by.get((draw, group, reading)), by.get((draw, "shared", reading))
                if not a or not b:
                    continue

                def arrays(recs):
                    recs = sorted(recs, key=lambda r: r["seed"])
                    model = np.concatenate([np.asarray(r["model"], float) for r in recs])
                    base = np.tile(np.asarray(recs[0]["baseline"], float), (len(model), 1))
                    return model, base, recs[0]["tasks"]

                order = order_between_groups(arrays(a), arrays(b), paired=True)
                independent = order_between_groups(arrays(a), arrays(b))
                gates = {"a": a[0]["gate"], "b": b[0]["gate"]}
                if len(a) > 1 or len(b) > 1:  # pixel seeds: every seed's gate must pass
                    gates = {"a": min((r["gate"] for r in a), key=lambda g: g["passes"]),
                             "b": min((r["gate"] for r in b), key=lambda g: g["passes"])}
                rows.append({"draw": draw, "describe": draw_control(draw).describe(), "family": family,
                             "reading": reading, "seeds": len(a), "difference": order["difference"],
                             "interval": order["interval"], "interval_independent": independent["interval"],
                             "relative_errors": order["relative_errors"],
                             "gate_" + group: gates["a"]["verdict"], "gate_shared": gates["b"]["verdict"],
                             "verdict": verdict_of(family, gates["a"], gates["b"], order)})
    counts = {}
    for row in rows:
        c = counts.setdefault(f"{row['family']}/{row['reading']}", {"draws": 0, **dict.fromkeys(VERDICTS, 0)})
        c["draws"] += 1
        c[row["verdict"]] += 1
    return {"rows": rows, "counts": counts, "draw_seeds": list(DRAW_SEEDS)}


def markdown(table: dict) -> str:
    lines = ["# Random dynamics-diversity controls", "",
             "Per family and reading: draws, how many read the right order, how many were gated (no reading), how "
             f"many had an interval too wide to tell an order from none (no reading: it contains 0 and reaches past "
             f"+-{ORDER_MARGIN}), how many read no order (within +-{ORDER_MARGIN}), how many read the wrong order "
             "(must be 0). Built by "
             "`python src/controls.py random` (criterion in its docstring).", "",
             "| family / reading | draws | right | gated | too wide | no order | wrong |",
             "|---|---|---|---|---|---|---|"]
    for name, c in sorted(table["counts"].items()):
        lines.append(f"| {name} | {c['draws']} | " + " | ".join(str(c[v]) for v in VERDICTS) + " |")
    lines += ["", "| draw | family | reading | pixel seeds | relative error (other / shared) | difference [95%, paired "
              "episodes] | [95%, independent] | verdict | gate (other; shared) |",
              "|---|---|---|---|---|---|---|---|---|"]
    for r in table["rows"]:
        other = FAMILIES[r["family"]]
        lo, hi = r["interval"]
        ilo, ihi = r["interval_independent"]
        seeds = r["seeds"] if r["reading"] == "pixel" else "-"
        lines.append(f"| {r['describe']} | {r['family']} | {r['reading']} | {seeds} | "
                     f"{r['relative_errors'][0]:.3f} / {r['relative_errors'][1]:.3f} | "
                     f"{r['difference']:+.3f} [{lo:+.3f}, {hi:+.3f}] | [{ilo:+.3f}, {ihi:+.3f}] | "
                     f"{r['verdict']} | {r['gate_' + other]}; {r['gate_shared']} |")
    return "\n".join(lines) + "\n"


def plot(table: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = {"right": "tab:green", "gated": "tab:gray", "too wide": "tab:olive", "no order": "tab:orange",
              "wrong": "tab:red"}
    panels = [(f, r) for f in FAMILIES for r in READINGS if any(x["family"] == f and x["reading"] == r
                                                                for x in table["rows"])]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 4.2), squeeze=False)
    for ax, (family, reading) in zip(axes[0], panels):
        rows = [r for r in table["rows"] if r["family"] == family and r["reading"] == reading]
        for i, r in enumerate(rows):
            lo, hi = r["interval"]
            ax.errorbar([i], [r["difference"]], yerr=[[r["difference"] - lo], [hi - r["difference"]]], fmt="o",
                        color=colors[r["verdict"]], capsize=3)
        ax.axhline(0, color="k", lw=0.8)
        for edge in (-ORDER_MARGIN, ORDER_MARGIN):
            ax.axhline(edge, color="k", lw=0.5, ls=":")
        ax.set_xticks(range(len(rows)), [str(r["draw"]) for r in rows])
        ax.set_xlabel("draw")
        other = FAMILIES[family]
        ax.set_title(f"{family} family, {reading} reading\n{other} - shared relative one-step error", fontsize=9)
        c = table["counts"][f"{family}/{reading}"]
        ax.text(0.02, 0.98, ", ".join(f"{v} {c[v]}" for v in VERDICTS), transform=ax.transAxes, va="top",
                fontsize=8)
    handles = [plt.Line2D([], [], marker="o", ls="", color=v, label=k) for k, v in colors.items()]
    fig.legend(handles=handles, loc="lower center", ncol=len(colors), fontsize=8)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None, conf_dir: Path = Path("conf")) -> None:
    ap = OneLineParser(prog="controls.py random", description=__doc__.split("\n\n")[0],
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--draws", type=int, nargs="+", default=list(DRAW_SEEDS),
                    help=f"draw seeds, {DRAW_SEEDS[0]}-{DRAW_SEEDS[-1]} (default: all)")
    ap.add_argument("--families", nargs="+", choices=list(FAMILIES), default=list(FAMILIES))
    ap.add_argument("--readings", nargs="+", choices=READINGS, default=list(READINGS))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0], help="pixel models' training seeds (default: 0)")
    ap.add_argument("--episodes", type=int, default=10, help="training episodes per task (default: 10)")
    ap.add_argument("--preset", default="cpu", help="world_model preset, conf/world_model/<name>.yaml (default: cpu)")
    ap.add_argument("--jobs", type=int, default=2, help="runs at a time (default: 2)")
    add_output_options(ap, "controls/random/runs", "the table under TABLES/tables, the figure under TABLES/figures")
    args = ap.parse_args(argv)
    args.conf_dir = conf_dir
    require_folders(out=args.out, tables=args.tables)
    bad = sorted(set(args.draws) - set(DRAW_SEEDS))
    if bad:
        fail(f"error: --draws {' '.join(map(str, bad))}: not among the fixed draw seeds {DRAW_SEEDS[0]}.."
             f"{DRAW_SEEDS[-1]}")
    if not args.replot:
        run_all(args)
    write_outputs(args, "random_controls", build(args), markdown, plot)
