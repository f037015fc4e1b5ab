"""Paper Table 5 from generalization result.json files: the paper's value beside ours, per task group, as tables
and a figure.

    python src/report.py report=table5 [report.runs_dir=outputs] [report.policy=cpu] \
        [report.keep=[outputs/tables/table5.csv]] [overwrite=true]          (rebuild_table5, from Python)
writes table5.{csv,md,tex}, table5_detail.{csv,md} (per task, task-level intervals, mean progress) and
table5.{png,pdf}. Ours: success rate of the `eval` split (the paper's protocol: the
group's tasks under variations) with its Wilson 95% interval and its mean progress (GenSim's paper value is a
step-wise reward: the progress is what it compares with), and the train/heldout splits beside it when run. Several
runs of one cell must agree on their identity (settings), one run per training seed; seeds are pooled (successes and
rollouts add up; table5_detail adds each seed's rate and an interval over seeds and tasks). The
paper's values (simeval.writing.paper_values.TABLE5) are GenSim's step-wise reward and RoboGen/BBSEA's success rate.
No generalization result.json under runs_dir: one line on stderr, exit status 2. `keep=[outputs/tables/table5.csv]`
(a list) extends an earlier table: its rows of cells the runs under runs_dir lack are kept (how the committed table
gathers groups run on different machines, whose result.json files are not all here); the runs under runs_dir still
have to exist, and a cell they have replaces the kept row. Tables and figures that git tracks (the committed ones)
are replaced only with `overwrite=true`.
"""

from __future__ import annotations

import re
from pathlib import Path

from simeval.errors import UserError
from simeval.stats.intervals import task_bootstrap_interval, wilson_interval
from simeval.writing.paper_groups import suite_group
from simeval.writing.paper_values import TABLE5 as PAPER, paper_table5
from simeval.writing.paper_values import TABLE5_MEANING
from simeval.writing.tables import (Rebuilt, ReportWords, kept_only_hint, read_csv, read_kept, refuse_committed,
                                    replaced_notes, rows_lost, write_table)
from simeval.results import identity_difference, read_results, rolled_out

METRIC = "generalization"
SPLITS = ("eval", "train", "heldout")  # table column order: the paper's protocol first
CHANCE = "random"  # policy=random: the chance baseline (simeval.measures.generalization.random_baseline), nothing trained
CHANCE_NOTE = " (chance: nothing trained)"
PAPER_PROGRESS = {"gensim", "gensim_own"}  # pipelines whose paper value is a step-wise reward: the figure draws
# our eval progress
LEGEND_ROW_INCHES = 14.5  # the figure legend's five keys in one row at fontsize 8 (measured: ~14 in)
GROUPS_PER_ROW = 10  # panels wrap into rows of at most this many groups: one row of 26 groups was 5300 px wide and
# unreadable at any size a screen shows it
GROUP_INCHES = 1.25
PLOT_SPLITS = {"train": ("train (trained tasks)", "C0", "o"), "eval": ("eval (varied scenes)", "C3", "s"),
               "heldout": ("held-out tasks", "C2", "^")}  # figure order: as the policy moves away from its data


def _cell(rec: dict, policy: str | None) -> tuple | None:
    """(pipeline, the paper's group, policy preset) of a run, or None when `policy` names another preset."""
    ident = rec["identity"]
    if policy is not None and ident.get("policy") != policy:
        return None
    return ident["pipeline"], suite_group(ident["pipeline"], ident["task_group"]), ident.get("policy")


_NOT_A_SETTING = {"seed", "checkpoint_every", "log_every"}  # settings.train keys runs of one cell may differ in


def cell_setting(rec: dict) -> dict:
    """A run's identity without its training seed (top-level `seed`, and `settings.train.seed` where the run
    records its training settings) and without the training's bookkeeping (how often it logs and checkpoints: a
    resumed training gets the same weights at any checkpoint interval), with the demonstrations it trained on
    (all | successful; recorded in the identity since that choice exists, in values.training before, absent = all):
    what runs of one cell, one per seed, must share."""
    identity = rec["identity"]
    base = {k: v for k, v in identity.items() if k != "seed"}
    kept = (((rec.get("values") or {}).get("training") or {}).get("demonstrations") or {}).get("kept")
    if identity.get("policy") != "random":
        base["demonstrations"] = identity.get("demonstrations") or kept or "all"
    train = (base.get("settings") or {}).get("train")
    if isinstance(train, dict):
        base["settings"] = {**base["settings"], "train": {k: v for k, v in train.items() if k not in _NOT_A_SETTING}}
    return base


def build(records: list[dict], policy: str | None = None) -> list[dict]:
    """One row per paper cell and policy preset (then per other group run): {pipeline, group, paper, policy, runs,
    demonstrations (all | successful; None untrained), eval, train, heldout}, a split being {k, n, rate, ci} pooled over the cell's runs, or None when not run.
    `policy`: only runs of that policy preset (the quick profile's `tiny` runs beside the `cpu` ones give two
    rows per group otherwise). Runs of one cell and preset with other settings (another sampler, other seeds)
    are a UserError: pooling them would mix two experiments."""
    cells: dict = {}
    for rec in records:
        key = _cell(rec, policy)
        if key is None:
            continue
        base = cell_setting(rec)
        if key in cells and cells[key]["identity"] != base:
            diff = identity_difference(cells[key]["identity"], base)
            raise UserError(f"{rec['path']}: runs of {key[:2]} with policy {key[2]} differ in {diff}; a cell pools "
                            f"runs of one setting only: move the other runs out of the folder searched, or search "
                            f"one sweep's folder (report.runs_dir)")
        cell = cells.setdefault(key, {"identity": base, "counts": {}, "runs": [], "seeds": {}, "eval_progress": 0.0})
        seed = rec["identity"].get("seed")
        if seed in cell["seeds"]:
            raise UserError(f"{rec['path']} and {cell['seeds'][seed]}: two runs of {key[:2]} with policy {key[2]} and "
                            f"seed {seed}; a cell pools one run per training seed: move one out of the folder "
                            f"searched (report.runs_dir)")
        cell["seeds"][seed] = rec["path"]
        cell["runs"].append(rec["path"])
        for split, v in rec["values"].get("splits", {}).items():
            if not v["success"]["n"]:  # every rollout left out: the variation changed no scene (evaluate.rollout_task)
                continue
            k, n = cell["counts"].get(split, (0, 0))
            cell["counts"][split] = (k + v["success"]["k"], n + v["success"]["n"])
            if split == "eval":  # progress summed over rollouts, so runs of other sizes weigh by their rollouts;
                # None once a run has none (a result written before runs recorded it)
                progress = cell["eval_progress"]
                cell["eval_progress"] = (None if progress is None or v.get("mean_progress") is None
                                         else progress + v["mean_progress"] * v["success"]["n"])
    if policy is not None and not cells:
        presets = sorted({str(r["identity"].get("policy")) for r in records})
        raise UserError(f"report.policy={policy}: no {METRIC} run of that preset (the runs' presets: "
                        f"{', '.join(presets)})")
    ran = {(p, g) for p, g, _ in cells}
    keys = [(p, g, pr) for p, g in [*PAPER, *sorted(ran - set(PAPER))]
            for pr in (sorted((k[2] for k in cells if k[:2] == (p, g)), key=str) or [None])]
    rows = []
    for (pipeline, group, preset) in keys:
        cell = cells.get((pipeline, group, preset))
        row = {"pipeline": pipeline, "group": group, "paper": paper_table5(pipeline, group),
               "policy": preset, "runs": len(cell["runs"]) if cell else 0,
               "demonstrations": cell["identity"].get("demonstrations") if cell and preset != CHANCE else None}
        for split in SPLITS:
            k, n = (cell or {"counts": {}})["counts"].get(split, (0, 0))
            row[split] = _split(k, n) if n else None
        has_progress = cell and row["eval"] and cell["eval_progress"] is not None
        row["eval_progress"] = cell["eval_progress"] / row["eval"]["n"] if has_progress else None
        rows.append(row)
    return rows


HEAD = ["Pipeline", "Task group", "Paper", "Ours: eval (varied)", "Ours: eval progress", "Ours: train",
        "Ours: held-out", "Policy", "Demonstrations", "Runs"]
HEAD_WITHOUT_DEMONSTRATIONS = [h for h in HEAD if h != "Demonstrations"]  # tables written before 2026-11-28
HEAD_WITHOUT_PROGRESS = [h for h in HEAD_WITHOUT_DEMONSTRATIONS if h != "Ours: eval progress"]  # before 2026-11-27
_COUNTS = re.compile(r"\((\d+)/(\d+)\)$")


def _split(k: int, n: int) -> dict:
    return {"k": k, "n": n, "rate": k / n, "ci": wilson_interval(k, n)}


def read_rows(path: str | Path) -> list[dict]:
    """The rows of a table `write` made, from its CSV: each split's successes/rollouts are read back (the rate and
    interval recomputed from them), for `merge`."""
    raw = read_csv(path)
    if not raw or raw[0] not in (HEAD, HEAD_WITHOUT_DEMONSTRATIONS, HEAD_WITHOUT_PROGRESS):
        raise UserError(f"{path}: not a Table 5 CSV (written by src/report.py report=table5): its header "
                        f"should be {','.join(HEAD)}")
    head = raw[0]
    rows = []
    for line, cells in enumerate(raw[1:], start=2):
        if not cells:
            continue  # a blank line (an editor's trailing newline)
        if len(cells) != len(head):
            raise UserError(f"{path}, line {line}: {len(cells)} cells, expected {len(head)}")
        if head == HEAD_WITHOUT_PROGRESS:
            cells = [*cells[:4], "-", *cells[4:]]
        if head != HEAD:  # written before the choice existed: every trained run used all its episodes
            cells = [*cells[:8], "-" if cells[7].removesuffix(CHANCE_NOTE) in ("-", CHANCE) else "all", cells[8]]
        pipeline, group, paper, eval_cell, progress, train_cell, heldout_cell, policy, demonstrations, runs = cells
        splits = (eval_cell, train_cell, heldout_cell)  # SPLITS' order
        try:
            row = {"pipeline": pipeline, "group": group, "paper": None if paper == "-" else float(paper),
                   "policy": None if policy == "-" else policy.removesuffix(CHANCE_NOTE), "runs": int(runs),
                   "demonstrations": None if demonstrations == "-" else demonstrations,
                   "eval_progress": None if progress == "-" else float(progress)}
        except ValueError as e:
            raise UserError(f"{path}, line {line}: {e}") from e
        for split, text in zip(SPLITS, splits):
            m = _COUNTS.search(text)
            if text != "-" and (m is None or int(m[1]) > int(m[2])):
                raise UserError(f"{path}, line {line}: {split} cell {text!r} has no (successes/rollouts) with "
                                "successes <= rollouts")
            row[split] = _split(int(m[1]), int(m[2])) if m else None
        rows.append(row)
    if not rows:  # this report always writes the paper's rows: a header alone is a cut or hand-made file
        raise UserError(f"{path}: not a Table 5 CSV (written by src/report.py report=table5): no rows")
    return rows


def merge(kept: list[dict], fresh: list[dict]) -> list[dict]:
    """`fresh` rows (from result.json files) and the rows of `kept` (an earlier table's, read_rows) for every
    (pipeline, group, policy) the fresh ones have no run of: a table extended with runs made on another machine,
    whose result.json files are not here. A not-run row is dropped where its group has a run; the paper's order."""
    rows = {(r["pipeline"], r["group"], r["policy"]): r for r in fresh}
    for old in kept:
        key = (old["pipeline"], old["group"], old["policy"])
        if old["runs"] and not (key in rows and rows[key]["runs"]):
            rows[key] = old
    ran = {k[:2] for k, r in rows.items() if r["runs"]}
    order = [*PAPER, *sorted({k[:2] for k in rows} - set(PAPER))]
    return sorted((r for k, r in rows.items() if r["runs"] or k[:2] not in ran),
                  key=lambda r: (order.index((r["pipeline"], r["group"])), str(r["policy"])))


def eval_progress_from_detail(rows: list[dict], lines: list[list[str]]) -> list[dict]:
    """`rows` with the eval progress of each row that has none (a row kept from a table written before the column
    existed) taken from its group's "all tasks" eval line of the per-task table (detail_lines), where it has one."""
    progress = {(c[0], c[1], c[2]): float(c[9]) for c in lines if c[3] == "eval" and c[4] == "all tasks"}
    return [{**r, "eval_progress": progress.get((r["pipeline"], r["group"], _policy_cell(r["policy"])))}
            if r.get("eval_progress") is None and r["runs"] else r for r in rows]


def _draws_progress(row: dict) -> bool:
    """Whether the figure draws the row's eval progress: where the paper's value is a step-wise reward."""
    return row["pipeline"] in PAPER_PROGRESS and row.get("eval_progress") is not None


def _policy_cell(policy: str | None) -> str:
    return "-" if not policy else policy + (CHANCE_NOTE if policy == CHANCE else "")


def _fmt(v) -> str:
    return "-" if v is None else f"{v['rate']:.2f} [{v['ci'][0]:.2f}, {v['ci'][1]:.2f}] ({v['k']}/{v['n']})"


def write(rows: list[dict], out: str | Path) -> dict[str, Path]:
    """`<out>.csv`, `<out>.md` and `<out>.tex` (booktabs): {suffix: path}."""
    table = [[r["pipeline"], r["group"], "-" if r["paper"] is None else f"{r['paper']:.2f}", _fmt(r["eval"]),
              "-" if r.get("eval_progress") is None else f"{r['eval_progress']:.2f}",
              *(_fmt(r[s]) for s in SPLITS[1:]), _policy_cell(r["policy"]), r.get("demonstrations") or "-",
              str(r["runs"])] for r in rows]
    notes = ["Success rate with Wilson 95% interval (successes/rollouts); '-' = not run",
             TABLE5_MEANING[0].upper() + TABLE5_MEANING[1:],
             ("Eval progress: the mean over the eval rollouts of each task's progress at the rollout's end (1.0 = "
              "success; for GenSim the step-wise reward, the quantity of the paper's GenSim column; for Meta-World its "
              "shaped reward / 10, which can stay below 1.0 at a success)"),
             ("Eval counts the rollouts whose scene the variation changed: a seed whose first observation is its "
              "train rollout's is left out, and a group where no scene changed shows '-' (GenSim's own task.mode "
              "changes no scene in most of its tasks; rows built before 2026-11-30 count such rollouts: which "
              "scenes a variation changes, before any training, is src/generalization_tools.py variation-probe's "
              "eval_variation_<pipeline>_<group>.md)"),
             "RoboGen train: the training scene itself (RoboGen-style tasks start from one fixed state)",
             ("Demonstrations: the episodes the policy trained on: 'all' stored, or only the 'successful' ones (as "
              "GenSim's demos.py keeps them); '-' = nothing trained"),
             "Per task, task-level intervals, mean progress and the random-policy baseline: table5_detail.md"]
    paths = write_table(out, HEAD, table, notes=notes, label="tab:table5",
                        caption="Diffusion Policy trained per task group: success rate on the group's tasks under "
                                "variations (eval), on the training distribution (train) and on held-out tasks.")
    return {p.suffix.lstrip("."): p for p in paths}


DETAIL_HEAD = ["Pipeline", "Task group", "Policy", "Split", "Task", "Success", "Wilson 95%", "Task-level 95%",
               "Per run", "Mean progress", "Runs"]


def detail_rows(records: list[dict], policy: str | None = None) -> list[dict]:
    """Per (pipeline, group, policy, split): the pooled success with its Wilson interval and its task-level
    (cluster) bootstrap interval (simeval.stats.intervals.task_bootstrap_interval; with several runs of the cell,
    i.e. training seeds, over runs and tasks both), each run's own rate, the mean progress (GenSim's step-wise reward
    is a progress, not a success), then one row per task, its runs pooled. Rows are dicts: {pipeline, group, policy,
    split, task ('*' for the group), k, n, rate, ci, task_ci, run_rates and run_progress (the group line's
    {training seed: rate} and {training seed: mean progress}, None on task lines), progress, runs}."""
    cells: dict = {}
    for rec in records:
        key = _cell(rec, policy)
        if key is None:
            continue
        cell = cells.setdefault(key, {"runs": 0, "tasks": {}, "seeds": []})
        run = cell["runs"]
        cell["runs"] += 1
        cell["seeds"].append(rec["identity"].get("seed"))
        for t in rec["values"].get("tasks", []):
            eps = rolled_out(t.get("episodes") or [])
            per_run = cell["tasks"].setdefault((t["split"], t["task"]), {})
            k, n, prog = per_run.get(run, (0, 0, 0.0))
            progress = [e["progress"] for e in eps]
            per_run[run] = (k + t["success"]["k"], n + t["success"]["n"],
                            None if prog is None or None in progress else prog + sum(progress))
    order = [*PAPER, *sorted({k[:2] for k in cells} - set(PAPER))]
    rows = []
    for key in sorted(cells, key=lambda c: (order.index(c[:2]), str(c[2]))):
        cell = cells[key]
        runs = range(cell["runs"])
        for split in SPLITS:
            tasks = sorted((t, v) for (sp, t), v in cell["tasks"].items()
                           if sp == split and sum(n for _, n, _ in v.values()))  # not every rollout left out
            if not tasks:
                continue
            # (runs, tasks) counts; a run that did not roll a task out adds 0 of 0 there
            k_rt = [[v.get(r, (0, 0, 0))[0] for _, v in tasks] for r in runs]
            n_rt = [[v.get(r, (0, 0, 0))[1] for _, v in tasks] for r in runs]
            pooled = [(*(sum(c[i] for c in v.values()) for i in range(2)), _sum_known(c[2] for c in v.values()))
                      for _, v in tasks]
            k, n = sum(p[0] for p in pooled), sum(p[1] for p in pooled)
            base = dict(zip(("pipeline", "group", "policy"), key), split=split, runs=cell["runs"])
            p_rt = [[v.get(r, (0, 0, 0))[2] for _, v in tasks] for r in runs]
            run_rates = {seed: sum(kr) / sum(nr) if sum(nr) else None
                         for seed, kr, nr in zip(cell["seeds"], k_rt, n_rt)}
            run_progress = {seed: _ratio(_sum_known(pr), sum(nr)) for seed, pr, nr in zip(cell["seeds"], p_rt, n_rt)}
            rows.append({**base, "task": "*", "k": k, "n": n, "rate": k / n, "ci": list(wilson_interval(k, n)),
                         "task_ci": task_bootstrap_interval(k_rt, n_rt), "run_rates": run_rates,
                         "run_progress": run_progress, "progress": _ratio(_sum_known(p[2] for p in pooled), n)})
            for (t, _), (tk, tn, tp) in zip(tasks, pooled):
                rows.append({**base, "task": t, "k": tk, "n": tn, "rate": tk / tn, "ci": list(wilson_interval(tk, tn)),
                             "task_ci": None, "run_rates": None, "run_progress": None, "progress": _ratio(tp, tn)})
    return rows


def _sum_known(values) -> float | None:
    """The sum, or None where any value is unknown (an environment that reports no progress)."""
    values = list(values)
    return None if None in values else sum(values)


def _ratio(total: float | None, n: int) -> float | None:
    return None if total is None or not n else total / n


def _progress_text(progress: float | None) -> str:
    return "unknown" if progress is None else f"{progress:.2f}"


def read_detail_lines(path: str | Path) -> list[list[str]]:
    """The lines of a per-task table write_detail made, from its CSV, as written (its cells are kept, not
    recomputed: a kept group's runs are not here to recompute them from)."""
    raw = [cells for cells in read_csv(path) if cells]  # blank lines (an editor's trailing newline) say nothing
    if not raw or raw[0] != DETAIL_HEAD:
        raise UserError(f"{path}: not a Table 5 detail CSV (written beside table5.csv): its header should be "
                        f"{','.join(DETAIL_HEAD)}")
    for line, cells in enumerate(raw[1:], start=2):
        if len(cells) != len(DETAIL_HEAD):
            raise UserError(f"{path}, line {line}: {len(cells)} cells, expected {len(DETAIL_HEAD)}")
    return raw[1:]


def merge_detail(kept: list[list[str]], fresh: list[list[str]]) -> list[list[str]]:
    """The lines of `fresh` (detail_lines of runs on disk) and those of `kept` (read_detail_lines of an earlier
    table) for every (pipeline, group, policy) the fresh ones have none of, a group's lines in their order; groups
    in the paper's order, then by policy (detail_rows' order)."""
    def key(cells):
        return tuple(cells[:3])

    have = {key(c) for c in fresh}
    lines = [*fresh, *(c for c in kept if key(c) not in have)]
    order = [*PAPER, *sorted({tuple(c[:2]) for c in lines} - set(PAPER))]
    return sorted(lines, key=lambda c: (order.index(tuple(c[:2])), c[2].removesuffix(CHANCE_NOTE)))


def _seed_order(item) -> tuple:
    """Integer seeds by value, anything else (a seed missing from an old record) after them by its text."""
    seed = item[0]
    return (0, seed, "") if isinstance(seed, int) else (1, 0, str(seed))


def detail_lines(rows: list[dict]) -> list[list[str]]:
    """detail_rows as the table's cells."""
    def interval(ci) -> str:
        return "-" if ci is None else f"[{ci[0]:.2f}, {ci[1]:.2f}]"

    def per_run(rates, progress) -> str:
        if rates is None or len(rates) < 2:
            return "-"

        def value(x, prog) -> str:
            return "-" if x is None else f"{x:.2f} (progress {_progress_text(prog)})"
        # in seed order: runs arrive in their folders' order (launch time), which need not be the seeds'
        return ", ".join(f"seed {seed}: " + value(x, progress.get(seed))
                         for seed, x in sorted(rates.items(), key=_seed_order))

    return [[r["pipeline"], r["group"], _policy_cell(r["policy"]), r["split"],
             "all tasks" if r["task"] == "*" else r["task"],
             f"{r['rate']:.2f} ({r['k']}/{r['n']})", interval(r["ci"]), interval(r["task_ci"]),
             per_run(r["run_rates"], r["run_progress"]), _progress_text(r["progress"]), str(r["runs"])] for r in rows]


def write_detail(table: list[list[str]], out: str | Path) -> dict[str, Path]:
    """`<out>.csv`, `<out>.md` and `<out>.tex` of detail_lines (a group's line first, its tasks under it)."""
    notes = ["Task-level 95%: percentile bootstrap over the group's tasks (whole tasks resampled), the interval a "
             "group rate needs when one task holds most successes; the Wilson interval treats every rollout as "
             "independent. With several runs (training seeds) runs and tasks are both resampled",
             ("Per run: each run's rate on the split, by its training seed, and its mean progress (rows kept from a "
              "table built before progress was listed per run give the rate alone)"),
             "Policy 'random': uniform random actions on the same tasks, seeds and step limits (the chance level)",
             "RoboGen train: the training scene itself (RoboGen-style tasks start from one fixed "
             "state)"]
    paths = write_table(out, DETAIL_HEAD, table, notes=notes, label="tab:table5-detail",
                        caption="Table 5 per task: success, intervals and mean progress per split.")
    return {p.suffix.lstrip("."): p for p in paths}


COUNT_BAND = (-0.17, -0.035)  # the panels' strip under 0 where each split's successes/rollouts are written
COUNT_Y = (-0.07, -0.135)  # its two lines: train and held-out on the first, eval (between them) on the second


def plot(rows: list[dict], path: str | Path, formats: tuple[str, ...] = ("png", "pdf")) -> list[Path]:
    """Success rate with its Wilson 95% interval per group and split, one panel per pipeline (panels wrap into rows
    of at most GROUPS_PER_ROW groups), successes/rollouts under each interval (in a band below 0, COUNT_BAND, clear
    of the intervals and of the paper's line) and the paper's value as a dashed line
    over its group; where that value is a step-wise reward (GenSim), the eval split's mean progress as an open
    diamond beside the eval success. Written as `path` with each suffix of `formats`. Long because it is one figure
    drawn panel by panel, its bands, labels and keys placed against each other."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from simeval.writing.figures import save_figure

    pipelines = list(dict.fromkeys(r["pipeline"] for r in rows))
    per = {p: [r for r in rows if r["pipeline"] == p] for p in pipelines}
    layout = pack_panels([len(per[p]) for p in pipelines], GROUPS_PER_ROW)
    width = max(sum(len(per[pipelines[k]]) for k in row) for row in layout)
    fig = plt.figure(figsize=(1.6 + GROUP_INCHES * width, 0.6 + 3.6 * len(layout)))
    outer = fig.add_gridspec(len(layout), 1)
    axes_of = {}
    for r_i, row in enumerate(layout):
        sizes = [len(per[pipelines[k]]) for k in row]
        spare = width - sum(sizes)  # an unused column keeps one group as wide in every row
        inner = outer[r_i].subgridspec(1, len(row) + bool(spare), width_ratios=sizes + ([spare] if spare else []))
        for c_i, k in enumerate(row):
            axes_of[pipelines[k]] = fig.add_subplot(inner[0, c_i])
            if c_i:
                axes_of[pipelines[k]].tick_params(labelleft=False)
            else:
                axes_of[pipelines[k]].set_ylabel("success rate\n(Wilson 95% interval)")
    for p, ax in axes_of.items():
        for i, r in enumerate(per[p]):
            ran = False
            for j, (split, (_, color, marker)) in enumerate(PLOT_SPLITS.items()):
                v = r[split]
                if v is None:
                    continue
                ran, x, (lo, hi) = True, i + (j - 1) * 0.27, v["ci"]
                ax.errorbar(x, v["rate"], yerr=[[v["rate"] - lo], [hi - v["rate"]]], fmt=marker, color=color,
                            ms=5, capsize=3, lw=1.4)
                # in a band of their own under the zero line (above each interval they sat on the paper's line),
                # eval's a line lower than its neighbours' so that "28/180" and "25/180" do not run together
                ax.text(x, COUNT_Y[j % 2], f"{v['k']}/{v['n']}", ha="center", va="center", fontsize=6.5,
                        color=color)
            if _draws_progress(r):
                ax.plot(i + 0.13, r["eval_progress"], marker="D", ms=5, mfc="white", mec="C3", ls="none", zorder=3)
            if r["paper"] is not None:
                ax.hlines(r["paper"], i - 0.45, i + 0.45, colors="k", linestyles="--", lw=1.3, zorder=0)
            if not ran:
                ax.text(i, 0.5, "not run", ha="center", va="center", rotation=90, color="0.55", fontsize=8)
        for i in range(1, len(per[p])):
            ax.axvline(i - 0.5, color="0.85", lw=0.8)
        several = len({r["policy"] for r in rows if r["policy"]}) > 1
        short = {CHANCE: "random: chance"}  # the table's long note does not fit under a tick
        ax.set_xticks(range(len(per[p])), [r["group"] + (f"\n({short.get(r['policy'], r['policy'])})"
                                                         if several and r["policy"] else "") for r in per[p]],
                      fontsize=7)
        ax.set_xlim(-0.5, len(per[p]) - 0.5)
        ax.set_ylim(COUNT_BAND[0], 1.12)
        ax.axhspan(*COUNT_BAND, color="0.95", lw=0, zorder=0)
        ax.set_yticks([0, 0.2, 0.4, 0.6, 0.8, 1.0])  # none in the counts' band
        ax.grid(axis="y", alpha=0.3)
        ax.set_title(p)
    handles = [Line2D([], [], color=c, marker=m, ls="-", label=label) for label, c, m in PLOT_SPLITS.values()]
    if any(_draws_progress(r) for r in rows):
        handles.append(Line2D([], [], marker="D", ms=5, mfc="white", mec="C3", ls="none",
                              label="eval progress (GenSim: the paper's quantity)"))
    handles.append(Line2D([], [], color="k", ls="--", label=TABLE5_MEANING))
    # one row of keys needs about LEGEND_ROW_INCHES: a narrower figure (few groups) takes two rows, not a cut legend
    rows_of_keys = 1 if fig.get_figwidth() >= LEGEND_ROW_INCHES else 2
    fig.legend(handles=handles, loc="lower center", ncol=-(-len(handles) // rows_of_keys), fontsize=8, frameon=False)
    policies = sorted({r["policy"] for r in rows if r["policy"]})
    fig.suptitle("Table 5: Diffusion Policy success per task group"
                 + (f" (policy {', '.join(policies)})" if policies else " (no runs)"))
    # the top 0.25 in kept for the title: tight_layout would set the first row's heading against it
    fig.tight_layout(rect=(0, 0.35 * rows_of_keys / fig.get_figheight(), 1, 1 - 0.25 / fig.get_figheight()))
    path = Path(path)
    written = [save_figure(fig, path.with_suffix(f".{fmt}"), dpi=150) for fmt in formats]  # byte-reproducible
    plt.close(fig)
    return written


def pack_panels(sizes: list[int], per_row: int) -> list[list[int]]:
    """Panels (one per pipeline, `sizes[k]` groups each) in order into rows of at most `per_row` groups; a panel
    larger than `per_row` gets a row of its own. Returns the panel indices of each row."""
    rows: list[list[int]] = []
    used = per_row  # no open row yet
    for k, size in enumerate(sizes):
        if used + size > per_row:
            rows.append([])
            used = 0
        rows[-1].append(k)
        used += size
    return rows


def rebuild_table5(root: str | Path | None, out: str | Path, figure: str | Path, *, policy: str | None = None, keep=(),
                   overwrite: bool = False, words: ReportWords = ReportWords()) -> Rebuilt:
    """Table 5, its per-task detail and its figure from every generalization result.json under `root` (see
    simeval.report.rebuild, which the report door calls)."""
    keep_key = words.keep
    kept = read_kept(read_rows, keep, keep_key, "Table 5")
    # each kept table's per-task table beside it (table5.csv -> table5_detail.csv), where there is one
    beside = {Path(path): Path(path).with_name(Path(path).stem + "_detail.csv") for path in keep}
    lacking = [path for path, detail in beside.items() if not detail.is_file()]
    if root is None and lacking:  # without runs, the per-task tables would be written empty
        raise UserError(f"{keep_key}: {lacking[0]} has no {lacking[0].stem}_detail.csv beside it, from which the "
                        "per-task table is drawn when there are no runs; keep the two files together")
    kept_detail = read_kept(read_detail_lines, [d for d in beside.values() if d.is_file()], keep_key,
                            "Table 5 detail")
    records = [] if root is None else read_results(root, metric=METRIC)  # None: the kept tables alone
    if not records and root is not None:  # with keep too: a mistyped root must not pass for "nothing new"
        raise UserError(f"no {METRIC} result.json under {root}: run the policies first (make table5, or "
                        "src/generalization.py), or give the folder that holds them"
                        + kept_only_hint(keep, keep_key, Path(out).with_suffix(".csv")))
    rows = build(records, policy=policy)
    for rows_of_file in kept:
        rows = merge([r for r in rows_of_file if policy in (None, r["policy"]) or not r["runs"]], rows)
    lost = rows_lost(Path(out).with_suffix(".csv"), keep, rows, read_rows,
                     lambda r: (r["pipeline"], r["group"], r["policy"]) if r["runs"] else None, keep_key)
    refuse_committed([*(Path(f"{stem}{x}") for stem in (out, f"{out}_detail") for x in (".csv", ".md", ".tex")),
                      *(Path(figure).with_suffix(x) for x in (".png", ".pdf"))], overwrite, words.overwrite,
                     words.elsewhere, source="the kept tables alone" if root is None else "the runs on disk",
                     lost=lost)
    lines = detail_lines(detail_rows(records, policy=policy))
    for lines_of_file in kept_detail:
        lines = merge_detail([c for c in lines_of_file if policy in (None, c[2].removesuffix(CHANCE_NOTE))], lines)
    rows = eval_progress_from_detail(rows, lines)
    written = write(rows, out)
    detail = write_detail(lines, f"{out}_detail")
    figures = plot(rows, figure)
    return Rebuilt([*written.values(), *detail.values(), *figures], written["md"].read_text(),
                   replaced_notes(lost))

