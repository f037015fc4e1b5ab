"""The validity gate of a dynamics-diversity reading: a learned model's held-out error reads the diversity of a
group's dynamics only where the model has learned more than a predictor that knows nothing of the dynamics. A model
that never learned where a small object is (issue 50: a 2% disk) predicts about as well as the task's mean image on
every group alike, and its error then ranks groups by how much their pixels move, not by how diverse their dynamics
are; so such a run gives "no reading", never a number.

Shapes: for R training seeds and E held-out episodes (strata `tasks` (E,): each episode's task), per-episode sums of
the model's squared error x[r, e] and of each baseline b's on the same frames (and pixels, or state dimensions)
x_b[r, e] (a baseline does not depend on the seed; it is given per run all the same).

    skill_b            1 - sum_{r,e} x[r, e] / sum_{r,e} x_b[r, e]        (> 0: better than b; 0: as good as b)
    its interval       the 95% percentile interval over resamples of seeds and, within each task, held-out
                       episodes (simeval.stats.resample.draws; the same draws for every baseline)
    passes             for every baseline b: skill_b >= margin and the interval's lower end > 0
    per task           skill_b >= margin on that task's episodes alone (its interval is reported, not required: a
                       task's 10 held-out episodes give intervals as wide for a model that learned as for one
                       that did not); the group's reading needs the group to pass and at
                       least `min_task_share` of its tasks to pass (default: every task: a group whose reading
                       mixes learned and unlearned tasks averages numbers that mean different things); `exempt`
                       tasks are checked and shown but not required (the state reading's tasks whose read values
                       barely move: a model cannot beat an exact last state, and there is nothing to learn there)

Verdict text (`verdict`): "reads" or "no reading: the model does not beat <baseline> (skill <s> [<lo>, <hi>])[ nor
<baseline> (...)]; needs >= <margin>"; with tasks failing, "no reading: the model does not beat <baseline> on k of
n tasks (<task>, ...)". Baseline names are the human ones of BASELINE_NAMES.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simeval.errors import UserError, require_whole_fields, settings_from_dict
from simeval.measures.dynamics_diversity.prediction import MIN_MOVING_PIXELS
from simeval.stats import resample

BASELINE_NAMES = {"last": "the last frame", "mean": "the mean image", "last_state": "the last state",
                  "mean_state": "the mean state", "constant_velocity": "constant velocity"}


@dataclass(frozen=True)
class GateConfig:
    margin: float = 0.05  # the least skill against every baseline: the model's error at most 95% of each one's
    min_task_share: float = 1.0  # the share of a group's tasks that must pass for the group to read
    n_boot: int = 1000
    seed: int = 0

    def __post_init__(self) -> None:
        for key in ("margin", "min_task_share"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise UserError(f"protocol.gate.{key}={v!r}: expected a number")
        require_whole_fields(self, "protocol.gate", ("seed",), low=0)
        require_whole_fields(self, "protocol.gate", ("n_boot",), low=100)  # fewer resamples: a coarse interval
        if not 0 <= self.margin < 1:
            raise UserError(f"protocol.gate.margin={self.margin}: expected a skill in [0, 1) (0.05: 5% better than "
                            "each baseline)")
        if not 0 < self.min_task_share <= 1:
            raise UserError(f"protocol.gate.min_task_share={self.min_task_share}: expected a share in (0, 1]")

    @classmethod
    def from_dict(cls, d: dict | None) -> GateConfig:
        return settings_from_dict(cls, d, "protocol.gate")


def _skill(x: np.ndarray, xb: np.ndarray, draws) -> tuple[float, list[float]]:
    """1 - sum x / sum x_b and its interval: resample's ratio of sums, with the baseline's error as the denominator."""
    return 1 - resample.ratio(x, xb), resample.percentile(1 - resample.replicates(x, xb, draws))


def _check(x: np.ndarray, bases: dict[str, np.ndarray], strata, cfg: GateConfig, interval: bool = True) -> dict:
    draws = resample.draws(x.shape[0], strata, cfg.n_boot, cfg.seed)
    out, failed = {}, []
    for name, xb in bases.items():
        point, (lo, hi) = _skill(x, xb, draws)
        ok = bool(np.isfinite(point) and point >= cfg.margin and (not interval or (np.isfinite(lo) and lo > 0)))
        out[name] = {"skill": point, "interval": [lo, hi], "passes": ok}
        if not ok:
            failed.append(name)
    return {"baselines": out, "passes": not failed, "failed": failed}


def _fmt(v: float) -> str:
    return f"{v:.3f}" if np.isfinite(v) else "n/a"


def gate(model: np.ndarray, baselines: dict[str, np.ndarray], tasks, cfg: GateConfig = GateConfig(),
         exempt: tuple[str, ...] = ()) -> dict:
    """The gate of one reading (see the module docstring): `model` (R, E) and each of `baselines` {name: (R, E)}
    summed squared errors, `tasks` (E,); `exempt` tasks are checked and reported but not required to pass (the
    state reading's tasks whose read values do not move: nothing to predict there). Returns {passes, verdict, margin,
    baselines: {name: {skill, interval, passes}}, per_task: {task: {passes, failed, baselines}}, tasks_passing,
    tasks, exempt}."""
    x = np.atleast_2d(np.asarray(model, float))
    bases = {k: np.atleast_2d(np.asarray(v, float)) for k, v in baselines.items()}
    tasks = np.asarray(tasks)
    if not bases:
        raise ValueError("gate: no baselines")
    for k, v in bases.items():
        if v.shape != x.shape:
            raise ValueError(f"gate: baseline {k} has shape {v.shape}, the model's {x.shape}")
    if tasks.shape != (x.shape[1],):
        raise ValueError(f"gate: {len(tasks)} task labels for {x.shape[1]} episodes")
    group = _check(x, bases, tasks, cfg)
    per_task = {}
    for t in sorted(set(tasks.tolist())):
        cols = tasks == t
        per_task[str(t)] = _check(x[:, cols], {k: v[:, cols] for k, v in bases.items()}, tasks[cols], cfg,
                                  interval=False)
    required = {t: r for t, r in per_task.items() if t not in exempt}
    passing = sum(r["passes"] for r in required.values())
    enough = passing >= cfg.min_task_share * len(required) - 1e-9
    if not group["passes"]:
        parts = []
        for b in group["failed"]:
            s = group["baselines"][b]
            parts.append(f"{BASELINE_NAMES.get(b, b)} (skill {_fmt(s['skill'])} [{_fmt(s['interval'][0])}, "
                         f"{_fmt(s['interval'][1])}])")
        verdict = f"no reading: the model does not beat {' nor '.join(parts)}; needs >= {cfg.margin:g}"
    elif not enough:
        bad = [t for t, r in required.items() if not r["passes"]]
        worst = {}
        for t in bad:
            for b in per_task[t]["failed"]:
                worst[b] = worst.get(b, 0) + 1
        b = max(worst, key=worst.get)
        verdict = (f"no reading: the model does not beat {BASELINE_NAMES.get(b, b)} on {len(bad)} of "
                   f"{len(required)} tasks ({', '.join(bad[:3])}{', ...' if len(bad) > 3 else ''})")
    else:
        verdict = "reads"
    return {"passes": bool(group["passes"] and enough), "verdict": verdict, "margin": cfg.margin,
            "min_task_share": cfg.min_task_share, "baselines": group["baselines"], "per_task": per_task,
            "tasks_passing": int(passing), "tasks": len(required), "exempt": sorted(set(exempt) & set(per_task))}


PIXEL_SUMS = {"model": "one_step/model/object", "last": "one_step/last/object", "mean": "one_step/mean/object"}


# the held-out frames' moving kept pixels, summed over runs and episodes (records made before they were summed lack it)
MOVING_PIXELS = "one_step/moving_pixels"


def pixel_gate(per_episode_runs: list[list[dict]], cfg: GateConfig = GateConfig()) -> dict:
    """The gate of the pixel reading on the protocol's primary number (the object-focused one-step error: robot
    pixels out where the episodes carry masks) from R runs' `per_episode` lists
    (simeval.measures.dynamics_diversity.prediction; every run on the same held-out episodes)."""
    order = sorted((e["task"], int(e["seed"])) for e in per_episode_runs[0])
    keys = {**PIXEL_SUMS, **({"moving": MOVING_PIXELS} if all(MOVING_PIXELS in e["sums"] for run in per_episode_runs
                                                              for e in run) else {})}
    arrays = {k: np.zeros((len(per_episode_runs), len(order))) for k in keys}
    for r, run in enumerate(per_episode_runs):
        where = {(e["task"], int(e["seed"])): e["sums"] for e in run}
        if sorted(where) != order:
            raise UserError("gate: the runs of one reading were evaluated on different held-out episodes")
        for j, ep in enumerate(order):
            for k, key in keys.items():
                arrays[k][r, j] = where[ep][key]
    return gate_of_sums(arrays, [t for t, _ in order], cfg)


def gate_of_sums(sums: dict[str, np.ndarray], tasks, cfg: GateConfig = GateConfig()) -> dict:
    """The pixel gate of per-episode sums {model, last, mean: (R, E); moving: (R, E) moving kept pixels, optional},
    as the run (pixel_gate) and the held-out table read it. A failed gate where under MIN_MOVING_PIXELS kept pixels
    moved says that, not the skill against the last frame it would quote: that skill is undefined there (the table
    shows '—'; a fresh-clone trial's tiny run quoted "skill -7282" beside it)."""
    g = gate(sums["model"], {"last": sums["last"], "mean": sums["mean"]}, tasks, cfg)
    if not g["passes"] and "moving" in sums and np.sum(sums["moving"]) < MIN_MOVING_PIXELS:
        g["verdict"] = (f"no reading: under {MIN_MOVING_PIXELS} kept pixels moved (the last frame is a near-exact "
                        "copy; no skill against it is defined)")
    return g


OPPOSITE = "no reading: the fall and its excess over a baseline's own change point opposite ways"
TOO_WIDE = "no reading: too wide"


def fall_verdict(model_fall: tuple[float, float, float], relative_fall: dict[str, tuple[float, float]],
                 gates: dict[int, dict], first_error: float, margin: float = GateConfig.margin) -> str:
    """Whether a fall of the error from the fewest to the most training episodes is read: `model_fall` (point, lo,
    hi) of error_first - error_last; `relative_fall` {baseline: (lo, hi)} the interval of the fall of the model's
    relative error against that baseline (error / baseline error) as a share of it at the fewest episodes,
    1 - relative_last / relative_first, on the same resamples (relative_fall_interval): a fall beyond what the
    baseline's own change gives, in the unit of the margin (the mean image or mean state changes with the training
    episodes, a copy of the last frame or state does not: against it, the share is the fall's own);
    `gates` {count: gate} of each count; `first_error` the model's error at the fewest.

        "no reading: ... at k episodes"   a count is gated
        "no fall"                         the fall's interval lies within +-margin * first_error (read first)
        "falls" / "rises"                 the fall's interval and every relative fall's exclude zero on the same side
        "no fall"                         one baseline's relative fall within +-margin: no change beyond that
                                          baseline's own, to within the gate's margin
        OPPOSITE                          every interval excludes zero, the fall's and a relative error's on
                                          opposite sides: the error falls as a baseline's own falls more
        TOO_WIDE ...                      otherwise: an interval that contains zero and reaches past the margin
                                          cannot tell a fall from none (as the random controls' "too wide")

    Why relative errors and not differences of errors: a baseline far worse than the model (a mean state with 40x
    its error) changes by more than the model's whole error when the training episodes change its mean, so a
    difference of falls would call any fall of a good model "no fall"; the relative error compares the two at their
    own scales. Why its share and not the skill's rise (1 - relative error, lo -> hi; until 2026-12-07): against a
    baseline 1,000x the model's error (the mean state) the skill is 0.999 at every count and its rise never reaches
    the margin, so any fall that did not read "falls" read "no fall" (GenSim's own assembling, a state fall of 8%
    [1%, 15%] of its error); the share is that of the error at the fewest episodes, as the margin on the fall."""
    if len(gates) < 2 or any("passes" not in g for g in gates.values()):  # a caller's fault, said as such
        raise ValueError(f"fall_verdict: a fall needs the gate (with its 'passes') of two counts or more, got "
                         f"{ {k: sorted(g) for k, g in gates.items()} }")
    for k in sorted(gates):
        if not gates[k]["passes"]:
            return f"{gates[k]['verdict']} at {k} episodes"
    _, lo, hi = model_fall
    relative = list(relative_fall.values())
    bound = margin * abs(first_error)
    # the margin first: a change whose whole interval lies within it is no change to read, whichever its sign, as
    # the gate's margin makes a model that beats a baseline by less than it no reading (GenSim-style stacking's state
    # error rose 2.4% [0.7%, 4.2%] from 10 to 40 episodes: "rises" before this order, a confident reading of nothing)
    if -bound <= lo and hi <= bound:
        return "no fall"
    if lo > 0 and all(a > 0 for a, _ in relative):
        return "falls"
    if hi < 0 and all(b < 0 for _, b in relative):
        return "rises"
    if any(-margin <= a and b <= margin for a, b in relative):
        return "no fall"
    if (lo > 0 or hi < 0) and all(a > 0 or b < 0 for a, b in relative):  # every interval excludes 0, not on one side
        return (f"{OPPOSITE} (the fall's interval [{lo:+.3g}, {hi:+.3g}]; the relative error's against each "
                "baseline: " + ", ".join(f"[{a:+.3g}, {b:+.3g}]" for a, b in relative) + ")")
    # which interval it is: the fall's own may exclude 0 while a baseline's own change explains it (the mean
    # state's: GenSim's own assembling, a fall of 8% [1%, 15%] of its error)
    wide = ([f"the fall's interval [{lo:+.3g}, {hi:+.3g}] contains 0 and reaches past +-{margin:g} of the error at "
             f"{min(gates)} episodes, {bound:.3g}"] if lo <= 0 <= hi else [])
    wide += [f"its relative fall against the {name.replace('_', ' ')} [{a:+.3g}, {b:+.3g}] contains 0 and reaches "
             f"past +-{margin:g}" for name, (a, b) in relative_fall.items() if a <= 0 <= b]
    if lo > 0 or hi < 0:
        wide.append(f"the fall's interval [{lo:+.3g}, {hi:+.3g}] excludes 0")
    return f"{TOO_WIDE} ({'; '.join(wide)})"


def relative_fall_interval(model_first: np.ndarray, base_first: np.ndarray, model_last: np.ndarray,
                           base_last: np.ndarray, level: float = 0.95) -> tuple[float, float]:
    """The interval of 1 - (model_last / base_last) / (model_first / base_first) over paired resamples (each
    array (B,): the same draws at both counts): the fall of the model's error relative to a baseline's, as a share
    of it at the fewest episodes (fall_verdict's `relative_fall`)."""
    share = 1 - (model_last / base_last) / (model_first / base_first)
    return resample.percentile(share, level=level)


def relative_error(model: np.ndarray, baseline: np.ndarray) -> float:
    """sum model / sum baseline (R, E) each: the share of a physics-free predictor's error the model leaves (1 -
    skill); a unit-free reading that two groups whose objects move by different amounts can compare."""
    return resample.ratio(np.atleast_2d(model), np.atleast_2d(baseline))


def order_between_groups(a: tuple, b: tuple, n_boot: int = 2000, seed: int = 0, level: float = 0.95,
                         paired: bool = False) -> dict:
    """Whether group a reads as more diverse than group b: each group `(model (R, E), baseline (R, E), tasks
    (E,))` gives relative_error; the difference a - b with a percentile interval over resamples of seeds and, within
    task, episodes (simeval.stats.resample). `paired`: episode e of a and of b share their start and actions (the
    same position in each group's task order), so both draw the same episodes (resample.paired_draws); otherwise the
    two groups' episodes are drawn independently. {difference, interval, order}: order "a > b" / "a < b" where the
    interval excludes zero, else "none"."""
    groups = [(np.atleast_2d(np.asarray(x, float)), np.atleast_2d(np.asarray(xb, float)), list(tasks))
              for x, xb, tasks in (a, b)]
    points = [relative_error(x, xb) for x, xb, _ in groups]
    if paired:
        positions = [np.unique(tasks, return_inverse=True)[1] for _, _, tasks in groups]
        if len(positions[0]) != len(positions[1]) or not np.array_equal(*positions):
            raise ValueError("paired groups must hold the same number of episodes per task, in the same order")
        resamples = resample.paired_draws(groups[0][0].shape[0], groups[1][0].shape[0], positions[0], n_boot, seed)
    else:
        resamples = [resample.draws(x.shape[0], tasks, n_boot, seed + 7919 * k)
                     for k, (x, _, tasks) in enumerate(groups)]
    reps = [resample.replicates(x, xb, r) for (x, xb, _), r in zip(groups, resamples)]
    diff = points[0] - points[1]
    lo, hi = resample.percentile(reps[0] - reps[1], level)
    order = "a > b" if lo > 0 else "a < b" if hi < 0 else "none"
    return {"difference": diff, "interval": [lo, hi], "order": order, "relative_errors": points}
