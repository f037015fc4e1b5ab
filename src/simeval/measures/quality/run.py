"""Single-task quality: scene alignment (1-5) and task completion (0-10) from judges, over task bundles (the format:
simeval.measures.quality.bundle).

Unreadable parts and bad ground truth are a per-task error: the other tasks are still judged and the failures are
reported. A task with no valid score at all (every reply unparseable, or nothing readable) is a failed task; a run
where every task failed has status "failed".

`run_quality` is the whole run as one call (the Hydra entrypoint src/quality.py only builds its arguments).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from simeval.errors import UserError, require_choice
from simeval.judges.prompts import PromptTemplate
from simeval.judges.runner import JudgeItem, ScoreRecord
from simeval.measures.quality.bundle import (METRICS, SCALES, BundleError, TaskBundle, load_bundles,
                                    validate_ground_truth)

log = logging.getLogger(__name__)
VERSION = "1.2"  # 1.1: tasks with no valid score are failed tasks; ground truth validated; progress not clipped;
# 1.2: the oracle scores a recorded success 10 whatever its progress (Meta-World's shaped progress is < 1 at success)


def completion_items(bundles: list[TaskBundle], template: PromptTemplate, n_frames: int = 8
                     ) -> tuple[list[JudgeItem], dict[str, str]]:
    items, errors = [], {}
    for b in bundles:
        try:
            frames = b.trajectory_frames(n_frames)
        except BundleError as e:
            errors[b.name] = str(e)
            continue
        items.append(JudgeItem(b.name, "task_completion", template, {"description": b.description}, frames,
                               SCALES["task_completion"], b.pipeline))
    return items, errors


def alignment_items(bundles: list[TaskBundle], template: PromptTemplate,
                    captions: dict[str, list[str]] | None = None) -> tuple[list[JudgeItem], dict[str, str]]:
    """VLM path (images in the request), or caption path (`captions[task]` = one caption per view, no images)."""
    items, errors = [], {}
    for b in bundles:
        try:
            if captions is None:
                items.append(JudgeItem(b.name, "scene_alignment", template, {"description": b.description},
                                       b.scene_images(), SCALES["scene_alignment"], b.pipeline))
            else:
                if b.name not in captions:
                    raise BundleError(f"{b.name}: no captions")
                text = "\n".join(f"View {i + 1}: {c}" for i, c in enumerate(captions[b.name]))
                items.append(JudgeItem(b.name, "scene_alignment", template,
                                       {"description": b.description, "captions": text}, [], SCALES["scene_alignment"],
                                       b.pipeline))
        except BundleError as e:
            errors[b.name] = str(e)
    return items, errors


def caption_items(bundles: list[TaskBundle], template: PromptTemplate) -> tuple[list[JudgeItem], dict[str, str]]:
    """One captioning request per scene view; the reply is free text (scale unused: any text is valid)."""
    items, errors = [], {}
    for b in bundles:
        try:
            for v, im in enumerate(b.scene_images()):
                items.append(JudgeItem(f"{b.name}#view{v}", "caption", template, {"description": b.description},
                                       [im], None, b.pipeline))
        except BundleError as e:
            errors[b.name] = str(e)
    return items, errors


def oracle_completion(bundles: list[TaskBundle]) -> dict[str, dict]:
    """Completion 0-10 from simulator ground truth: 10 for a recorded success, else 10 x progress (partial reward
    in [0, 1]), else 0 for a recorded failure; nothing recorded is not scored.

    Success decides before progress because a task's success criterion is its definition of complete, and some
    sources' progress is a shaped reward that stays below 1 at success (Meta-World's reward / 10: 0.66-0.9 on
    successful expert episodes of shelf-place, pick-place, button-press-topdown)."""
    out = {}
    for b in bundles:
        gt = validate_ground_truth(b.ground_truth, str(b.path))
        if gt.get("success") is True:
            score = 10.0
        elif "progress" in gt:
            score = 10.0 * gt["progress"]
        elif "success" in gt:
            score = 0.0
        else:
            continue
        out[b.name] = {"mean": score, "var": None, "n_valid": 1, "n_invalid": 0, "scores": [score]}
    return out


def summarize(records: list[ScoreRecord]) -> dict[str, dict[str, dict]]:
    """{metric: {item: {mean, var (sample, ddof=1, as the paper's parentheses), n_valid, n_invalid, scores}}}.
    (The 5-repeat variances of the paper's tables match ddof=1, e.g. scores 0,0,0,0,2 give its "0.40 (0.80)".)"""
    out: dict[str, dict[str, dict]] = {}
    for rec in records:
        entry = out.setdefault(rec.metric, {}).setdefault(rec.item, {"scores": [], "n_invalid": 0})
        if rec.valid:
            entry["scores"].append(rec.score)
        else:
            entry["n_invalid"] += 1
    for per_item in out.values():
        for entry in per_item.values():
            s = np.asarray(entry["scores"], dtype=float)
            entry["n_valid"] = int(len(s))
            entry["mean"] = float(s.mean()) if len(s) else None
            entry["var"] = float(s.var(ddof=1)) if len(s) >= 2 else None  # ddof=1 is undefined for one score
    return out


def check_metric_and_mode(metric: str, mode: str) -> None:
    require_choice("metric", metric, (*METRICS, "all"))
    require_choice("scene_alignment_mode", mode, ("vlm", "caption"))


@dataclass
class ModelJudge:
    """A model judge's parts (model_judge builds them from conf/quality.yaml): its `provider` (an OpenAI-compatible
    HTTP client or a local transformers model), the prompt `templates` by name, the call `cache` (JudgeCache), the
    cost `ledger` (Ledger) and the runner's `settings` (JudgeSettings: repeats, re-asks, concurrency, rate, replay);
    for scene alignment by captions also a `captioner` and its `caption_settings`."""

    provider: Any
    templates: dict
    cache: Any
    ledger: Any
    settings: Any
    captioner: Any = None
    caption_settings: Any = None


@dataclass(frozen=True)
class Scoring:
    """What is scored: `metric` (scene_alignment, task_completion or all), scene alignment's `mode` (vlm: the
    judge sees the 4 views; caption: a captioner describes them and the judge reads the captions) and the
    `n_frames` of a trajectory task completion sees."""

    metric: str = "all"
    mode: str = "vlm"
    n_frames: int = 8


def evaluate_quality(bundles: list[TaskBundle], judge: ModelJudge, scoring: Scoring = Scoring(),
                     dry: bool = False) -> dict:
    """Judge the bundles. Returns {"records": [ScoreRecord], "summary": summarize(...), "errors": {task: msg},
    "captions": {task: [..]}} or, with `dry`, {"dry_run": {...}, "errors": ...} (every bundle that would be
    skipped is in errors: its images are read, nothing is sent)."""
    from simeval.judges.runner import dry_run, run_judge

    metric, mode, n_frames = scoring.metric, scoring.mode, scoring.n_frames
    provider, templates, cache, ledger, settings = judge.provider, judge.templates, judge.cache, judge.ledger, \
        judge.settings
    captioner, caption_settings = judge.captioner, judge.caption_settings
    check_metric_and_mode(metric, mode)
    wanted = METRICS if metric == "all" else (metric,)
    items, errors, captions, records, plan = [], {}, None, [], {}
    if "scene_alignment" in wanted and mode == "caption":
        if captioner is None:
            raise UserError("scene_alignment_mode=caption needs a captioner (captioner=openai or captioner=hf)")
        cap_items, cap_errors = caption_items(bundles, templates["caption"])
        errors.update(cap_errors)
        if dry:
            plan = {"captions": dry_run(cap_items, captioner, cache, ledger, caption_settings),
                    "note": "judge calls on captions follow the captions"}
        else:
            cap_records = run_judge(cap_items, captioner, cache, ledger, caption_settings)
            captions = {}
            for rec in cap_records:
                task = rec.item.split("#view")[0]
                if rec.text is None:
                    errors[task] = f"captioner gave no caption for {rec.item}"
                    continue
                captions.setdefault(task, []).append(rec.text)
            captions = {t: c for t, c in captions.items() if t not in errors}
            records += cap_records
            al, al_err = alignment_items([b for b in bundles if b.name in captions],
                                         templates["scene_alignment_captions"], captions)
            items += al
            errors.update(al_err)
    elif "scene_alignment" in wanted:
        al, al_err = alignment_items(bundles, templates["scene_alignment_vlm"])
        items += al
        errors.update(al_err)
    if "task_completion" in wanted:
        tc, tc_err = completion_items(bundles, templates["task_completion"], n_frames)
        items += tc
        errors.update({k: (errors[k] + "; " + v if k in errors else v) for k, v in tc_err.items()})
    if dry:
        return {"dry_run": {**plan, **dry_run(items, provider, cache, ledger, settings)}, "errors": errors}
    records += run_judge(items, provider, cache, ledger, settings)
    summary = summarize([r for r in records if r.metric != "caption"])
    return {"records": records, "summary": summary, "errors": errors, "captions": captions}


def no_score_errors(summary: dict[str, dict[str, dict]], records: list[ScoreRecord]) -> dict[str, str]:
    """{task: message} for every (task, metric) whose replies held no valid score, e.g. "task_completion: no
    valid score in 15 replies (last: no 'Score: X' in reply)"."""
    asks: dict[tuple[str, str], list[dict]] = {}
    for r in records:
        asks.setdefault((r.metric, r.item), []).extend(r.asks)
    out: dict[str, str] = {}
    for metric, per_item in summary.items():
        for task, entry in per_item.items():
            if entry["n_valid"]:
                continue
            replies = asks.get((metric, task), [])
            last = next((a["error"] for a in reversed(replies) if a.get("error")), None)
            msg = f"{metric}: no valid score in {len(replies)} replies" + (f" (last: {last})" if last else "")
            out[task] = out[task] + "; " + msg if task in out else msg
    return out


def judge_reliability(records: list[ScoreRecord]) -> dict[str, dict]:
    """Per metric, agreement of the judge with itself across repeats: Krippendorff's alpha (interval; invalid
    replies are missing values) and ICC(1,1) on complete items. None where undefined (e.g. constant scores)."""
    from simeval.measures.agreement.metric import icc_1_1, krippendorff_alpha_interval

    out = {}
    for metric in dict.fromkeys(r.metric for r in records if r.metric != "caption"):
        recs = [r for r in records if r.metric == metric]
        items = list(dict.fromkeys(r.item for r in recs))
        repeats = max(r.repeat for r in recs) + 1
        x = np.full((len(items), repeats), np.nan)
        for r in recs:
            if r.score is not None:
                x[items.index(r.item), r.repeat] = r.score
        out[metric] = {"krippendorff_alpha": krippendorff_alpha_interval(x), "icc_1_1": icc_1_1(x),
                       "items": len(items), "repeats": repeats}
    return out


def resolve_bundles_dir(bundles_dir: str | None, episodes: dict | None, out_dir: Path) -> Path:
    """The bundles to judge: `bundles_dir`, or the episodes of a store (`episodes["store"]`) exported as bundles
    into `<out_dir>/bundles` (the other `episodes` keys go to export_bundles). A VLM judge needs the images."""
    episodes = episodes or {}
    if episodes.get("store"):
        from simeval.measures.quality.episode_bundles import export_bundles

        target = Path(out_dir) / "bundles"
        export_bundles(episodes["store"], target, **{k: v for k, v in episodes.items() if k != "store"})
        return target
    if not bundles_dir:
        raise UserError("set bundles_dir=DIR (or env SIMEVAL_BUNDLES), or episodes.store=DIR (an episode store)")
    return Path(bundles_dir)


def write_scores(path: Path, records: list[ScoreRecord]) -> Path:
    """Per-item provenance, one strict JSON line (no NaN) per (task, metric, repeat): model, template and image
    hashes, every raw reply with its parse and latency, the accepted score."""
    import dataclasses

    from simeval.results import atomic_write_text, dumps_strict

    lines = [dumps_strict(dataclasses.asdict(r) | {"valid": r.valid}) for r in records]
    return atomic_write_text(path, "\n".join(lines) + ("\n" if lines else ""))


@dataclass
class QualityOutcome:
    """What a run did. `status`: ok (at least one task scored), failed (every task failed: no valid score at all),
    dry_run (nothing sent; `plan` says what would be). `summary` is the one line the entrypoint logs; `error` the
    one line it prints when the run failed."""
    status: str
    values: dict
    errors: dict[str, str]
    scored: list[str]
    failed: list[str]
    summary: str
    cost: dict | None = None
    plan: dict | None = None
    error: str | None = None
    records: list = field(default_factory=list)
    result_path: Path | None = None


def _tasks_and_errors(judge: str, bundles_dir, episodes: dict | None, out_dir: Path):
    if judge == "oracle" and (episodes or {}).get("store"):  # ground truth from the store's metadata: no export
        from simeval.measures.quality.episode_bundles import store_tasks

        return store_tasks(episodes["store"], **{k: v for k, v in episodes.items()
                                                 if k in ("pipeline", "group", "per_task", "camera")})
    return load_bundles(resolve_bundles_dir(bundles_dir, episodes, out_dir))


def _outcome_of(values: dict, names: list[str], errors: dict[str, str]) -> tuple[list[str], list[str]]:
    scored = sorted({t for per_item in values.values() for t, e in per_item.items() if e.get("n_valid")})
    failed = sorted(set(names) - set(scored))
    return scored, failed


def _summary_line(judge: str, scored: list[str], failed: list[str], cost: dict | None) -> str:
    n = len(scored) + len(failed)
    line = f"quality ({judge}): {n} tasks, {len(scored)} scored, {len(failed)} failed"
    if failed:
        line += f" ({', '.join(failed[:5])}{', ...' if len(failed) > 5 else ''})"
    if cost is not None:
        line += (f"; {cost['new_calls']} new calls (${cost['cost_usd']:.4f}), {cost['invalid_calls']} of them paid "
                 f"for nothing (no valid score, ${cost['invalid_cost_usd']:.4f}); {cost['cached_calls']} cached")
    return line


def _means_line(values: dict) -> str:
    """'; task_completion 9.73 (mean of 750)': each metric's mean over the items it scored, so the run's headline
    number is in its log, not only in result.json."""
    parts = []
    for metric, per_item in sorted(values.items()):
        means = [e["mean"] for e in per_item.values() if e.get("n_valid") and e.get("mean") is not None]
        if means:
            parts.append(f"{metric} {sum(means) / len(means):.2f} (mean of {len(means)})")
    return "".join(f"; {p}" for p in parts)


def log_task_table(logger, result_path: Path) -> None:
    """`quality/tasks` (per-task scores with the scene views and judged frames, lowest first), rebuilt from the
    written result.json as every report table is. The run's result is already written: a table that cannot be drawn
    is a warning, not a failed run."""
    import json

    from simeval.measures.quality.task_media import quality_task_table

    rec = {**json.loads(Path(result_path).read_text()), "path": str(result_path)}
    try:
        logger.log_table("quality/tasks", *quality_task_table(rec))
    except Exception as e:  # noqa: BLE001 (any drawing failure: the scores are safe in result.json)
        log.warning("quality/tasks table not logged: %s: %s", type(e).__name__, e)


def model_judge(provider, captioner, *, judge: Mapping, captioner_settings: Mapping, prompts: Mapping[str, str],
                cache_dir: str | os.PathLike, budget_usd: float | None, repeats: int, max_reasks: int) -> ModelJudge:
    """run_quality's ModelJudge (the oracle needs none): `provider` (and `captioner`, None for
    none: it captions each view once and every judge repeat reuses it) with conf/quality.yaml's `judge` and
    `captioner` sections as plain mappings (prices, concurrency, rate_limit_per_min, replay), the prompt template
    files by name, the call cache in `cache_dir` and a cost ledger stopped at `budget_usd`."""
    from simeval.judges import cache, ledger, prompts as prompt_files, runner

    out = ModelJudge(provider, {k: prompt_files.load_template(v) for k, v in prompts.items()},
                     cache.JudgeCache(Path(cache_dir) / "judge_calls.sqlite"),
                     ledger.Ledger(ledger.Prices(**judge["prices"]), budget_usd),
                     runner.JudgeSettings(repeats, max_reasks, judge["concurrency"], judge["rate_limit_per_min"],
                                          judge["replay"]))
    if captioner is not None:
        out.captioner, out.caption_settings = captioner, runner.JudgeSettings(
            1, max_reasks, captioner_settings["concurrency"], captioner_settings["rate_limit_per_min"], judge["replay"])
    return out


def run_quality(out_dir: str | os.PathLike, *, bundles_dir: str | os.PathLike | None = None,
                episodes: dict | None = None, judge: ModelJudge | str, scoring: Scoring = Scoring(),
                dry_run: bool = False, logger=None, meta: dict | None = None) -> QualityOutcome:
    """One quality run, writing `<out_dir>/result.json` (and scores.jsonl for a model judge).

    Tasks come from `bundles_dir`, or from an episode store (`episodes={"store": DIR, "pipeline", "group",
    "per_task", "camera", "max_frames"}`): `judge="oracle"` reads the store's ground truth directly; a model
    judge (a ModelJudge) gets the episodes exported as bundles into `<out_dir>/bundles`. `meta` is added to
    result.json (config, choices,
    seed, overrides, label); `logger` (anything with log_metrics) gets the cost, and, when it keeps tables
    (`wants_tables`), the per-task table (log_task_table).
    A budget or replay stop writes status "stopped" with what finished and re-raises."""
    from simeval.results import write_result

    model = judge if isinstance(judge, ModelJudge) else None
    if model is None and judge != "oracle":
        raise UserError(f"judge {judge!r}: expected a ModelJudge or 'oracle'")
    judge = "model" if model is not None else "oracle"  # the kind result.json records
    _check_scoring(scoring)
    out_dir = Path(out_dir)
    bundles, errors = _tasks_and_errors(judge, bundles_dir, episodes, out_dir)
    names = [b.name for b in bundles] + [k for k in errors if k not in {b.name for b in bundles}]
    result = dict(metric="quality", version=VERSION, judge=judge, **(meta or {}),
                  tasks={b.name: {"pipeline": b.pipeline} for b in bundles})
    if judge == "oracle":
        scores = _oracle_scores(bundles, names, errors, dry_run)
    else:
        scores = _model_scores(bundles, names, errors, model, scoring, dry_run, out_dir, result)
    if isinstance(scores, QualityOutcome):  # a dry run's plan
        return scores
    values, records, cost, extra = scores
    scored, failed = _outcome_of(values, names, errors)
    summary = _summary_line(judge, scored, failed, cost) + _means_line(values)
    status, error = "ok", None
    if not scored:
        status = "failed"
        first = failed[0] if failed else None
        error = (f"every task failed ({len(failed)} of {len(names)}; {first}: {errors.get(first, 'not scored')})"
                 + (f"; {cost['invalid_calls']} new calls paid for nothing" if cost else "")
                 + f"; details in {out_dir / 'result.json'}")
    path = write_result(out_dir, values=values, errors=dict(sorted(errors.items())), status=status,
                        **({"error": error} if error else {}), scored=len(scored), failed=failed, summary=summary,
                        **extra, **result)
    if logger is not None and cost is not None:
        logger.log_metrics({"cost": cost})
    if logger is not None and values and getattr(logger, "wants_tables", False):
        log_task_table(logger, path)
    return QualityOutcome(status, values, errors, scored, failed, summary, cost=cost, error=error, records=records,
                          result_path=path)


def _check_scoring(scoring: Scoring) -> None:
    n_frames = scoring.n_frames
    if isinstance(n_frames, bool) or not isinstance(n_frames, int) or n_frames < 2:
        raise UserError(f"n_frames must be a whole number >= 2 (first and last frame at least), got {n_frames!r}")
    check_metric_and_mode(scoring.metric, scoring.mode)  # the oracle ignores both; a typo is still a mistake


def _oracle_scores(bundles, names: list, errors: dict, dry_run: bool):
    """The store's ground truth as scores: (values, records, cost, extra), or a dry run's QualityOutcome."""
    values = {"task_completion": oracle_completion(bundles)}
    errors.update({b.name: "no ground truth (success or progress) recorded" for b in bundles
                   if b.name not in values["task_completion"]})
    if dry_run:
        plan = {"calls": 0, "bundles": len(names), "skipped": len(errors), "skip": dict(sorted(errors.items()))}
        return QualityOutcome("dry_run", {}, errors, [], [], f"dry run: {len(errors)} of {len(names)} tasks "
                              f"skipped (see skip)", plan=plan)
    return values, [], None, {}


def _model_scores(bundles, names: list, errors: dict, model: ModelJudge, scoring: Scoring, dry_run: bool,
                  out_dir: Path, result: dict):
    """The model judge's scores (scores.jsonl written): (values, records, cost, extra), or a dry run's
    QualityOutcome. A budget or replay stop writes status "stopped" with what finished and re-raises."""
    from simeval.judges.ledger import BudgetExceeded
    from simeval.judges.runner import ReplayMiss
    from simeval.results import write_result

    try:
        out = evaluate_quality(bundles, model, scoring, dry=dry_run)
    except (BudgetExceeded, ReplayMiss) as e:  # keep what finished (it is cached too), then stop loudly
        write_result(out_dir, values=summarize(getattr(e, "partial", [])), errors=errors,
                     cost=model.ledger.totals(),
                     status="stopped", stopped=str(e), **result)
        raise
    errors.update(out["errors"])
    if dry_run:
        plan = {**out["dry_run"], "bundles": len(names), "skipped": len(errors),
                "skip": dict(sorted(errors.items()))}
        return QualityOutcome("dry_run", {}, errors, [], [], f"dry run: {plan['calls']} calls; {len(errors)} "
                              f"of {len(names)} bundles skipped in part or whole (see skip)", plan=plan)
    records, values = out["records"], out["summary"]
    for task, msg in no_score_errors(values, records).items():
        errors[task] = errors[task] + "; " + msg if task in errors else msg
    write_scores(out_dir / "scores.jsonl", records)
    cost = model.ledger.totals()
    return values, records, cost, {"cost": cost, "reliability": judge_reliability(records)}
