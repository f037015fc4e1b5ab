"""Table 4 under the heldout protocol: per (pipeline, group, preset, steps) and training-episode count, the world
model's prediction errors on held-out episodes beside the baselines, with 95% intervals over training seeds and
held-out episodes (simeval.stats.resample), from dynamics_diversity result.json records of protocol=heldout.

Per cell (the runs of one count: one per training seed, all evaluated on the same held-out episodes), from the
per-episode sums of simeval.measures.dynamics_diversity.prediction, with x[r, e] summed squared errors and n[r, e]
frames, for each kind of prediction K (one_step: o_t predicted from o_{<t} and the actions; open_loop: frames imagined
from the actions after the context; reconstruction: the paper's quantity, here on held-out frames):
    K                   sum x_model / sum n
    K_last, K_mean      the baselines on the same frames: copy the last observed frame; the task's mean training image
    K_skill_last        1 - K / K_last;  K_skill_mean  1 - K / K_mean   (< 0: worse than the baseline)
    K_object, K_object_last, K_object_skill_last   the same per kept (non-robot) pixel and channel; the skill vs
                        the last frame only where K_moving has a reading: with (nearly) nothing moving outside the
                        robot the copy is exact up to 8-bit noise and the ratio divides by ~0 (it read -13,823)
    K_moving, K_moving_last, K_moving_skill_last   the same per moving kept pixel and channel (one step and open loop:
                        kept pixels whose colour changed from the reference frame); K_moving_share = moving / kept
and per row the fall from the first to the last count of one_step_object, one_step, open_loop and one_step_moving
(`drop_K`) on paired resamples (the same seeds' indices and held-out episodes for both counts).

The primary number (PRIMARY) is the object-focused one-step error: the protocol leaves the robot's pixels out of
the training loss (protocol.exclude_robot_from_loss), so where episodes carry robot masks the full-frame error scores
pixels the model never learned; without masks the two are the same frames (per pixel vs summed).

    rows = build(read_results(root, "dynamics_diversity"))
    write(rows, "outputs/tables/table4_heldout")      # .csv (every number), .md
    rows = merge(read_rows("outputs/tables/table4_heldout.csv"), rows)   # keep the rows run on other machines
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from simeval.errors import UserError
from simeval.stats import resample
from simeval.measures.dynamics_diversity.gate import (MOVING_PIXELS, OPPOSITE, PIXEL_SUMS, TOO_WIDE, GateConfig,
                                                      fall_verdict, gate_of_sums, relative_fall_interval)
from simeval.measures.dynamics_diversity.prediction import MIN_MOVING_PIXELS
from simeval.measures.dynamics_diversity.table4 import one_setting
from simeval.writing.tables import read_csv, to_csv, to_markdown
from simeval.results import atomic_write_text

METRIC = "dynamics_diversity"
PRIMARY = "one_step_object"
BASELINES = {"one_step": ("last", "mean"), "open_loop": ("last", "mean"), "reconstruction": ("mean",)}
# name -> (numerator sum key, denominator sum key, scale of the denominator)
RATIOS = {}
SKILLS = {}  # name -> (model ratio, baseline ratio)
for _kind, _bases in BASELINES.items():
    for _who in ("model", *_bases):
        _suffix = "" if _who == "model" else f"_{_who}"
        RATIOS[f"{_kind}{_suffix}"] = (f"{_kind}/{_who}/full", f"{_kind}/frames", 1)
        RATIOS[f"{_kind}_object{_suffix}"] = (f"{_kind}/{_who}/object", f"{_kind}/kept_pixels", 3)
    for _base in _bases:
        SKILLS[f"{_kind}_skill_{_base}"] = (_kind, f"{_kind}_{_base}")
        SKILLS[f"{_kind}_object_skill_{_base}"] = (f"{_kind}_object", f"{_kind}_object_{_base}")
    if _kind != "reconstruction":  # kept pixels whose colour changed from the reference (prediction's docstring)
        RATIOS[f"{_kind}_moving_share"] = (f"{_kind}/moving_pixels", f"{_kind}/kept_pixels", 1)
        for _who in ("model", *_bases):
            _suffix = "" if _who == "model" else f"_{_who}"
            RATIOS[f"{_kind}_moving{_suffix}"] = (f"{_kind}/{_who}/moving", f"{_kind}/moving_pixels", 3)
        for _base in _bases:
            SKILLS[f"{_kind}_moving_skill_{_base}"] = (f"{_kind}_moving", f"{_kind}_moving_{_base}")


def sum_arrays(recs: list[dict]) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """({sum key: (R, E)}, tasks (E,)) from the per-episode sums of R runs; every run must have evaluated the same
    held-out episodes (a UserError names the difference)."""
    def episodes(rec):
        return [(e["task"], int(e["seed"])) for e in rec["values"]["prediction"]["per_episode"]]

    order = sorted(episodes(recs[0]))
    for rec in recs[1:]:
        if sorted(episodes(rec)) != order:
            raise UserError(f"{rec.get('path', 'a run')}: evaluated other held-out episodes than "
                            f"{recs[0].get('path', 'the first run')}; a cell compares runs on the same episodes")
    # the sums every run has: records written before a sum existed (the moving pixels) leave its ratios out
    keys = set.intersection(*(set(rec["values"]["prediction"]["per_episode"][0]["sums"]) for rec in recs))
    out = {k: np.zeros((len(recs), len(order))) for k in keys}
    for r, rec in enumerate(recs):
        where = {(e["task"], int(e["seed"])): e["sums"] for e in rec["values"]["prediction"]["per_episode"]}
        for j, ep in enumerate(order):
            for k in keys:
                out[k][r, j] = where[ep][k]
    return out, np.array([t for t, _ in order])


def gated_by_motion(name: str) -> bool:
    """Whether a ratio needs MIN_MOVING_PIXELS moving pixels to be read (NaN where fewer), so its interval is drawn
    only where nearly every resample had them."""
    return "_moving" in name or name.endswith("_object_skill_last")


def max_missing(name: str) -> float:
    """The share of NaN resamples `resample.percentile` accepts for `name`."""
    return 0.05 if gated_by_motion(name) else 1.0


def cell_replicates(sums: dict[str, np.ndarray], draws) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """Point values and bootstrap replicates (on `draws`) of every RATIOS and SKILLS entry of one cell (a moving
    ratio is NaN where fewer than MIN_MOVING_PIXELS pixels moved, in the cell or in a resample)."""
    point, reps = {}, {}
    for name, (num, den, scale) in RATIOS.items():
        if num not in sums or den not in sums:
            continue
        x, n = sums[num], sums[den] * scale
        least = MIN_MOVING_PIXELS * scale if den.endswith("/moving_pixels") else 0.0
        point[name] = resample.ratio(x, n, min_total=least)
        reps[name] = resample.replicates(x, n, draws, min_total=least)
    with np.errstate(invalid="ignore", divide="ignore"):
        for name, (model, base) in SKILLS.items():
            if model not in point or base not in point:
                continue
            point[name] = 1 - point[model] / point[base] if point[base] else float("nan")
            reps[name] = 1 - reps[model] / reps[base]
        for kind in ("one_step", "open_loop"):  # the object skill vs a copy needs something to have moved
            name, moving = f"{kind}_object_skill_last", f"{kind}_moving"
            if name in point and moving in point:
                point[name] = point[name] if np.isfinite(point[moving]) else float("nan")
                reps[name] = np.where(np.isfinite(reps[moving]), reps[name], np.nan)
    return point, reps


N_BOOT = 2000  # the table's bootstrap draws, shared by every count of a row (paired falls)


def build(records: list[dict], *, n_boot: int = N_BOOT, seed: int = 0,
          gate_cfg: GateConfig = GateConfig()) -> list[dict]:
    """One row per (pipeline, group, preset, steps) with runs of protocol=heldout (see the module docstring). Runs
    of one seed found twice (a sweep run again: it resumes and evaluates again) count once, the newest."""
    rows = []
    for (p, g, pr, steps), cell in sorted(_cells(records).items(), key=lambda kv: tuple(map(str, kv[0]))):
        by_k = {k: runs for k, (runs, _) in cell.items()}
        states = {k: state for k, (_, state) in cell.items()}
        counts = sorted(by_k)
        one_setting((p, g, pr), [r for k in counts for r in by_k[k] if "settings" in r["identity"]])
        row = {"pipeline": p, "group": g, "preset": pr, "steps": steps, "counts": "/".join(map(str, counts))}
        reps_by_k, gates = {}, {}
        for k in counts:
            reps_by_k[k], gates[k] = _count_columns(row, k, by_k[k], n_boot=n_boot, seed=seed, gate_cfg=gate_cfg)
            if states[k] is not by_k[k][0]:  # a states-only sweep read the state after the pixel runs
                _state_columns(row, k, states[k]["values"].get("state"))
                row["state_runs"] = STATE_BESIDE_PIXELS
        lo, hi = counts[0], counts[-1]
        if lo != hi and row[f"runs_{lo}"] == row[f"runs_{hi}"] and \
                row[f"heldout_episodes_{lo}"] == row[f"heldout_episodes_{hi}"]:
            if reps_by_k[lo] is not None and reps_by_k[hi] is not None:
                _fall_columns(row, lo, hi, reps_by_k, gates, gate_cfg.margin)
            row.update(state_fall(states[lo]["values"].get("state"), states[hi]["values"].get("state"), lo, hi,
                                  n_boot, seed, gate_cfg))
        rows.append(row)
    return rows


def _cells(records: list[dict]) -> dict:
    """{(pipeline, group, preset, steps): {episodes: ([one record per seed], the record whose state reading the
    count shows)}} from the held-out runs that ended ok. Runs with pixels carry the same state reading as a
    states-only sweep of the group (tested): where a count has both, its runs with pixels make the row, and its
    state reading is theirs unless the newest states-only run is newer (_newer_state)."""
    cells: dict = defaultdict(lambda: defaultdict(list))
    for rec in records:
        ident = rec.get("identity") or {}
        if rec.get("metric") != METRIC or rec.get("status") != "ok" or ident.get("protocol") != "heldout":
            continue
        cells[(ident["pipeline"], ident["task_group"], ident["preset"], ident.get("steps"))][
            int(ident["episodes"])].append(rec)
    out = {}
    for key, by_k in cells.items():
        out[key] = {}
        for k, recs in by_k.items():
            recs = sorted(recs, key=lambda r: str(r.get("created", "")))
            pixels = [r for r in recs if r["values"].get("prediction") is not None]
            newest = {}  # one run per seed: a sweep rerun after a kill writes the same runs again
            for rec in pixels or recs:
                newest[int(rec["identity"].get("seed", 0))] = rec
            runs = list(newest.values())
            state = runs[0]
            states_only = [r for r in recs if r["values"].get("prediction") is None]
            if pixels and states_only and _newer_state(states_only[-1], runs):
                state = states_only[-1]
            out[key][k] = (runs, state)
    return out


def _state_version(rec: dict) -> int:
    return int(((rec["values"].get("state") or {}).get("version")) or 0)


def _newer_state(states_only: dict, pixel_runs: list[dict]) -> bool:
    """Whether a states-only run's reading replaces the pixel runs' own: a newer version of the reading, or the
    same version read after them (the episodes collected again with more of the state recorded, as the moving links
    of articulated objects were; the same episodes read again give the same numbers)."""
    newest = max(str(r.get("created", "")) for r in pixel_runs)
    return (_state_version(states_only), str(states_only.get("created", ""))) > (
        max(_state_version(r) for r in pixel_runs), newest)


def _count_columns(row: dict, k: int, recs: list[dict], *, n_boot: int, seed: int,
                   gate_cfg: GateConfig) -> tuple[dict | None, dict | None]:
    """One episode count's columns, added to `row`; returns its resampled replicates and its pixel gate (None, None
    for runs of the state reading only, protocol.pixels=false)."""
    recs = sorted(recs, key=lambda r: int(r["identity"].get("seed", 0)))
    if any(r["values"].get("prediction") is None for r in recs):
        state = recs[0]["values"].get("state") or {}
        row[f"runs_{k}"] = len(state.get("seeds") or recs)  # its own training seeds; the run's seed trains nothing
        row[f"heldout_episodes_{k}"] = len(state.get("per_episode") or [])
        row["state_runs"] = STATE_ONLY
        _state_columns(row, k, state)
        return None, None
    sums, tasks = sum_arrays(recs)
    draws = resample.draws(len(recs), tasks, n_boot, seed)  # the same draws for every count: paired
    point, reps = cell_replicates(sums, draws)
    row[f"runs_{k}"] = len(recs)
    row[f"heldout_episodes_{k}"] = len(tasks)
    row[f"robot_mask_{k}"] = all(r["values"]["prediction"].get("robot_mask") for r in recs)
    g = gate_of_sums({**{k: sums[key] for k, key in PIXEL_SUMS.items()},
                      **({"moving": sums[MOVING_PIXELS]} if MOVING_PIXELS in sums else {})}, tasks, gate_cfg)
    row[f"gate_{k}"], row[f"gate_passes_{k}"] = g["verdict"], g["passes"]
    _state_columns(row, k, recs[0]["values"].get("state"))  # the same in every seed's run (its own seeds inside)
    for name, v in point.items():
        row[f"{name}_{k}"] = v
        # a moving ratio's interval only where nearly every resample had enough moving pixels to read
        row[f"{name}_{k}_lo"], row[f"{name}_{k}_hi"] = resample.percentile(
            reps[name], max_missing=max_missing(name))
    return reps, g


def _state_columns(row: dict, k: int, state: dict | None) -> None:
    """A count's state reading: what it reads (state_reads_<k>: "objects", or "state" for the whole; "state
    (version 4)" for runs made before version 5 read the objects' poses apart), its gate and numbers; where it read
    the objects, the robot's and the whole state's errors, skills and gates beside (state_robot_*, state_whole_*)."""
    if state and state.get("gate"):
        row[f"state_reads_{k}"] = state.get("reads", "state (version 4)")
        settings = _settings(state)
        if settings:  # read with another setting than the protocol's: the cell says so
            row[f"state_inputs_{k}"] = settings
        row[f"state_gate_{k}"] = state["gate"]["verdict"]
        row[f"state_gate_passes_{k}"] = state["gate"]["passes"]
        for key, v in state["summary"].items():
            row[f"state_{key}_{k}"] = v
        for name, beside in (("robot", (state.get("parts") or {}).get("robot")), ("whole", state.get("whole_state"))):
            if beside and "summary" in beside:
                row[f"state_{name}_gate_passes_{k}"] = beside["gate"]["passes"]
                for key in ("model", "last_state", "skill_vs_last_state", "skill_vs_mean_state"):
                    row[f"state_{name}_{key}_{k}"] = beside["summary"][key]


def _settings(state: dict) -> str:
    """The state model's settings a reading was made with where they are not the protocol's (target_scale and
    input_scale other than "change": versions 1-6's loss or inputs), e.g. "input_scale=state"; "" otherwise."""
    return ", ".join(f"{key}={state[key]}" for key in ("target_scale", "input_scale")
                     if state.get(key, "change") != "change")


def has_pixels(row: dict) -> bool:
    """Whether a row holds a pixel reading (runs of protocol.pixels=false hold the state reading only)."""
    return any(c.startswith(("gate_", "one_step_object_")) for c in row)


def _fall_columns(row: dict, lo: int, hi: int, reps_by_k: dict, gates: dict, margin: float) -> None:
    """The pixel errors' falls lo -> hi (paired resamples) and the primary number's fall verdict, added to `row`."""
    for kind in ("one_step_object", "one_step", "open_loop", "one_step_moving"):
        if kind not in reps_by_k[lo] or kind not in reps_by_k[hi]:  # runs recorded before it was summed
            continue
        row[f"drop_{kind}"] = row[f"{kind}_{lo}"] - row[f"{kind}_{hi}"]
        row[f"drop_{kind}_lo"], row[f"drop_{kind}_hi"] = resample.percentile(
            reps_by_k[lo][kind] - reps_by_k[hi][kind], max_missing=max_missing(kind))
    # the primary number's fall, read only where both counts pass the gate and its error relative to each
    # baseline falls on the same resamples (the mean image changes with the training episodes)
    relative = {b: relative_fall_interval(reps_by_k[lo][PRIMARY], reps_by_k[lo][f"{PRIMARY}_{b}"],
                                          reps_by_k[hi][PRIMARY], reps_by_k[hi][f"{PRIMARY}_{b}"])
                for b in ("last", "mean")}
    row["fall_verdict"] = fall_verdict((row[f"drop_{PRIMARY}"], row[f"drop_{PRIMARY}_lo"],
                                        row[f"drop_{PRIMARY}_hi"]), relative, {k: gates[k] for k in (lo, hi)},
                                       row[f"{PRIMARY}_{lo}"], margin)


def _state_sums(state: dict) -> tuple[list, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """(episode keys, model (R, E), frames (R, E), {baseline: (R, E)}) of a state reading's per-episode sums."""
    rows = sorted(state["per_episode"], key=lambda r: (r["task"], int(r["index"])))
    n_seeds = len(rows[0]["model"])
    model = np.array([[r["model"][s] for r in rows] for s in range(n_seeds)], float)
    frames = np.tile([float(r["frames"]) for r in rows], (n_seeds, 1))
    bases = {b: np.tile([float(r[b]) for r in rows], (n_seeds, 1)) for b in ("last_state", "mean_state")}
    return [(r["task"], int(r["index"])) for r in rows], model, frames, bases


def state_fall(first: dict | None, last: dict | None, lo: int, hi: int, n_boot: int = 2000, seed: int = 0,
               gate_cfg: GateConfig = GateConfig()) -> dict:
    """The state reading's fall from `lo` to `hi` training episodes, read as the pixels' (fall_verdict): the
    one-step state error per step, resampled over the state model's seeds and, within task, the held-out episodes,
    the same draws at both counts (the same episodes); its error's fall relative to the last state (which does not
    train) and the task mean state, as a share (gate.relative_fall_interval). {} where either count has no state
    reading or they scored other episodes."""
    if not first or not last or not first.get("per_episode") or not last.get("per_episode"):
        return {}
    versions = {k: (state.get("version") or 0, state.get("reads", "state"), _settings(state))
                for k, state in ((lo, first), (hi, last))}
    if versions[lo] != versions[hi]:  # an objects' error against a whole state's: no fall of anything
        return {"state_fall_verdict": MIXED_VERSIONS + ", ".join(
            f"{k}: version {v or '< 4'}, {reads}" + (f", {settings}" if settings else "")
            for k, (v, reads, settings) in versions.items()) + ")"}
    dims = {k: (state.get("dims"), state.get("read_dims")) for k, state in ((lo, first), (hi, last))}
    if dims[lo] != dims[hi]:  # one count of episodes recorded with more of the state (moving links) than the other
        return {"state_fall_verdict": MIXED_LAYOUTS + ", ".join(
            f"{k}: {read} of {whole} values" for k, (whole, read) in dims.items()) + ")"}
    (keys_a, model_a, frames_a, bases_a), (keys_b, model_b, frames_b, bases_b) = _state_sums(first), _state_sums(last)
    if keys_a != keys_b or model_a.shape != model_b.shape:
        return {}
    draws = resample.draws(model_a.shape[0], [t for t, _ in keys_a], n_boot, seed)
    error = {k: resample.replicates(m, f, draws) for k, m, f in ((lo, model_a, frames_a), (hi, model_b, frames_b))}
    fall = error[lo] - error[hi]
    relative = {b: relative_fall_interval(error[lo], resample.replicates(bases_a[b], frames_a, draws),
                                          error[hi], resample.replicates(bases_b[b], frames_b, draws))
                for b in ("last_state", "mean_state")}
    point = resample.ratio(model_a, frames_a) - resample.ratio(model_b, frames_b)
    lo_hi = resample.percentile(fall)
    gates = {k: state["gate"] for k, state in ((lo, first), (hi, last))}
    verdict = fall_verdict((point, *lo_hi), relative, gates, resample.ratio(model_a, frames_a), gate_cfg.margin)
    return {"state_drop": point, "state_drop_lo": lo_hi[0], "state_drop_hi": lo_hi[1],
            "state_fall_verdict": verdict}


ROW_KEY = ("pipeline", "group", "preset", "steps")
REQUIRED_COLUMNS = ("pipeline", "group", "preset", "counts")
# state_runs: where a row's state reading came from, on rows of protocol.pixels=false runs
STATE_ONLY = "runs of the state reading only (protocol.pixels=false)"
STATE_BESIDE_KEPT = ("runs of the state reading only (protocol.pixels=false), beside the kept row's pixel reading "
                     "(as many held-out episodes per count; its runs may be of episodes collected apart)")
STATE_BESIDE_PIXELS = ("runs of the state reading only (protocol.pixels=false), newer than the row's runs with pixels "
                       "(a newer version of the reading, or the same read after them; as many held-out episodes per "
                       "count)")
# fall_verdict: rows written before the gate have none; state_fall_verdict: rows without a state reading
TEXT_COLUMNS = (*REQUIRED_COLUMNS, "fall_verdict", "state_fall_verdict", "state_runs")


def is_text(column: str) -> bool:
    return (column in TEXT_COLUMNS or column.startswith(("gate_", "state_gate_")) and "_passes_" not in column
            or column.startswith(("state_reads_", "state_inputs_")))


def is_flag(column: str) -> bool:
    return column.startswith(("robot_mask_", "gate_passes_", "state_gate_passes_")) or (
        column.startswith(("state_robot_gate_passes_", "state_whole_gate_passes_")))


def row_gate(row: dict, k: int, margin: float = GateConfig.margin) -> tuple[bool, str]:
    """The gate of a count of a row: its own (`gate_<k>`, from the runs' per-episode sums) or, for a kept row
    written before the gate, the group's gate from the row's skills and their intervals (no per-task check); a row
    without a pixel reading (protocol.pixels=false) says so."""
    if f"gate_{k}" in row:
        return bool(row[f"gate_passes_{k}"]), row[f"gate_{k}"]
    if not has_pixels(row):
        return False, "not read (protocol.pixels=false)"
    failed = []
    for b, name in (("last", "the last frame"), ("mean", "the mean image")):
        v, lo = row.get(f"one_step_object_skill_{b}_{k}"), row.get(f"one_step_object_skill_{b}_{k}_lo")
        if v is None or not np.isfinite(v) or v < margin or lo is None or not np.isfinite(lo) or lo <= 0:
            failed.append(f"{name} (skill {v:.2f})" if v is not None and np.isfinite(v) else name)
    if failed:
        return False, f"no reading: the model does not beat {' nor '.join(failed)} (group only)"
    return True, "reads (group only: per-task sums not kept)"


def read_rows(path: str | Path) -> list[dict]:
    """The rows of a table `write` made, from its CSV, as `build` returns them (for `merge`): an empty cell is a
    number the row's runs did not record (runs made before it was summed), so it stays absent, as in `build`."""
    lines = [cells for cells in read_csv(path) if cells]  # blank lines (an editor's trailing newline) say nothing
    needed = {*REQUIRED_COLUMNS, *ROW_KEY}
    if len(lines) < 2 or not needed <= set(lines[0]):
        raise UserError(f"{path}: not a held-out Table 4 CSV (written by src/report.py "
                        "report=table4_heldout): " + ("no rows" if len(lines) < 2 else "its header lacks "
                                                   + ",".join(sorted(needed - set(lines[0])))))
    header = lines[0]
    rows = []
    for i, cells in enumerate(lines[1:], start=2):
        if len(cells) != len(header):
            raise UserError(f"{path}, line {i}: {len(cells)} cells, expected {len(header)}")
        row = {}
        for column, text in zip(header, cells):
            if text == "":
                if column == "steps":
                    row[column] = None
                continue
            try:
                row[column] = _cell_value(column, text)
            except (KeyError, ValueError):
                raise UserError(f"{path}, line {i}, column {column}: {text!r} is not a "
                                + ("True/False" if is_flag(column) else "number")) from None
        rows.append(row)
    return rows


def _cell_value(column: str, text: str):
    """A CSV cell as `build` made it: names as text, robot_mask_* as bools, counts as ints, the rest floats."""
    if is_text(column):
        return text
    if is_flag(column):
        return {"True": True, "False": False}[text]
    if column == "steps" or column.startswith(("runs_", "heldout_episodes_")):
        return int(text)
    return float(text)


def merge(kept: list[dict], fresh: list[dict]) -> list[dict]:
    """`fresh` rows (from result.json files) beside the `kept` rows (an earlier table's, read_rows) that have no
    fresh row of the same (pipeline, group, preset, steps): a table extended with sweeps made on another machine or
    in an earlier checkout, whose result.json files are not here. A row is one sweep's whole set of counts, with
    intervals drawn jointly over them (the paired falls), so a fresh row replaces a kept one whole, never a cell;
    but a fresh row of the state reading only (protocol.pixels=false) replaces only the kept row's state columns,
    where both scored as many held-out episodes per count (the pixel and the state readings draw their intervals
    apart; `state_runs` says the row's two readings came from two sweeps)."""
    def key(r):
        return tuple(str(r.get(c)) for c in ROW_KEY)

    merged = {key(r): r for r in kept}
    for r in fresh:
        old = merged.get(key(r))
        if old is not None and not has_pixels(r) and has_pixels(old) and _same_episodes(old, r):
            r = {**{c: v for c, v in old.items() if not c.startswith("state_")}, **r,
                 "state_runs": STATE_BESIDE_KEPT}
        merged[key(r)] = r
    return [merged[k] for k in sorted(merged)]


def _same_episodes(a: dict, b: dict) -> bool:
    counts = a.get("counts")
    return counts == b.get("counts") and all(
        a.get(f"heldout_episodes_{k}") == b.get(f"heldout_episodes_{k}") for k in counts.split("/"))


def _ci(row: dict, name: str, digits: int) -> str:
    v = row.get(name)
    if v is None or not np.isfinite(v):
        return "—"
    return f"{v:.{digits}f} [{row[name + '_lo']:.{digits}f}, {row[name + '_hi']:.{digits}f}]"


def _milli(row: dict, name: str) -> str:
    """`name` with its interval, x1e3 (the per-pixel object-focused errors)."""
    if row.get(name) is None or not np.isfinite(row[name]):
        return "—"
    return _ci({f"v{s}": row[f"{name}{s}"] * 1e3 for s in ("", "_lo", "_hi")}, "v", 2)


def display(rows: list[dict]) -> tuple[list[str], list[list[str]]]:
    """A compact Markdown view: per count the object-focused one-step error (the primary number) with its skill
    against both baselines and its fall, then the full-frame one-step error with its skill against the last frame,
    the open-loop error with its skill against the last frame, and the reconstruction, each with its 95% interval;
    where any row's runs summed them, the moving pixels' share of the kept pixels and their one-step and open-loop
    skill against the last frame (runs recorded before they were summed give the table they gave then). A count
    that fails the pixel gate shows "no reading" in place of every model error; its skills stay (how far it lost)."""
    header = ["Method", "Task group", "preset (steps)", "episodes", "seeds", "gate (pixels)",
              "object-focused one-step (x1e-3/pixel)",
              "its skill vs last frame", "its skill vs mean image", "its fall first->last (x1e-3)",
              "full-frame one-step error", "full-frame skill vs last", "open-loop error", "open-loop skill vs last",
              "reconstruction", "state reading (one-step error of the objects' poses where recorded, else of the "
              "whole state; skill vs last state / constant velocity)",
              "its fall first->last"]
    moving = has_moving(rows)
    if moving:
        header += ["moving pixels (% of kept: one step / open loop)", "moving-pixel one-step (x1e-3/pixel)",
                   "its skill vs last frame", "its fall first->last (x1e-3)", "moving-pixel open-loop skill vs last"]
    body = []
    for r in rows:
        counts = [int(c) for c in r["counts"].split("/")]
        for i, k in enumerate(counts):
            passes, verdict = row_gate(r, k)
            # a gated count's model errors read nothing: none is shown; its skills (how far it lost) stay
            read = lambda cell: cell if passes or cell == "—" else "no reading"  # noqa: E731
            obj = _milli(r, f"one_step_object_{k}") if passes else "no reading" if has_pixels(r) else "—"
            if obj not in ("—", "no reading") and not r[f"robot_mask_{k}"]:
                obj += " (no masks: full frame)"
            preset = f"{r['preset']} ({r['steps']})" if has_pixels(r) else "states only"  # no world model
            body.append([r["pipeline"] if i == 0 else "", r["group"] if i == 0 else "",
                         preset if i == 0 else "", str(k), str(r[f"runs_{k}"]), verdict,
                         obj, _ci(r, f"one_step_object_skill_last_{k}", 2),
                         _ci(r, f"one_step_object_skill_mean_{k}", 2),
                         _fall(r, counts) if i == 0 else "",
                         read(_ci(r, f"one_step_{k}", 1)), _ci(r, f"one_step_skill_last_{k}", 2),
                         read(_ci(r, f"open_loop_{k}", 1)), _ci(r, f"open_loop_skill_last_{k}", 2),
                         read(_ci(r, f"reconstruction_{k}", 1)), _state(r, k), _state_fall(r) if i == 0 else ""]
                        + ([_shares(r, k), read(_milli(r, f"one_step_moving_{k}")),
                            _ci(r, f"one_step_moving_skill_last_{k}", 2),
                            _milli(r, "drop_one_step_moving") if i == 0 else "",
                            _ci(r, f"open_loop_moving_skill_last_{k}", 2)] if moving else []))
    return header, body


def _fall(row: dict, counts: list[int]) -> str:
    """The primary number's fall first -> last count, where it is read (fall_verdict; a kept row written before
    the gate: gated by its rows' skills, the baselines' own change not checked)."""
    number = _milli(row, "drop_one_step_object")
    verdict = row.get("fall_verdict")
    if not has_pixels(row):
        return "—"
    if verdict is None:
        gated = [k for k in (counts[0], counts[-1]) if not row_gate(row, k)[0]]
        if gated:
            return f"no reading (gated at {gated[0]} episodes)"
        return f"{number} (baselines' change not checked)"
    return _fall_text(verdict, number)


MIXED_VERSIONS = "no reading: its counts were read by different versions of the state reading ("
MIXED_LAYOUTS = "no reading: its counts read states of different layouts, recorded apart ("


def _fall_text(verdict: str, number: str) -> str:
    """A fall verdict (gate.fall_verdict) as a table cell: the number where it is read."""
    if verdict.startswith(MIXED_VERSIONS):
        return "no reading (counts read by different versions: rerun the sweep)"
    if verdict.startswith(MIXED_LAYOUTS):
        return "no reading (counts read states recorded apart: rerun the sweep on one collection)"
    if verdict.startswith(TOO_WIDE):
        return "no reading (interval too wide)"
    if verdict.startswith(OPPOSITE):
        return "no reading (the fall and a baseline's own change point opposite ways)"
    if verdict.startswith("no reading"):
        return "no reading (gated at " + verdict.rsplit(" at ", 1)[-1] + ")"
    return f"{verdict}: {number}"  # falls, rises, no fall


def _state_fall(row: dict) -> str:
    """The state reading's fall first -> last count, where it is read ('—' for rows without one)."""
    verdict = row.get("state_fall_verdict")
    if not verdict:
        return "—"
    return _fall_text(verdict, _sig({f"v{s}": row.get(f"state_drop{s}") for s in ("", "_lo", "_hi")}, "v"))


def _sig(row: dict, name: str) -> str:
    """`name` with its interval to 2 significant digits of the larger end (a state error's fall is 1e-5 in one
    group's units and 1 in another's: fixed decimals showed BBSEA drawer's objects as 0.0000 [-0.0000, 0.0000])."""
    v = row.get(name)
    if v is None or not np.isfinite(v):
        return "—"
    lo, hi = row[name + "_lo"], row[name + "_hi"]
    scale = max(abs(v), abs(lo), abs(hi))
    digits = max(0, 1 - int(np.floor(np.log10(scale)))) if scale > 0 else 0
    return f"{v:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def _state(row: dict, k: int) -> str:
    """The state-space reading of a count ('—' for runs without one: recorded before it, or no state)."""
    verdict = row.get(f"state_gate_{k}")
    if verdict is None:
        return "—"
    reads = STATE_READS.get(row.get(f"state_reads_{k}") or "state (version 4)", row.get(f"state_reads_{k}"))
    if row.get(f"state_inputs_{k}"):
        reads += f" [{row[f'state_inputs_{k}']}]"
    if not row[f"state_gate_passes_{k}"]:
        return f"{reads}: {verdict}"
    return (f"{reads}: {row[f'state_model_{k}']:.3g} ({row[f'state_skill_vs_last_state_{k}']:.2f} / "
            f"{row[f'state_skill_vs_constant_velocity_{k}']:.2f})")


# what a state cell read (state_reads_<k>), as the table says it
STATE_READS = {"objects": "objects", "state": "whole state", "state (version 4)": "whole state (v4)"}


def has_moving(rows: list[dict]) -> bool:
    """Whether any row's runs summed the moving pixels."""
    return any(key.startswith("one_step_moving_share_") for r in rows for key in r)


def _shares(row: dict, k: int) -> str:
    """The share of kept pixels that moved, one step and open loop ('—' for runs recorded before it was summed)."""
    v = [row.get(f"{kind}_moving_share_{k}") for kind in ("one_step", "open_loop")]
    if any(x is None or not np.isfinite(x) for x in v):
        return "—"
    return f"{100 * v[0]:.2g}% / {100 * v[1]:.2g}%"


def write(rows: list[dict], stem: str | Path) -> dict[str, Path]:
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    columns = sorted({k for r in rows for k in r}, key=lambda c: (c not in ("pipeline", "group", "preset", "steps",
                                                                            "counts"), c))
    csv_rows = [[r.get(c, "") for c in columns] for r in rows]
    header, body = display(rows)
    note = ("Held-out episodes (no model of a row trained on them); the same gradient steps for every count; "
            "object-focused errors per kept (non-robot) pixel and channel, the others summed over H x W x 3 pixels "
            "per frame; " + ("moving pixels: kept pixels whose colour changed from the last observed frame (no "
                             f"reading where fewer than {MIN_MOVING_PIXELS} moved); " if has_moving(rows) else "")
            + "[95% interval over training seeds and held-out episodes]; skill = 1 - error / baseline "
            "error (< 0: worse than the baseline). Gate (simeval.measures.dynamics_diversity.gate): a count reads only where the "
            f"object-focused one-step skill is >= {GateConfig.margin:g} against both the last frame and the mean "
            "image with its interval above 0, for the group and each task; elsewhere its number is 'no reading'. "
            f"The gate's interval is its own bootstrap (protocol.gate.n_boot={GateConfig.n_boot} draws), the "
            f"columns' {N_BOOT} draws shared by every count (paired falls): the same skill's two intervals differ in "
            "the last digits. A fall (pixels and states alike) is read only where both counts read, its interval "
            "excludes 0 and its error relative to each baseline falls (interval above 0: more than the baseline's own change); 'no "
            f"fall' where the fall lies within +-{GateConfig.margin:g} of the error at the fewest episodes (read "
            f"first) or its relative error's fall within +-{GateConfig.margin:g} of it, else 'no reading (interval "
            "too wide)'. The state "
            "reading (simeval.measures.dynamics_diversity.state_reading; its cell says what it read: the objects' "
            "poses where the store records them, moving links of articulated objects included, else the whole "
            "state) is gated the same way against the last and the task's mean state, per task where that task's "
            "read values move.")
    if any(k.startswith("state_inputs_") and r[k] for r in rows for k in r):
        note += (" A state cell marked [input_scale=state] or [target_scale=state] was read with that setting of "
                 "protocol.state_model (versions 1-6's inputs or loss), not the protocol's.")
    apart = [name for name, r in zip(row_names(rows), rows)
             if str(r.get("state_runs", "")).startswith(STATE_ONLY + ",")]  # beside a kept row's or newer runs
    if apart:
        note += (f" The state reading of {', '.join(apart)} comes from sweeps of the state reading alone "
                 "(protocol.pixels=false) on as many held-out episodes, beside the row's pixel reading (CSV column "
                 "state_runs says whose).")
    paths = {"csv": stem.with_suffix(".csv"), "md": stem.with_suffix(".md")}
    atomic_write_text(paths["csv"], to_csv(columns, csv_rows))
    atomic_write_text(paths["md"], to_markdown(header, body) + "\n" + note + "\n")
    return paths


def row_names(rows: list[dict]) -> list[str]:
    """Each row's name, pipeline/group, with its preset and steps where another row has the same pipeline/group
    (a user's tiny sweep kept beside the committed cpu row: two keys "robogen/table_top" told apart by counts alone)."""
    plain = [f"{r['pipeline']}/{r['group']}" for r in rows]
    return [name if plain.count(name) == 1 else
            f"{name} ({r['preset']}, {r['steps']} steps)" if has_pixels(r) else f"{name} (states only)"
            for name, r in zip(plain, rows)]


def _missing_readings(row: dict, counts: list[int], moving_panel: bool) -> str:
    """Why a row has no point in a skill-vs-last-frame panel (the second, object-focused; the right, moving
    pixels), for its key: a row missing from a panel without a word reads as a plotting fault. Both need pixels
    that moved (simeval.measures.dynamics_diversity.prediction: a copy of the last frame is otherwise exact and the
    ratio divides by ~0); a row's runs may also predate the moving-pixel sums."""
    summed = all(f"one_step_moving_skill_last_{k}" in row for k in counts)
    few_moved = summed and not any(np.isfinite(row[f"one_step_moving_skill_last_{k}"]) for k in counts)
    no_object = not any(np.isfinite(row.get(f"one_step_object_skill_last_{k}", np.nan)) for k in counts)
    reasons = []
    if few_moved:
        panels = ["second"] * no_object + ["fourth"] * moving_panel
        if panels:
            reasons.append(f"{' and '.join(panels)} panel{'s' * (len(panels) > 1)}: no reading, under "
                           f"{MIN_MOVING_PIXELS} pixels moved")
    else:
        reasons += ["second panel: no reading"] * no_object
        reasons += ["fourth panel: its runs did not sum moving pixels"] * (moving_panel and not summed)
    return f" ({'; '.join(reasons)})" if reasons else ""


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)


def _still(row: dict, ks: list[int]) -> bool:
    """Whether a row's state reading read values that never change (its last state exact at every count: RoboGen's
    objects), whose zero errors a log axis cannot draw."""
    return all(_number(row.get(f"state_last_state_{k}")) and row[f"state_last_state_{k}"] == 0 for k in ks)


def _state_panel_title(rows: list[dict]) -> str:
    """What the state panel's rows read (state_reads_<k> of their first count): the objects' poses, or the whole
    state for rows whose stores record no separate poses and for rows read before version 5, named."""
    reads = {f"{r['pipeline']}/{r['group']}": r.get(f"state_reads_{r['counts'].split('/')[0]}") or "state (version 4)"
             for r in rows}
    whole = [name for name, what in reads.items() if what != "objects"]
    if not whole:
        head = "objects' poses"
    elif len(whole) == len(reads):
        head = "whole state" + (" (v4)" if any(w == "state (version 4)" for w in reads.values()) else "")
    else:
        head = f"objects' poses; whole state: {', '.join(whole[:3])}{', ...' if len(whole) > 3 else ''}"
    return f"state reading: {head}\n(x: a gated count; baselines dashed)"


def _state_settings_key(r: dict, ks: list[int]) -> str:
    """What a row's key in the figure adds where a count's state reading was made with other settings than the
    protocol's, as its table cell does ("[input_scale=state]"): " [state at 10/20: input_scale=state]"; "" where
    none was (a figure that showed both versions' points unmarked read as one reading)."""
    by_setting: dict[str, list[str]] = {}
    for k in ks:
        if r.get(f"state_inputs_{k}"):
            by_setting.setdefault(r[f"state_inputs_{k}"], []).append(str(k))
    return "".join(f" [state at {'/'.join(counts)}: {setting}]" for setting, counts in by_setting.items())


def _state_panel(ax, r: dict, ks: list[int], color, marker, name: str) -> None:
    """A row's state reading against training episodes: the model's one-step error (a black x over it where its
    count fails the state gate; hollow markers are the open loop's in the skill panels) beside the last state
    (dash-dot) and the task mean state (dashed)."""
    have = [k for k in ks if _number(r.get(f"state_model_{k}"))]
    # the model above its baselines: a gated count is gated because its error is the last state's, and a baseline
    # marker drawn over its mark hid it
    ax.plot(have, [r[f"state_model_{k}"] for k in have], "-", marker=marker, ms=6, color=color, lw=1, zorder=3)
    gated = [k for k in have if not r.get(f"state_gate_passes_{k}")]
    ax.plot(gated, [r[f"state_model_{k}"] for k in gated], "x", ms=7, mew=1.5, color="black", zorder=4)
    for base, ls, alpha in (("last_state", "-.", 1.0), ("mean_state", "--", 0.5)):
        ax.plot(have, [r[f"state_{base}_{k}"] for k in have], ls, marker=marker, ms=3, lw=0.9, color=color,
                alpha=alpha, label=f"{name}: {base.replace('_', ' ')}")


def _pixel_axes(ax1, ax2, ax3, rows: list[dict]) -> None:
    """The pixel panels' scales, ticks, labels and titles (plot), and a note where a panel has nothing to draw."""
    from matplotlib.ticker import FuncFormatter

    # log scale: the last-frame baselines (~0.005) and the mean images (up to ~16) differ by 10^3-10^4
    ax1.set(ylabel="per kept pixel and channel (x1e-3, log scale)", yscale="log",
            title="object-focused one-step error (primary; model: 95% CI)")
    ax1.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))  # 0.01, 1, 10 rather than 10^-2 ..
    ax1.yaxis.set_minor_formatter(FuncFormatter(  # .. and 2, 3, 4 (not 2x10^0) where it spans under a decade
        lambda v, _: f"{v:g}" if np.log10(max(ax1.get_ylim()) / min(ax1.get_ylim())) < 1 else ""))
    ax2.axhline(0, color="0.5", lw=0.8)
    # symlog: one group's -800 (a redraw of still pixels) left every other group's -1 .. -70 a flat line at 0
    ax2.set_yscale("symlog", linthresh=1)
    ax2.set_ylim(top=1.5)  # a skill is at most 1; symlog's autoscale left two empty decades above it
    # symlog's own ticks are 0 and powers of ten: skills between -1 and 1 (most of them) could not be read
    bottom = ax2.get_ylim()[0]
    ax2.set_yticks([1, 0.5, 0, -0.5, -1] + [-(10.0 ** k) for k in range(1, 6) if -(10.0 ** k) >= bottom])
    ax2.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax2.set(ylabel="skill vs last frame (1 - model / baseline;\nsymlog: linear within [-1, 1])",
            title="object-focused skill vs the last frame")
    if not any(has_pixels(r) for r in rows):  # no row has a reading at all: say why the panels are empty
        for ax in (ax1, ax2, ax3):
            ax.text(0.5, 0.5, "not read (protocol.pixels=false)", transform=ax.transAxes, ha="center",
                    va="center", color="0.35")
    elif not any(np.isfinite(r.get(f"one_step_object_skill_last_{c}", np.nan)) for r in rows
                 for c in (int(c) for c in r["counts"].split("/"))):  # an empty panel would read as a plotting fault
        ax2.text(0.5, 0.5, "no reading: too few kept pixels\nchange from one frame to the next\n(the last frame is a "
                 "near-exact copy)", transform=ax2.transAxes, ha="center", va="center", color="0.35",
                 bbox={"facecolor": "white", "edgecolor": "none"})  # the zero line ran through its middle line
    ax3.set(ylabel="sum over pixels per frame", title="full-frame one-step error (robot included)")


def plot(rows: list[dict], path: str | Path, title: str = "") -> Path:
    """Per row, against training episodes: the object-focused one-step error per kept pixel (the primary number;
    the full frame's when the episodes carry no robot masks) with its interval and the row's two baselines on the
    same pixels (left), its skill against the last frame beside the open loop's (second), the full-frame one-step
    error (third) and, where the runs summed them, the moving pixels' skill against the last frame (fourth: what the
    model predicts of the motion outside the robot; a row without a skill reading says why in its key) and, where any
    row has one, the state reading's one-step error beside the last and the mean state (last panel; alone where no
    row has a pixel reading); more than three panels wrap onto two rows. Rows of one pipeline/group are told apart
    by preset (row_names). A row has one colour and one marker shape in every panel, a reading one line style; in
    the fourth panel an interval far wider than the points' spread is cut at the edge and named in its title
    (simeval.writing.figures.cut_wide_intervals).
    Saved without dates or versions (simeval.writing.figures.save_figure), so a rebuild from the same runs gives the
    same bytes. The first panel has a log scale (its baselines span four decades), the second a symmetric log one
    (skills from 1 to -800). Long because it is one figure drawn panel by panel: every panel shares the rows'
    colours and markers and the figure-wide keys, and each axis setting sits beside the reason it was needed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.ticker import NullFormatter

    from simeval.writing.figures import cut_wide_intervals, distinct_colors, row_markers, save_figure

    def bars(ax, r, name, ks, ls, color, marker, label, hollow=False, shift=1.0, scale=1.0):
        """The reading's points with their intervals; (values, lows, highs), or None where there is no reading."""
        v = np.array([r[f"{name}_{k}"] for k in ks]) * scale
        lo = np.array([r[f"{name}_{k}_lo"] for k in ks]) * scale
        hi = np.array([r[f"{name}_{k}_hi"] for k in ks]) * scale
        if not np.isfinite(v).any():  # no reading at any count: nothing drawn
            return None
        err = np.maximum(np.stack([v - lo, hi - v]), 0)  # a percentile interval of a ratio may sit beside its point
        ax.errorbar(np.array(ks) * shift, v, yerr=err, ls=ls, marker=marker, ms=5, color=color, capsize=3,
                    mfc="white" if hollow else color, label=label)
        return v, lo, hi

    moving = [r for r in rows if all(np.isfinite(r.get(f"one_step_moving_skill_last_{k}", np.nan))
                                     for k in (int(c) for c in r["counts"].split("/")))]
    stated = [r for r in rows if any(_number(r.get(f"state_model_{c}")) for c in r["counts"].split("/"))]
    # states-only rows alone: the state panel alone (three empty pixel panels that each said "not read" were most
    # of a figure with one reading in it)
    pixel_panels = 3 if any(has_pixels(r) for r in rows) or not stated else 0
    n_panels = pixel_panels + bool(moving) + bool(stated)
    # the rows' keys below the panels (inside, the first panel's covered its own baselines' lines), the line
    # styles' in a cell of their own after the panels; more than four cells wrap onto two rows, since five panels
    # in one row made a strip too wide to read at a page's width
    n_cells = n_panels + 1
    n_rows = 1 if n_cells <= 4 else 2
    n_cols = -(-n_cells // n_rows)
    fig, grid = plt.subplots(n_rows, n_cols, figsize=(5.2 * n_cols, 5.4 * n_rows + 1.4), layout="constrained",
                             squeeze=False)
    axes = list(grid.flat)
    key_cell = axes[n_panels]
    key_cell.axis("off")
    for spare in axes[n_panels + 1:]:
        spare.remove()
    axes = axes[:n_panels]
    ax1, ax2, ax3 = axes[:3] if pixel_panels else (None, None, None)
    n_gated = 0  # rows with a count that fails the gate (simeval.measures.dynamics_diversity.gate)
    row_keys, moving_drawn = [], []  # one key per row for the whole figure (below); the moving panel's lines
    # a row: its colour and its marker shape in every panel (two of tab20's shades alone were hard to tell apart)
    open_loop = False  # whether an open-loop line is drawn: its style's key only then
    for r, name, color, marker in zip(rows, row_names(rows), distinct_colors(len(rows)), row_markers(len(rows)),
                                      strict=True):
        ks = [int(c) for c in r["counts"].split("/")]
        masked = all(r.get(f"robot_mask_{k}") for k in ks) or not has_pixels(r)
        gated = [str(k) for k in ks if not row_gate(r, k)[0]] if has_pixels(r) else []
        row_keys.append(Line2D([], [], color=color, marker=marker, ms=5,
                               label=name + ("" if masked else " (no masks: full frame)")
                               + (f" [pixels: no reading at {'/'.join(gated)}]" if gated else "")
                               + (_missing_readings(r, ks, bool(moving)) if has_pixels(r) else
                                  " (states only: protocol.pixels=false)")
                               + (" (no state reading)" if stated and r not in stated else "")
                               + (" (state: objects never move, not drawn)" if r in stated and _still(r, ks) else "")
                               + _state_settings_key(r, ks)))
        n_gated += bool(gated)
        if r in stated:
            _state_panel(axes[-1], r, ks, color, marker, name)
        if not has_pixels(r):
            continue
        bars(ax1, r, "one_step_object", ks, "-", color, marker, f"{name}: model", scale=1e3)
        ax1.plot(ks, [r[f"one_step_object_last_{k}"] * 1e3 for k in ks], "-.", marker=marker, ms=3, lw=0.9,
                 color=color, label=f"{name}: last frame")
        ax1.plot(ks, [r[f"one_step_object_mean_{k}"] * 1e3 for k in ks], "--", marker=marker, ms=3, lw=0.9,
                 color=color, alpha=0.5, label=f"{name}: mean image")
        bars(ax2, r, "one_step_object_skill_last", ks, "-", color, marker, f"{name}: one step (object-focused)")
        open_loop |= bars(ax2, r, "open_loop_object_skill_last", ks, ":", color, marker,
                          f"{name}: open loop (object-focused)", hollow=True, shift=1.04) is not None
        bars(ax3, r, "one_step", ks, "-", color, marker, name)
        if r in moving:
            drawn = [bars(axes[3], r, "one_step_moving_skill_last", ks, "-", color, marker, f"{name}: one step")]
            if all(np.isfinite(r.get(f"open_loop_moving_skill_last_{k}", np.nan)) for k in ks):
                drawn.append(bars(axes[3], r, "open_loop_moving_skill_last", ks, ":", color, marker,
                                  f"{name}: open loop", hollow=True, shift=1.04))
            moving_drawn += [(name, *d) for d in drawn if d is not None]
            open_loop |= len(drawn) > 1 and drawn[1] is not None
    if pixel_panels:
        _pixel_axes(ax1, ax2, ax3, rows)
    if moving:
        axes[3].axhline(0, color="0.5", lw=0.8)
        # one row's wide interval (few moving pixels) had squeezed the other rows into a strip: cut, and said
        cut = cut_wide_intervals(axes[3], moving_drawn)
        axes[3].set(ylabel="skill vs last frame (1 - model / baseline)",
                    title="moving pixels: skill vs the last frame"
                    + ("\n(intervals cut: " + "; ".join(cut) + ")" if cut else ""))
    if stated:
        axes[-1].set(ylabel="one-step error per step (state units, log scale)", yscale="log",
                     title=_state_panel_title(stated))
    ks = sorted({int(c) for r in rows for c in r["counts"].split("/")})
    for ax in axes:
        ax.set(xlabel="training episodes per task", xscale="log")
        ax.set_xticks(ks, [str(k) for k in ks])
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlim(min(ks) / 1.3, max(ks) * 1.3)
    # two keys for the whole figure: a row keeps its colour in every panel and a reading its line style, so one
    # list of rows and one of styles replace four legends that each repeated every row (up to 60 entries)
    style_keys = [Line2D([], [], color="0.3", marker="o", ms=5, ls="-", label="model, one step (95% CI)"),
                  Line2D([], [], color="0.3", marker="o", ms=3, lw=0.9, ls="-.",
                         label="last-frame / last-state baseline"),
                  Line2D([], [], color="0.3", marker="o", ms=3, lw=0.9, ls="--", alpha=0.5,
                         label="mean-image / mean-state baseline")]
    if open_loop:
        style_keys.insert(1, Line2D([], [], color="0.3", marker="o", ms=5, mfc="white", ls=":",
                                    label="model, open loop (skill panels)"))
    if stated:
        style_keys.append(Line2D([], [], color="black", marker="x", ms=7, mew=1.5, ls="",
                                 label="state reading: a gated count (its gate fails)"))
    fig.legend(handles=row_keys, loc="outside lower center", ncol=-(-len(row_keys) // 5), fontsize=8,
               frameon=False, title="row (colour and marker)", title_fontsize=8, alignment="left")
    key_cell.legend(handles=style_keys, loc="upper left", ncol=1, fontsize=9, frameon=False, handlelength=4,
                    title="reading (line style)", title_fontsize=9, alignment="left")
    # the reason the gate gave: a count where too few pixels moved has no skill to beat (a trial's tiny sweep's title
    # said "does not beat" beside its cells' "under 100 kept pixels moved")
    still = any(has_pixels(r) and row_gate(r, int(k))[1].startswith(f"no reading: under {MIN_MOVING_PIXELS} kept")
                for r in rows for k in r["counts"].split("/"))
    why = ("the model does not beat the last frame or the mean image" if not still else
           f"the model does not beat the last frame or the mean image, or under {MIN_MOVING_PIXELS} kept pixels moved")
    gated_line = (f"{n_gated} of {len(rows)} rows have counts that fail the pixel gate ([pixels: no reading at "
                  f"...]: {why}; their pixel numbers read nothing)" if n_gated else "")
    state_line = "the state reading (its own panel) has its own gate" if stated else ""
    lines = [title, gated_line, state_line]  # one line each: joined, they ran past the figure's edges
    fig.suptitle("\n".join(x for x in lines if x), fontsize=10)
    out = save_figure(fig, path, dpi=120)
    plt.close(fig)
    return out
