"""A validity control of the heldout dynamics-diversity protocol on GenSim's own episodes, whose answer is known.

    python src/controls.py gensim_own                    # stacking: its first four stored tasks by name
    python src/controls.py gensim_own --seeds 0 1 2 --per-task 4 --heldout 17 20

The synthetic and suite controls (src/controls.py) validated the protocol on data simeval makes;
this one runs on episodes recorded by GenSim's own code (`src/collect.py pipeline=gensim_own`, 20 per task). Four
tasks of a group, the first four stored by name. `generalist`: one world model trained on episodes 1..k of each of
the four tasks (4k episodes). `specialists`: one model per task, trained on episodes 1..4k of that task alone: the
same number of episodes and the same gradient steps per model. Both are scored on the same held-out episodes (by
default 17-20 of each task), each specialist on its own task's. The answer is known: with the same data a model
that has seen one task's motions four times over predicts that task's unseen episodes better than one that spreads
the data over four tasks' motions, so a number that reads how much a group's dynamics vary must be higher for the
generalist. Criterion, written down before the first run: the generalist's one-step moving-pixel error (Table 4's
reading of motion on GenSim's own rows) minus the specialists' has a 95% interval above zero, from a paired
bootstrap over training seeds and held-out episodes (the same resamples for both: they score the same pixels).
The object-focused error (still pixels: layouts) is judged by the same rule beside it and does not decide.

Each run is simeval.measures.dynamics_diversity.run.fit_and_evaluate with protocol="heldout" at the `cpu` preset and the
protocol's budget (conf/protocol/heldout.yaml), as `src/diversity.py` runs Table 4's rows. A run's record is saved
when it ends (OUT/controls/gensim_own/runs/*.json) and its model is checkpointed, so a killed control resumes. Then
OUT/tables/control_gensim_own.{json,md} (per task and pooled: both errors with intervals, the last-frame baseline,
the differences and the verdict) and OUT/figures/control_gensim_own.png. A committed table or figure is replaced
only with --overwrite. Needs the episodes in the store: without them it says which command collects them.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

from simeval.cli import OneLineParser

PIPELINE = "gensim_own"
CONDITIONS = ("specialists", "generalist")
JUDGED, BESIDE = "one_step_moving", "one_step_object"


def fail(message: str) -> None:
    """A user error: one line on stderr, exit status 2."""
    print(message, file=sys.stderr)
    sys.exit(2)


def task_episodes(store: Path, group: str, n_tasks: int, needed: int, names: list[str] | None = None) -> dict:
    """{task: its stored episode files} for `names` (or the group's first `n_tasks` stored tasks by name), each
    holding at least `needed` episodes; a UserError names what is missing and the command that collects it. The
    files are opened only by a run that trains (a rebuild from saved runs reads none)."""
    from simeval.episodes.dataset import store_paths_for
    from simeval.errors import UserError

    by_task: dict[str, list[str]] = {}
    try:
        paths = store_paths_for(store, PIPELINE, group)
    except UserError:  # none of this pipeline or group there: what to collect says more than what is absent
        paths = []
    for p in paths:
        by_task.setdefault(Path(p).parent.name, []).append(str(p))
    tasks = list(names) if names else sorted(by_task)[:n_tasks]
    short = {t: len(by_task.get(t, ())) for t in tasks if len(by_task.get(t, ())) < needed}
    if len(tasks) < n_tasks or short:
        have = ", ".join(f"{t}: {len(by_task[t])}" for t in sorted(by_task)) or "none"
        which = f"tasks=[{','.join(names)}]" if names else f"task_group={group}"
        raise UserError(f"--store {store}: the control needs {n_tasks} {PIPELINE} tasks of group {group} with "
                        f"{needed} episodes each (has {have}); collect them: python src/collect.py "
                        f"pipeline={PIPELINE} pipeline.root=<your GenSim checkout> {which} episodes={needed}")
    return {t: sorted(by_task[t]) for t in tasks}


def merged(records: list[dict]) -> dict:
    """The specialists of one seed as one record: their held-out episodes side by side (they score disjoint
    tasks), so table4_heldout.sum_arrays pairs them episode for episode with the generalist's."""
    per_episode = [e for r in records for e in r["values"]["prediction"]["per_episode"]]
    return {"path": "+".join(r["path"] for r in records), "values": {"prediction": {"per_episode": per_episode}}}


def verdict(general: list[dict], special: list[dict], n_boot: int = 2000) -> dict:
    """Pooled and per-task errors of both conditions and their differences (generalist minus specialists), with
    percentile intervals from the same resamples of seeds and held-out episodes for both (paired)."""
    import numpy as np

    from simeval.stats import resample
    from simeval.measures.dynamics_diversity.table4_heldout import cell_replicates, max_missing, sum_arrays

    by_seed = {}
    for r in special:
        by_seed.setdefault(r["identity"]["seed"], []).append(r)
    special_recs = [merged(by_seed[s]) for s in sorted(by_seed)]
    general_recs = sorted(general, key=lambda r: r["identity"]["seed"])
    sums_g, tasks = sum_arrays(general_recs)
    sums_s, tasks_s = sum_arrays(special_recs)
    if list(tasks) != list(tasks_s):
        raise RuntimeError("the conditions scored different held-out episodes")
    out: dict = {"pooled": {}, "per_task": {}}
    metrics = (JUDGED, BESIDE, "one_step_moving_last", "one_step_object_last", "one_step_moving_share")

    def cells(columns: np.ndarray, key: dict, seed: int) -> dict:
        draws = resample.draws(len(general_recs), tasks[columns], n_boot, seed=seed)
        pg, rg = cell_replicates({k: v[:, columns] for k, v in sums_g.items()}, draws)
        ps, rs = cell_replicates({k: v[:, columns] for k, v in sums_s.items()}, draws)
        for m in metrics:
            ci = partial(resample.percentile, max_missing=max_missing(m))
            key[m] = {"generalist": pg[m], "generalist_interval": ci(rg[m]), "specialists": ps[m],
                      "specialists_interval": ci(rs[m])}
            if m in (JUDGED, BESIDE):
                key[m].update(difference=pg[m] - ps[m], difference_interval=ci(rg[m] - rs[m]))
        return key

    cells(np.arange(len(tasks)), out["pooled"], seed=1)
    for i, task in enumerate(sorted(set(tasks.tolist()))):
        out["per_task"][task] = cells(np.flatnonzero(tasks == task), {}, seed=2 + i)
    def above_zero(interval):  # None: no reading (too few pixels moved in too many resamples), not a fail
        return bool(interval[0] > 0) if math.isfinite(interval[0]) else None

    out["passes"] = {"moving_pixel_error_higher_for_generalist":
                     above_zero(out["pooled"][JUDGED]["difference_interval"])}
    out["beside"] = {"object_error_higher_for_generalist": above_zero(out["pooled"][BESIDE]["difference_interval"])}
    out["held_out_episodes"] = len(tasks)
    return out


def outcome(v: dict) -> str:
    passed = v["passes"]["moving_pixel_error_higher_for_generalist"]
    return {True: "passes", False: "fails", None: "no reading (too few pixels moved)"}[passed]


def markdown(result: dict) -> str:
    v = result["verdict"]
    title = (f"# Control on GenSim's own episodes ({result['group']}, {result['preset']}, {result['steps']} steps, "
             f"seeds {', '.join(map(str, result['seeds']))})")
    setup = (f"generalist: one model on episodes 1-{result['per_task']} of each task; specialists: one model per task "
             f"on its episodes 1-{result['per_task'] * len(result['tasks'])}; both scored on held-out episodes "
             f"{result['heldout'][0]}-{result['heldout'][1]} of each task ({v['held_out_episodes']} episodes). "
             "x1e-3 per pixel, [95% paired intervals over seeds and held-out episodes]; no reading: too few pixels "
             "moved.")
    header = ("| tasks | moving-pixel one-step: generalist | specialists | difference | last frame | moving share | "
              "object-focused: generalist | specialists | difference |")
    lines = [title, "", setup, "", header, "|---|---|---|---|---|---|---|---|---|"]

    def f(x, iv=None):
        if not math.isfinite(x):
            return "no reading"
        return f"{1e3 * x:.2f}" + (f" [{1e3 * iv[0]:.2f}, {1e3 * iv[1]:.2f}]" if iv and math.isfinite(iv[0]) else "")

    for name, cell in [("pooled", v["pooled"]), *sorted(v["per_task"].items())]:
        m, o = cell[JUDGED], cell[BESIDE]
        lines.append(f"| {name} | {f(m['generalist'], m['generalist_interval'])} | "
                     f"{f(m['specialists'], m['specialists_interval'])} | "
                     f"{f(m['difference'], m['difference_interval'])} "
                     f"| {f(cell['one_step_moving_last']['generalist'])} | "
                     f"{100 * cell['one_step_moving_share']['generalist']:.2f}% | {f(o['generalist'])} | "
                     f"{f(o['specialists'])} | {f(o['difference'], o['difference_interval'])} |")
    beside = {True: "higher", False: "not higher",
              None: "no reading"}[v["beside"]["object_error_higher_for_generalist"]]
    lines += ["", (f"Criterion (the moving-pixel difference's interval above zero): **{outcome(v)}**"
                   f"; object-focused beside it: {beside} for the generalist."), ""]
    return "\n".join(lines)


def plot(result: dict, path: Path) -> None:
    """Per task and pooled: both conditions' moving-pixel and object-focused errors with their intervals, and what
    copying the last frame scores on the same pixels."""
    import textwrap

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    v = result["verdict"]
    names = ["pooled", *sorted(v["per_task"])]
    cells = [v["pooled"], *(v["per_task"][n] for n in names[1:])]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6))
    x = np.arange(len(names))
    for ax, metric, label in ((axes[0], JUDGED, "moving-pixel one-step error (judged)"),
                              (axes[1], BESIDE, "object-focused one-step error (beside)")):
        for j, (cond, color) in enumerate((("specialists", "tab:blue"), ("generalist", "tab:orange"))):
            vals = np.array([1e3 * c[metric][cond] for c in cells])
            ivs = np.array([1e3 * np.array(c[metric][f"{cond}_interval"]) for c in cells])
            err = np.where(np.isfinite(ivs.T), np.abs(ivs.T - vals), np.nan)
            ax.bar(x + (j - 0.5) * 0.38, vals, 0.38, color=color, label=cond, yerr=err, capsize=3)
        if metric == JUDGED:  # on the still pixels a copy is near exact (~1e-3 of the model's): a mark at zero
            last = np.array([1e3 * c[f"{metric}_last"]["generalist"] for c in cells])
            ax.scatter(x, last, marker="_", s=500, color="k", zorder=3, label="last frame copied (same pixels)")
        for i, c in enumerate(cells):
            if not np.isfinite(c[metric]["generalist"]):
                ax.text(x[i], 0.02, "no reading", ha="center", va="bottom", fontsize=8,
                        transform=ax.get_xaxis_transform())
        if not any(np.isfinite(c[metric]["generalist"]) for c in cells):
            ax.set_yticks([])  # nothing to read: no scale to suggest one
        ax.set_xlim(-0.6, len(names) - 0.4)
        ax.set_xticks(x, [textwrap.fill(n, 16, break_on_hyphens=True) for n in names], fontsize=8)
        ax.set_ylabel("x1e-3 per pixel and channel")
        ax.set_ylim(bottom=0)
        ax.set_title(label, fontsize=10)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=3, fontsize=9, bbox_to_anchor=(0.5, 0.91), frameon=False)
    d = v["pooled"][JUDGED]
    diff = (f"{1e3 * d['difference']:.2f} [{1e3 * d['difference_interval'][0]:.2f}, "
            f"{1e3 * d['difference_interval'][1]:.2f}] x1e-3" if math.isfinite(d["difference_interval"][0])
            else "no reading (too few pixels moved)")
    fig.suptitle(f"GenSim's own {result['group']} episodes: {len(result['tasks'])}-task generalist vs one-task "
                 f"specialists at equal data ({result['preset']}, seeds {', '.join(map(str, result['seeds']))}; "
                 f"held-out episodes {result['heldout'][0]}-{result['heldout'][1]}): {outcome(v)}\npooled moving-pixel "
                 f"difference (generalist minus specialists, paired) {diff}; bars: each condition's own interval",
                 fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.87))
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run_all(args) -> list[dict]:
    import torch
    import yaml

    from simeval.episodes.dataset import StoreSource, WindowSpec
    from simeval.episodes.store import read_meta
    from simeval.measures.dynamics_diversity.run import Evaluation, Execution, Training, fit_and_evaluate
    from simeval.models.world_model_training import TrainConfig
    from simeval.models.world_model import WorldModelConfig
    from simeval.results import atomic_write_text

    torch.set_num_threads(args.threads)
    wm = yaml.safe_load((Path(args.conf_dir) / "world_model" / f"{args.preset}.yaml").read_text())
    model_cfg = WorldModelConfig.from_dict(wm["model"])
    window = WindowSpec(**wm["window"])
    episodes = task_episodes(args.store, args.group, args.tasks, args.heldout[1], args.task_names)
    cameras = read_meta(next(iter(episodes.values()))[0])["cameras"]  # one header: the flag named, before training
    if args.camera not in cameras:
        fail(f"error: --camera {args.camera}: the episodes were recorded from {', '.join(cameras)}")
    runs_dir = args.out / "controls" / "gensim_own" / "runs"
    runs_dir.mkdir(parents=True, exist_ok=True)
    settings = {"preset": args.preset, "steps": args.steps, "lr": args.lr, "group": args.group,
                "tasks": sorted(episodes), "per_task": args.per_task, "heldout": list(args.heldout),
                "camera": args.camera, "context": 5, "horizon": args.horizon, "mask_margin": args.mask_margin}
    plan = [("generalist", None, args.per_task)] + [("specialists", t, args.per_task * len(episodes))
                                                    for t in episodes]
    records = []
    for seed in args.seeds:
        for condition, task, k in plan:
            path = runs_dir / f"{condition}_{task or 'all'}_s{seed}.json"
            if path.exists():
                rec = json.loads(path.read_text())
                if rec.get("settings") != settings:
                    fail(f"error: {path} was run with other settings; give another --out, or delete its runs")
                records.append(rec)
                print(f"{path.name}: saved already, reused", flush=True)
                continue
            files = episodes[task] if task else [f for t in sorted(episodes) for f in episodes[t]]
            source = StoreSource(files, args.camera)
            t0 = time.perf_counter()
            training = Training(model_cfg, TrainConfig.from_dict({**wm["train"], "seed": seed}), window,
                                steps=args.steps, lr=args.lr, exclude_robot_from_loss=True)
            evaluation = Evaluation(protocol="heldout", episodes=(args.heldout[0] - 1, args.heldout[1]),
                                    heldout_episodes=None, seed=seed, context=5, horizon=args.horizon,
                                    mask_margin=args.mask_margin)
            values = fit_and_evaluate(source, k, training, evaluation, Execution(
                checkpoint_dir=args.out / "checkpoints" / "controls", progress=False))
            rec = {"metric": "dynamics_diversity", "status": "ok", "path": path.name,
                   "identity": {"pipeline": f"control-{PIPELINE}", "task_group": condition, "task": task,
                                "episodes": k, "preset": args.preset, "seed": seed, "protocol": "heldout",
                                "steps": args.steps},
                   "values": {"prediction": values["prediction"]}, "settings": settings}
            atomic_write_text(path, json.dumps(rec, indent=1))  # a kill mid-write leaves no half record
            records.append(rec)
            one = values["prediction"]["summary"]["one_step"]["model"]
            shown = {k: "no reading" if one.get(k) is None else f"{1e3 * one[k]:.3f}"  # too few pixels moved
                     for k in ("moving_error_per_pixel", "object_error_per_pixel")}
            print(f"{path.name}: moving-pixel {shown['moving_error_per_pixel']}, object-focused "
                  f"{shown['object_error_per_pixel']} x1e-3 in {time.perf_counter() - t0:.0f} s", flush=True)
    return records


def check_arguments(args) -> None:
    """Each refusal one line naming the flag and what would do."""
    for flag, value, least in (("--per-task", args.per_task, 1), ("--steps", args.steps, 1),
                               ("--threads", args.threads, 1), ("--horizon", args.horizon, 1),
                               ("--mask-margin", args.mask_margin, 0)):
        if value < least:
            fail(f"error: {flag} {value}: expected a whole number >= {least}")
    if args.task_names is not None:
        if len(set(args.task_names)) != len(args.task_names):
            fail(f"error: --task-names {' '.join(args.task_names)}: a task twice")
        args.tasks = len(args.task_names)
    from simeval.pipelines.gensim.tasks import SUBSTRING_GROUPS

    if args.group not in SUBSTRING_GROUPS.values():
        fail(f"error: --group {args.group}: GenSim's groups (the authors' substring rule) are "
             f"{', '.join(sorted(SUBSTRING_GROUPS.values()))}")
    if args.tasks < 2:
        fail(f"error: --tasks {args.tasks}: expected at least 2 (with one task the generalist is the specialist)")
    lo, hi = args.heldout
    if not 1 <= lo <= hi:
        fail(f"error: --heldout {lo} {hi}: expected FIRST LAST with 1 <= FIRST <= LAST (1-based, inclusive)")
    if args.per_task * args.tasks >= lo:
        fail(f"error: --per-task {args.per_task} x --tasks {args.tasks}: the specialists would train on held-out "
             f"episodes from {lo}; use fewer, or --heldout past {args.per_task * args.tasks}")
    if args.store.exists() and not args.store.is_dir():
        fail(f"error: --store {args.store}: is a file, not a folder; give the episode store's folder")
    if not (Path(args.conf_dir) / "world_model" / f"{args.preset}.yaml").is_file():
        names = sorted(p.stem for p in (Path(args.conf_dir) / "world_model").glob("*.yaml"))
        fail(f"error: --preset {args.preset}: no conf/world_model/{args.preset}.yaml; one of {', '.join(names)}")


def main(argv: list[str] | None = None, conf_dir: Path = Path("conf")) -> None:
    """The control above; `conf_dir` is the entrypoint's conf/ (src/controls.py passes it)."""
    import yaml

    ap = OneLineParser(prog="controls.py gensim_own", description=__doc__.split("\n\n")[0],
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    protocol = yaml.safe_load((Path(conf_dir) / "protocol" / "heldout.yaml").read_text())
    ap.add_argument("--group", default="stacking", help="a GenSim group with stored gensim_own episodes")
    ap.add_argument("--tasks", type=int, default=4, help="tasks of the group: the first stored ones by name (>= 2)")
    ap.add_argument("--task-names", nargs="+", default=None, help="these tasks of the group instead (as many as "
                    "--tasks)")
    ap.add_argument("--per-task", type=int, default=4, help="the generalist's training episodes per task (each "
                    "specialist trains on tasks x this many of its own)")
    ap.add_argument("--heldout", type=int, nargs=2, default=[17, 20], help="held-out episodes (1-based, inclusive)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="training seeds")
    ap.add_argument("--preset", default="cpu", help="world_model preset (conf/world_model/<name>.yaml)")
    ap.add_argument("--steps", type=int, default=protocol["steps"], help="gradient steps of every model")
    ap.add_argument("--lr", type=float, default=protocol["lr"], help="Adam's learning rate")
    ap.add_argument("--horizon", type=int, default=protocol["horizon"], help="open-loop frames imagined")
    ap.add_argument("--mask-margin", type=int, default=protocol["mask_margin"],
                    help="pixels the robot masks are grown by")
    ap.add_argument("--camera", default="front", help="the recorded camera the models see")
    ap.add_argument("--store", type=Path, default=Path("outputs") / "episodes", help="the episode store")
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    ap.add_argument("--out", type=Path, default=Path("outputs"), help="runs under OUT/controls/gensim_own/runs, "
                    "tables and figures under OUT/tables, OUT/figures")
    ap.add_argument("--overwrite", action="store_true", help="replace a committed table or figure this would change")
    args = ap.parse_args(argv)
    args.conf_dir = conf_dir
    check_arguments(args)
    from simeval.errors import UserError
    from simeval.writing.tables import refuse_committed
    from simeval.results import atomic_write_text, dumps_strict

    try:
        records = run_all(args)
        general = [r for r in records if r["identity"]["task_group"] == "generalist"]
        special = [r for r in records if r["identity"]["task_group"] == "specialists"]
        result = {"control": "gensim_own", "group": args.group, "preset": args.preset, "steps": args.steps,
                  "lr": args.lr, "seeds": args.seeds, "tasks": records[0]["settings"]["tasks"],
                  "per_task": args.per_task, "heldout": args.heldout, "verdict": verdict(general, special)}
        stem = args.out / "tables" / "control_gensim_own"
        figure = args.out / "figures" / "control_gensim_own.png"
        with tempfile.TemporaryDirectory() as tmp:
            made = {stem.with_suffix(".json"): dumps_strict(result, indent=1) + "\n",
                    stem.with_suffix(".md"): markdown(result)}
            plot(result, Path(tmp) / figure.name)
            changed = [p for p, text in made.items() if not p.exists() or p.read_text() != text]
            if not (figure.exists() and figure.read_bytes() == (Path(tmp) / figure.name).read_bytes()):
                changed.append(figure)
            refuse_committed(changed, args.overwrite)
            for p, text in made.items():
                p.parent.mkdir(parents=True, exist_ok=True)
                atomic_write_text(p, text)
            figure.parent.mkdir(parents=True, exist_ok=True)
            figure.write_bytes((Path(tmp) / figure.name).read_bytes())
    except UserError as e:
        fail(f"error: {e}")
    print(markdown(result))
    print("wrote", stem.with_suffix(".json"), stem.with_suffix(".md"), figure)
