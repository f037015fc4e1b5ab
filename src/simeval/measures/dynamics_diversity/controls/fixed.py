"""Validity controls of the heldout dynamics-diversity protocol, on data whose answer is known, at the `cpu` preset.

    python src/controls.py dynamics            # physics shared vs varied, identical visuals
    python src/controls.py dynamics --seeds 0 1 2 --episodes 10 20 40 --steps 2000
    python src/controls.py visual --episodes 10   # identical physics, the robot's look varied
    python src/controls.py dose --episodes 10 --heldout 11 30   # 4 levels of a real task's pose range
    python src/controls.py dose_drawer --episodes 10 --heldout 11 30   # 4 drawer-opening noises
    python src/controls.py dose_push --episodes 10 --heldout 11 30   # 4 friction ranges of a push

Each run (condition x training-episode count x seed) is simeval.measures.dynamics_diversity.run.fit_and_evaluate with
protocol="heldout": trained on episodes 1..k of every task for the same `--steps` gradient steps, scored on
held-out episodes 41-50. A run's numbers are saved as soon as it ends (outputs/controls/<control>/runs/*.json) and
its model is checkpointed, so a killed control resumes where it stopped. Then:
    outputs/tables/control_<control>.{json,md}   per condition and count the errors, skills, intervals (seeds x
                                                 held-out episodes) and the verdicts below
    outputs/figures/control_<control>.png        one-step error (with baselines), skill and object-focused error
                                                 against episodes

The budget (steps, learning rate), context and horizon default to the protocol's (conf/protocol/heldout.yaml).
The dynamics control passes when the varied group's one-step error (the protocol's primary number) at the fewest
episodes is higher than the shared group's with a 95% interval of the difference above zero, and its fall from the
fewest to the most episodes is larger (interval of the difference of falls above zero). A failed control is
reported as it is. The visual control passes when the full-frame one-step error of the varied-looks group is
higher than the shared group's (95% interval of the difference above zero) while the object-focused error (robot
pixels excluded) moves less than a quarter as much, relative to the shared group's (the ratio is reported).
A dose-response control (DOSES) collects one real suite task (PyBullet, oracle demonstrations with robot masks)
at four levels of one variation knob into OUT/control_episodes, and passes when its judged number increases with
the level at every step (point values) and the top level minus the bottom one has a 95% interval above zero:
`dose`, GenSim's put-blocks-in-matching-zones from the top camera at four initial-pose ranges (the `scene:
{pose_range}` knob: 0 = one layout in every episode, 1 = the suite's usual uniform poses), judged by the protocol's
primary number (the object-focused one-step error, robot pixels out of the loss and the score); `dose_drawer`,
BBSEA's close-drawer from the front camera at four noises of the drawer's initial opening (`drawer:
{joint_init_noise}`: how far the slide the arm closes varies), judged by the one-step moving-pixel error;
`dose_push`, BBSEA's push-block-to-area from the front camera at four ranges of the block's friction (`block:
{friction}`, centred on one mean: how the block answers the same push varies, which no frame shows before it moves),
judged by the one-step moving-pixel error. The criteria were written down before each control ran.
The moving-pixel errors (simeval.measures.dynamics_diversity.prediction: kept pixels whose colour changed from the
reference frame) are read beside the primary number, by criteria written down before their first reading
(`moving_passes`; they do not decide `passes`): in the dynamics control the same two criteria on the one-step
moving-pixel error; in the visual control the moving-pixel error moves less than a quarter as much as the full frame's.
The `dose` control reports their share of the kept pixels (its top camera shows nothing moving outside the robot: the
carried block is under the suction cup); `dose_drawer` is judged by them. `--reevaluate` scores saved runs again from
their checkpoints, for quantities added later; `--replot` draws the figure again from the committed table alone (after
a change to the plotting code). `--conditions` runs some conditions only (two processes can share the runs; the last
one to finish, or any later call, builds the table from every run saved).
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from simeval.cli import OneLineParser
from simeval.measures.dynamics_diversity.controls.common import fail, preset, refuse_to_replace_committed, tracks_any_in



@dataclass(frozen=True)
class Dose:
    """A dose-response control: one real suite task collected at levels of one variation knob (`knob`: the
    variation's (section, key); a level l is the variation {section: {key: l}}), scored by `metric` (a
    table4_heldout name) whose criterion was written down before the control ran."""

    task: tuple[str, str]  # (pipeline, task)
    camera: str
    knob: tuple[str, str]
    levels: dict  # condition name -> level; the names sort by level
    metric: str
    knob_label: str
    window: tuple = ()  # (key, value) pairs over the preset's training window, where the task's episodes need them
    span: tuple[float, float] | None = None  # a range knob: level l draws from the middle of span +- l half-widths

    def variation(self, level: float) -> dict:
        if self.span is None:
            return {self.knob[0]: {self.knob[1]: level}}
        mid, half = (self.span[0] + self.span[1]) / 2, (self.span[1] - self.span[0]) / 2
        return {self.knob[0]: {self.knob[1]: [mid - level * half, mid + level * half]}}


DOSES = {
    # how much the layouts vary: poses pulled towards one anchor layout (fixed counts: only the poses differ)
    "dose": Dose(("gensim", "put-blocks-in-matching-zones"), "top", ("scene", "pose_range"),
                 {"range000": 0.0, "range033": 1 / 3, "range067": 2 / 3, "range100": 1.0}, "one_step_object",
                 "initial-pose range (scene.pose_range)"),
    # how much the motion varies: the drawer starts open by 0.8 of its travel, +- up to the noise, and the arm closes
    # it from there, in view of the front camera (the drawer's slide is most of what moves outside the robot)
    "dose_drawer": Dose(("bbsea", "bbsea-close-drawer"), "front", ("drawer", "joint_init_noise"),
                        {"noise000": 0.0, "noise017": 1 / 6, "noise033": 1 / 3, "noise050": 0.5}, "one_step_moving",
                        "drawer's initial-opening noise (drawer.joint_init_noise)",
                        # its episodes are 23 rows: a window of 20 from an offset past 3 would hold none (the
                        # preset's window check refuses that), so the last window of an epoch runs past the end
                        window=(("pad_end", True),)),
    # how the pushed block responds: its friction drawn per episode from 0.425 +- level x 0.375 (level 1: 0.05 to
    # 0.8; the mean stays the same, so only how much the response varies grows); the camera cannot see it before
    # the block moves (PyBullet multiplies it by the table's 0.6). A sticky block moves with the fingers, a slippery
    # one runs ahead of them in jerks; the arm's path is the same plan either way
    "dose_push": Dose(("bbsea", "bbsea-push-block-to-area"), "front", ("block", "friction"),
                      {"friction000": 0.0, "friction033": 1 / 3, "friction067": 2 / 3, "friction100": 1.0},
                      "one_step_moving", "pushed block's friction range (block.friction: 0.425 +- level x 0.375)",
                      window=(("pad_end", True),), span=(0.05, 0.8)),
}
CONDITIONS = {"dynamics": ("shared", "varied"), "visual": ("shared", "varied"),
              **{name: tuple(d.levels) for name, d in DOSES.items()}}
ROBOT_MASKS = {"dynamics": False, "visual": True, **dict.fromkeys(DOSES, True)}  # whether episodes carry robot masks


def sources(control: str, size: int, n_tasks: int, n_actions: int, episodes: int, data_seed: int,
            out: Path | None = None, workers: int = 1) -> dict:
    from simeval.measures.dynamics_diversity.controls.synthetic import make_physics_group, make_visual_group

    make = {"dynamics": make_physics_group, "visual": make_visual_group}.get(control)
    if make is not None:
        return {kind: make(kind, n_tasks, episodes, n_actions, size, seed=data_seed) for kind in CONDITIONS[control]}
    if control in DOSES:
        return dose_sources(DOSES[control], size, episodes, out, workers)
    fail(f"error: control {control!r}: expected one of {', '.join(CONDITIONS)}")


def dose_sources(dose: Dose, size: int, episodes: int, out: Path, workers: int) -> dict:
    """Per level, episode seeds 0..episodes-1 of the dose's task collected (once: the store keeps them, keyed by
    the variation) at frames of `size` with robot masks, from the dose's camera."""
    from simeval.collect import collect
    from simeval.episodes.dataset import StoreSource
    from simeval.episodes.store import EpisodeStore
    from simeval.sim.rollout import RecordSettings
    from simeval.sim.tasks.spec import suite_dir, load_suite

    pipeline, task = dose.task
    spec = next(s for s in load_suite(suite_dir(pipeline)) if s.name == task)
    store = EpisodeStore(out / "control_episodes")
    settings = RecordSettings(cameras=(dose.camera,), image_size=(size, size), robot_masks=True)
    data = {}
    for name, level in dose.levels.items():
        variation = dose.variation(level)
        seeds = list(range(episodes))
        done = collect([spec], seeds, store, settings, pipeline=pipeline, workers=workers, progress=False,
                       variation=variation)
        failed = [e for e in done["new"] if not e.get("success", True)]
        print(f"{name} ({dose.knob[1]} {level:.2f}): {len(done['new'])} episodes collected, {done['skipped']} in the "
              f"store; oracle success {done['tasks'][task]['rate']:.2f}" + (f", {len(failed)} failed" if failed
                                                                           else ""), flush=True)
        data[name] = StoreSource([store.path_for(pipeline, task, s, variation) for s in seeds], dose.camera)
    return data


def run_settings(args, has_robot_masks: bool) -> dict:
    """What a run's numbers depend on besides its condition, count and seed: a saved run is reused only when these
    match (else the table would label old numbers with new settings). Where the data has no robot masks (the
    dynamics control) leaving the robot out of the loss changes nothing, so it is not a setting there."""
    settings = {"preset": args.preset, "steps": args.steps, "lr": args.lr, "context": args.context,
                "horizon": args.horizon, "mask_margin": args.mask_margin, "heldout": list(args.heldout),
                "tasks": args.tasks, "actions": args.actions,
                "data_seed": args.data_seed}
    if has_robot_masks:
        settings["exclude_robot_from_loss"] = args.exclude_robot_from_loss
    return settings


def _refuse_other_settings(path: Path, settings: dict) -> None:
    stored = json.loads(path.read_text()).get("settings")
    if stored != settings:
        differ = sorted(key for key in settings if (stored or {}).get(key) != settings[key])
        fail(f"error: {path} was run with other settings ({', '.join(differ)}: "
             f"{', '.join(str((stored or {}).get(key)) for key in differ)}); give another "
             f"--out for these settings, or delete that folder's runs to redo them")


def _run_record(path: Path, identity: dict, values: dict, settings: dict) -> dict:
    """A saved control run: what the table reads (no machine paths, no last batch)."""
    record = {"metric": "dynamics_diversity", "status": "ok", "path": path.name, "identity": identity,
              "values": {key: values[key] for key in ("protocol", "prediction", "train", "model")},
              "settings": settings}
    record["values"]["train"] = {k2: v for k2, v in values["train"].items() if k2 != "last"}
    return record


def _one_step_line(values: dict) -> str:
    one = values["prediction"]["summary"]["one_step"]
    obj = {who: 1e3 * one[who]["object_error_per_pixel"] for who in ("model", "last", "mean")}
    return (f"object-focused one-step {obj['model']:.3f} x1e-3 (last frame {obj['last']:.3f}, mean image "
            f"{obj['mean']:.3f}); full frame {one['model']['error']:.2f} (last frame {one['last']['error']:.2f}, "
            f"mean image {one['mean']['error']:.2f})")


def run_all(args) -> list[dict]:
    import torch

    from simeval.episodes.dataset import WindowSpec
    from simeval.measures.dynamics_diversity.run import fit_and_evaluate
    from simeval.models.world_model import WorldModelConfig
    from simeval.results import atomic_write_text

    torch.set_num_threads(args.threads)
    wm = preset(args.conf_dir, "world_model", args.preset)
    model_cfg = WorldModelConfig.from_dict(wm["model"])
    runs_dir = args.out / "controls" / args.control / "runs"
    runs_dir.mkdir(parents=True, exist_ok=True)
    data: dict = {}

    def source_of(condition: str):
        """The episodes, made (or for dose collected) when a run first needs training: a rebuild from saved runs
        needs none."""
        if not data:
            data.update(sources(args.control, model_cfg.image_size, args.tasks, args.actions, args.heldout[1],
                                args.data_seed, args.out, args.threads))
            if any(s.has_robot_masks() for s in data.values()) != ROBOT_MASKS[args.control]:
                raise RuntimeError(f"ROBOT_MASKS[{args.control!r}] does not match its episodes")
        return data[condition]

    settings = run_settings(args, ROBOT_MASKS[args.control])
    window = WindowSpec(**{**wm["window"], **dict(DOSES[args.control].window if args.control in DOSES else ())})
    if args.reevaluate and not args.overwrite and tracks_any_in(runs_dir):  # before any record is rewritten
        fail(f"error: {runs_dir} holds committed runs; --reevaluate rewrites them: add --overwrite, or write "
             "elsewhere with --out DIR")
    for seed in args.seeds:
        for condition in CONDITIONS[args.control]:
            for k in args.episodes:
                path = runs_dir / f"{condition}_k{k}_s{seed}.json"
                if not _to_run(path, condition, k, seed, args, settings):
                    continue
                t0 = time.perf_counter()
                reevaluated = path.exists()  # --reevaluate: from its checkpoint, refused where it is gone
                training, evaluation, execution = _run_parts(args, wm, model_cfg, window, seed, reevaluated)
                values = fit_and_evaluate(source_of(condition), k, training, evaluation, execution)
                identity = {"pipeline": f"control-{args.control}", "task_group": condition, "episodes": k,
                            "preset": args.preset, "seed": seed, "protocol": "heldout", "steps": args.steps}
                if reevaluated:
                    print(f"{condition} k={k} seed={seed}: evaluated again from its checkpoint", flush=True)
                # a kill mid-write leaves the old record
                atomic_write_text(path, json.dumps(_run_record(path, identity, values, settings), indent=1))
                print(f"{condition} k={k} seed={seed}: {_one_step_line(values)} in {time.perf_counter() - t0:.0f} s",
                      flush=True)
    return [json.loads(p.read_text()) for p in sorted(runs_dir.glob("*.json"))]


def _to_run(path: Path, condition: str, k: int, seed: int, args, settings: dict) -> bool:
    """Whether the run saved at `path` is to be trained (or, with --reevaluate, evaluated again); a saved run of
    other settings, or a new one beside committed runs without --overwrite, is refused."""
    if path.exists():
        _refuse_other_settings(path, settings)
        if not args.reevaluate:
            print(f"{condition} k={k} seed={seed}: saved already ({path.name}), reused", flush=True)
            return False
    if args.conditions and condition not in args.conditions:
        return False
    if not path.exists() and not args.overwrite and tracks_any_in(path.parent):  # before training, not after
        fail(f"error: {path.parent} holds committed runs and {path.name} is not among them; "
             "write elsewhere with --out DIR, or add to them with --overwrite")
    return True


def _run_parts(args, wm: dict, model_cfg, window, seed: int, reevaluated: bool) -> tuple:
    """(Training, Evaluation, Execution) of one run of the control: the preset's world model and the options."""
    from simeval.measures.dynamics_diversity.run import Evaluation, Execution, Training
    from simeval.models.world_model_training import TrainConfig

    training = Training(model_cfg, TrainConfig.from_dict({**wm["train"], "seed": seed}), window, steps=args.steps,
                        lr=args.lr, exclude_robot_from_loss=args.exclude_robot_from_loss)
    evaluation = Evaluation(protocol="heldout", episodes=(args.heldout[0] - 1, args.heldout[1]), seed=seed,
                            context=args.context, horizon=args.horizon, mask_margin=args.mask_margin)
    execution = Execution(checkpoint_dir=args.out / "checkpoints" / "controls", progress=False,
                          evaluate_only=reevaluated)
    return training, evaluation, execution


def verdicts(records: list[dict], conditions: tuple[str, str], n_boot: int = 2000) -> dict:
    """Differences between the two conditions (second minus first) with intervals from independent resamples of
    each condition's seeds and held-out episodes: at the fewest episodes, and of the falls to the most."""
    from simeval.stats import resample
    from simeval.measures.dynamics_diversity.table4_heldout import cell_replicates, max_missing, sum_arrays

    counts = sorted({int(r["identity"]["episodes"]) for r in records})
    lo, hi = counts[0], counts[-1]
    reps, points = {}, {}
    for i, cond in enumerate(conditions):
        for k in (lo, hi):
            recs = sorted((r for r in records if r["identity"]["task_group"] == cond and
                           int(r["identity"]["episodes"]) == k), key=lambda r: r["identity"]["seed"])
            sums, tasks = sum_arrays(recs)
            draws = resample.draws(len(recs), tasks, n_boot, seed=1 + i)  # independent between conditions
            points[cond, k], reps[cond, k] = cell_replicates(sums, draws)
    out = {}
    a, b = conditions
    for metric in ("one_step", "one_step_object", "one_step_skill_last", "open_loop", "open_loop_skill_last",
                   "reconstruction", "one_step_moving", "one_step_moving_skill_last", "open_loop_moving",
                   "open_loop_moving_skill_last"):
        if not all(metric in p for p in points.values()):  # some runs recorded before the moving pixels were summed
            continue
        ci = partial(resample.percentile, max_missing=max_missing(metric))
        diff = reps[b, lo][metric] - reps[a, lo][metric]
        fall_b = reps[b, lo][metric] - reps[b, hi][metric]
        fall_a = reps[a, lo][metric] - reps[a, hi][metric]
        out[metric] = {
            f"{b}_minus_{a}_at_{lo}": points[b, lo][metric] - points[a, lo][metric],
            f"{b}_minus_{a}_at_{lo}_interval": ci(diff),
            f"fall_{lo}_to_{hi}": {c: points[c, lo][metric] - points[c, hi][metric] for c in conditions},
            "fall_difference": (points[b, lo][metric] - points[b, hi][metric])
            - (points[a, lo][metric] - points[a, hi][metric]),
            "fall_difference_interval": ci(fall_b - fall_a)}
    # the protocol's primary number (table4_heldout.PRIMARY): the object-focused one-step error, which is the full
    # frame's per pixel where episodes have no robot masks (the dynamics control: its verdict is unchanged by it)
    primary = out["one_step_object"]
    out["passes"] = {"higher_at_fewest": primary[f"{b}_minus_{a}_at_{lo}_interval"][0] > 0,
                     "larger_fall": primary["fall_difference_interval"][0] > 0}
    # how far each error moves from the first condition to the second, relative to the first (the visual control)
    rel = {m: (points[b, lo][m] - points[a, lo][m]) / points[a, lo][m]
           for m in ("one_step", "one_step_object", "one_step_moving") if m in points[a, lo]}
    out["relative_change_at_fewest"] = {**rel, "object_over_full": abs(rel["one_step_object"]) /
                                        max(abs(rel["one_step"]), 1e-12)}
    if "one_step_moving" in rel:
        out["relative_change_at_fewest"]["moving_over_full"] = abs(rel["one_step_moving"]) / max(abs(rel["one_step"]),
                                                                                                 1e-12)
    # the moving pixels' readings beside the primary one, judged by criteria written before their runs (the module
    # docstring); they do not decide `passes`
    if "one_step_moving" in out:
        m = out["one_step_moving"]
        out["moving_passes"] = {"higher_at_fewest": m[f"{b}_minus_{a}_at_{lo}_interval"][0] > 0,
                                "larger_fall": m["fall_difference_interval"][0] > 0,
                                "moves_under_a_quarter_of_full": out["relative_change_at_fewest"].get(
                                    "moving_over_full", float("nan")) < 0.25}
    return out


def dose_verdict(records: list[dict], levels: tuple[str, ...], n_boot: int = 2000,
                 primary: str = "one_step_object") -> dict:
    """Per level (at the fewest episodes) the object-focused, full-frame and moving-pixel errors, skills and shares
    with intervals, the differences between neighbouring levels and between the top and bottom levels (independent
    resamples of each level's seeds and held-out episodes), and whether `primary` (the dose's judged number) rises
    with the level; a level with no reading of it (nothing moved) passes nothing."""
    import numpy as np

    from simeval.stats import resample
    from simeval.measures.dynamics_diversity.table4_heldout import cell_replicates, max_missing, sum_arrays

    k = min(int(r["identity"]["episodes"]) for r in records)
    points, reps = {}, {}
    for i, level in enumerate(levels):
        recs = sorted((r for r in records if r["identity"]["task_group"] == level and
                       int(r["identity"]["episodes"]) == k), key=lambda r: r["identity"]["seed"])
        sums, tasks = sum_arrays(recs)
        points[level], reps[level] = cell_replicates(sums, resample.draws(len(recs), tasks, n_boot, seed=1 + i))
    out: dict = {"episodes": k}
    for metric in ("one_step_object", "one_step", "one_step_object_skill_last", "one_step_skill_last",
                   "one_step_moving", "one_step_moving_skill_last", "one_step_moving_share", "open_loop_moving_share",
                   "open_loop_moving", "open_loop_moving_skill_last"):
        if not all(metric in p for p in points.values()):  # some runs recorded before the moving pixels were summed
            continue
        ci = partial(resample.percentile, max_missing=max_missing(metric))
        out[metric] = {
            "by_level": {lv: [points[lv][metric], *ci(reps[lv][metric])] for lv in levels},
            "steps": {f"{b}_minus_{a}": [points[b][metric] - points[a][metric],
                                         *ci(reps[b][metric] - reps[a][metric])]
                      for a, b in zip(levels, levels[1:])},
            "top_minus_bottom": [points[levels[-1]][metric] - points[levels[0]][metric],
                                 *ci(reps[levels[-1]][metric] - reps[levels[0]][metric])]}
    judged = out.get(primary)  # the dose's number, fixed before the run
    if judged is None:
        fail(f"error: the runs have no {primary} (recorded before it was summed): rerun with --reevaluate")
    finite = all(np.isfinite(v[0]) for v in judged["by_level"].values())  # nothing moving at a level: no reading
    out["judged_by"] = primary
    out["passes"] = {"rises_at_every_level": finite and all(v[0] > 0 for v in judged["steps"].values()),
                     "top_minus_bottom_above_zero": finite and judged["top_minus_bottom"][1] > 0}
    return out


def moving_share_by_margin(dose: Dose, out: Path, heldout: tuple[int, int], margins=(0, 1, 2)) -> dict:
    """Per level and robot-mask margin, the share of the kept pixels of the held-out episodes (seeds heldout[0]-1 to
    heldout[1]-1) whose colour changed from the frame before (the moving-pixel rule of
    simeval.measures.dynamics_diversity.prediction, on the data alone, no model): where the judged moving-pixel error
    has no reading, this says whether the motion was there but inside the margin around the robot that the protocol
    leaves out."""
    import h5py
    import numpy as np

    from simeval.episodes.dataset import grow_masks
    from simeval.episodes.store import EpisodeStore
    from simeval.measures.dynamics_diversity.prediction import MOTION_THRESHOLD
    from simeval.sim.tasks.spec import suite_dir, check_variation, load_suite

    pipeline, task = dose.task
    spec = next(s for s in load_suite(suite_dir(pipeline)) if s.name == task)
    store = EpisodeStore(out / "control_episodes")
    shares: dict = {}
    for name, level in dose.levels.items():
        variation = check_variation([spec], dose.variation(level))
        moving, kept = dict.fromkeys(margins, 0), dict.fromkeys(margins, 0)
        for seed in range(heldout[0] - 1, heldout[1]):
            with h5py.File(store.path_for(pipeline, task, seed, variation), "r") as f:
                rgb = f[f"obs/rgb/{dose.camera}"][:].astype(np.float32) / 255
                robot = f[f"obs/robot_mask/{dose.camera}"][:]
            changed = ((rgb[1:] - rgb[:-1]) ** 2).sum(-1) > MOTION_THRESHOLD
            for m in margins:
                grown = grow_masks(robot, m)
                keep = ~grown[1:] & ~grown[:-1]
                moving[m] += int((changed & keep).sum())
                kept[m] += int(keep.sum())
        shares[name] = {f"margin_{m}": {"moving_pixels": moving[m], "share": moving[m] / kept[m]} for m in margins}
    return shares


def plot_dose(rows: list[dict], dose: Dose, path: Path, title: str) -> Path:
    """Against the dose's level, each with its interval and both baselines on the same pixels: the object-focused
    one-step error, the moving-pixel one-step error (where the runs summed it) and the full-frame one-step error;
    the panel of the dose's judged number says so, and the title when it has no reading. Saved without dates (simeval.writing.figures.save_figure): the
    same runs give the same bytes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from simeval.writing.figures import save_figure

    by_level = {r["group"]: r for r in rows}
    names = [n for n in dose.levels if n in by_level]
    x = np.array([dose.levels[n] for n in names])
    k = int(rows[0]["counts"].split("/")[0])
    panels = [("one_step_object", 1e3, "per kept pixel and channel (x1e-3)", "object-focused one-step error"),
              ("one_step_moving", 1e3, "per moving pixel and channel (x1e-3)", "moving-pixel one-step error"),
              ("one_step", 1.0, "sum over pixels per frame", "full-frame one-step error (robot not trained on)")]
    judged_label = next(p[3] for p in panels if p[0] == dose.metric)
    panels = [p for p in panels if all(np.isfinite(by_level[n].get(f"{p[0]}_{k}", np.nan)) for n in names)]
    if dose.metric not in [p[0] for p in panels]:  # the judged number has no reading: say so, not only "NO"
        from simeval.measures.dynamics_diversity.prediction import MIN_MOVING_PIXELS

        title += (f"\njudged by the {judged_label}: no reading (fewer than {MIN_MOVING_PIXELS} kept pixels moved "
                  "one step ahead at some level), so nothing passes")
    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 4.2))
    for ax, (name, scale, unit, label) in zip(np.atleast_1d(axes), panels):
        v = np.array([by_level[n][f"{name}_{k}"] for n in names]) * scale
        lo = np.array([by_level[n][f"{name}_{k}_lo"] for n in names]) * scale
        hi = np.array([by_level[n][f"{name}_{k}_hi"] for n in names]) * scale
        ax.errorbar(x, v, yerr=np.maximum(np.stack([v - lo, hi - v]), 0), fmt="o-", color="C0", capsize=3,
                    label="model (95% CI)")
        ax.plot(x, [by_level[n][f"{name}_last_{k}"] * scale for n in names], ":x", color="C1", label="last frame")
        ax.plot(x, [by_level[n][f"{name}_mean_{k}"] * scale for n in names], "--+", color="C2", ms=9,
                label="task's mean training image")
        ax.set_xticks(x, [f"{level:.2f}" for level in x])
        ax.set(xlabel=dose.knob_label, ylabel=unit, title=label + (" (judged)" if name == dose.metric else ""))
    # one legend below the panels: inside them it covered a baseline's line (every panel has the same three keys)
    fig.legend(*np.atleast_1d(axes)[0].get_legend_handles_labels(), loc="lower center", ncol=3, fontsize=8,
               frameon=False)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    out = save_figure(fig, path, dpi=120)
    plt.close(fig)
    return out


def draw_figure(result: dict, path: Path) -> Path:
    """The control's figure from its table's JSON (`result`: rows, settings, verdict), so a figure can be drawn
    again from a committed table alone (--replot), without its runs or episodes."""
    from simeval.measures.dynamics_diversity.table4_heldout import plot

    passes = ", ".join(f"{k.replace('_', ' ')}: {'yes' if v else 'NO'}" for k, v in result["verdict"]["passes"].items())
    seeds = ", ".join(map(str, result["seeds"]))
    title = f"{result['control']} control ({result['preset']}, {result['steps']} steps, seeds {seeds}): {passes}"
    dose = DOSES.get(result["control"])
    if dose is None:
        return plot(result["rows"], path, title)
    lo, hi = result["heldout"]
    return plot_dose(result["rows"], dose, path, f"{'/'.join(dose.task)} ({dose.camera}), {min(result['episodes'])} "
                     f"training episodes, held-out episodes {lo}-{hi}\n{title}")


def replot(control: str, out: Path, overwrite: bool) -> Path:
    """--replot: draw OUT/figures/control_<control>.png again from OUT/tables/control_<control>.json (after a
    change to the plotting code); a committed figure that would change is replaced only with --overwrite."""
    table = out / "tables" / f"control_{control}.json"
    try:
        result = json.loads(table.read_text())
    except FileNotFoundError:
        where = "" if out.resolve() == Path("outputs").resolve() else f" --out {out}"
        fail(f"error: --replot: no {table}; run `python src/controls.py {control}{where}` first")
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        fail(f"error: --replot: {table} is not JSON ({e})")
    needed = ("control", "preset", "steps", "seeds", "episodes", "heldout", "rows", "verdict")
    if not isinstance(result, dict) or any(k not in result for k in needed) or result["control"] != control:
        fail(f"error: --replot: {table} is not the {control} control's table (a control table has {', '.join(needed)})")
    # the JSON holds a number with no reading as null (strict JSON); the figure code reads it as nan, as in a run
    result["rows"] = [{k: float("nan") if v is None else v for k, v in r.items()} for r in result["rows"]]
    figure = out / "figures" / f"control_{control}.png"
    with tempfile.TemporaryDirectory() as tmp:
        try:
            made = draw_figure(result, Path(tmp) / figure.name)
        except (KeyError, TypeError, IndexError, ValueError, AttributeError) as e:  # JSON, but edited by hand
            fail(f"error: --replot: {table} is not a control table this script wrote ({type(e).__name__}: {e})")
        refuse_to_replace_committed([figure], [made.read_bytes()], overwrite)
        figure.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(made, figure)
    return figure


def main(argv: list[str] | None = None, conf_dir: Path = Path("conf")) -> None:
    """The fixed controls' command line (src/controls.py <control>). Long because it declares one option per line
    and checks each before anything runs."""
    ap = OneLineParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("control", choices=sorted(CONDITIONS))
    ap.add_argument("--preset", default="cpu", help="world_model preset (conf/world_model/<name>.yaml)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="training seeds")
    ap.add_argument("--episodes", type=int, nargs="+", default=[10, 20, 40], help="training episodes per task")
    ap.add_argument("--heldout", type=int, nargs=2, default=[41, 50], help="held-out episodes (1-based, inclusive)")
    protocol = preset(conf_dir, "protocol", "heldout")
    ap.add_argument("--steps", type=int, default=protocol["steps"], help="gradient steps for every run")
    ap.add_argument("--lr", type=float, default=protocol["lr"], help="learning rate for every run")
    ap.add_argument("--context", type=int, default=5)
    ap.add_argument("--horizon", type=int, default=protocol["horizon"])
    ap.add_argument("--mask-margin", type=int, default=protocol["mask_margin"],
                    help="pixels the robot masks are grown by in the object-focused error")
    ap.add_argument("--exclude-robot-from-loss", action=argparse.BooleanOptionalAction,
                    default=protocol["exclude_robot_from_loss"],
                    help="leave the (grown) robot pixels out of the training loss")
    ap.add_argument("--conditions", nargs="+", default=None, help="run only these conditions (all when not given)")
    ap.add_argument("--tasks", type=int, default=4)
    ap.add_argument("--actions", type=int, default=40, help="actions per episode (rows: one more)")
    ap.add_argument("--data-seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("outputs"), help="runs under OUT/controls/<control>/runs, "
                    "checkpoints under OUT/checkpoints/controls, tables and figures under OUT/tables, OUT/figures")
    ap.add_argument("--overwrite", action="store_true",
                    help="replace committed tables/figures that this run would change (refused otherwise)")
    ap.add_argument("--reevaluate", action="store_true",
                    help="evaluate saved runs again from their checkpoints and rewrite their records (for quantities "
                    "added to the evaluation; a run whose checkpoint is gone trains again and says so)")
    ap.add_argument("--replot", action="store_true",
                    help="only draw the figure again from OUT/tables/control_<control>.json (no runs, no episodes)")
    args = ap.parse_args(argv)
    args.conf_dir = conf_dir
    if args.replot:
        print("wrote", replot(args.control, args.out, args.overwrite))
        return
    if max(args.episodes) >= args.heldout[0]:
        fail(f"error: --episodes {max(args.episodes)} would train on held-out episodes from "
                         f"{args.heldout[0]}; use --heldout past it")
    from simeval.measures.dynamics_diversity.table4_heldout import build, write
    from simeval.results import dumps_strict

    records = run_all(args)  # a UserError (e.g. --reevaluate where a checkpoint is gone): one line, exit 2
    wanted = {(c, k, s) for c in CONDITIONS[args.control] for k in args.episodes for s in args.seeds}
    have = {(r["identity"]["task_group"], r["identity"]["episodes"], r["identity"]["seed"]) for r in records}
    if wanted - have:
        print(f"{len(wanted - have)} runs of this control are not done yet (another process?); the table waits")
        return
    records = [r for r in records if (r["identity"]["task_group"], r["identity"]["episodes"], r["identity"]["seed"])
               in wanted]
    rows = build(records)
    dose = DOSES.get(args.control)
    verdict = (dose_verdict(records, CONDITIONS[args.control], primary=dose.metric) if dose is not None
               else verdicts(records, CONDITIONS[args.control]))
    result = {"control": args.control, "preset": args.preset, "steps": args.steps, "lr": args.lr, "seeds": args.seeds,
              "episodes": args.episodes, "heldout": args.heldout, "tasks": args.tasks, "actions": args.actions,
              "exclude_robot_from_loss": args.exclude_robot_from_loss, "verdict": verdict, "rows": rows}
    if dose is not None:
        result.update(task="/".join(dose.task), camera=dose.camera, knob=".".join(dose.knob), levels=dose.levels,
                      moving_share_by_margin=moving_share_by_margin(dose, args.out, tuple(args.heldout)))
        del result["tasks"], result["actions"]
    if args.control == "visual":  # passes when the full frame moves (interval off zero) and the object error far less
        v = result["verdict"]
        full_moves = v["one_step"][f"varied_minus_shared_at_{min(args.episodes)}_interval"][0] > 0
        v["passes"] = {"full_frame_moves": full_moves,
                       "object_moves_under_a_quarter": v["relative_change_at_fewest"]["object_over_full"] < 0.25}
        if "moving_passes" in v:
            v["moving_passes"] = {"moves_under_a_quarter_of_full": v["moving_passes"]["moves_under_a_quarter_of_full"]}
    elif "moving_passes" in result["verdict"]:  # the dynamics control: the quarter rule is the visual one's
        del result["verdict"]["moving_passes"]["moves_under_a_quarter_of_full"]
    stem = args.out / "tables" / f"control_{args.control}"
    figure = args.out / "figures" / f"control_{args.control}.png"
    with tempfile.TemporaryDirectory() as tmp:  # built aside, compared with what is committed, then moved in
        tmp_stem = Path(tmp) / stem.name
        write(rows, tmp_stem)
        tmp_stem.with_suffix(".json").write_text(dumps_strict(result, indent=1) + "\n")
        draw_figure(result, Path(tmp) / figure.name)
        made = [tmp_stem.with_suffix(x) for x in (".csv", ".md", ".json")] + [Path(tmp) / figure.name]
        targets = [stem.with_suffix(x) for x in (".csv", ".md", ".json")] + [figure]
        refuse_to_replace_committed(targets, [m.read_bytes() for m in made], args.overwrite)
        for m, t in zip(made, targets):
            t.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(m, t)
    print(dumps_strict(result["verdict"], indent=1))
    print("wrote", ", ".join(map(str, targets)))
