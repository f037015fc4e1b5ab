"""One flat row per run (and per group, for runs that measure several groups) from result.json records: the table a
notebook loads into a DataFrame (`pandas.DataFrame(run_rows(read_results(root)), columns=COLUMNS)`).

Columns (COLUMNS): metric, pipeline, group, episodes, model, seed, status, statistic, value, ci_low, ci_high, k, n,
per_pixel, path. Per metric, `value` is the run's headline number, named by `statistic`:

    dynamics_diversity  eval_image_error: the world model's eval image error (summed over pixels), per_pixel beside
                        it (protocol=paper); heldout_one_step_error: the one-step prediction error on held-out
                        episodes (protocol=heldout); episodes = training episodes per task; model = world_model preset
    generalization      eval_success: success rate of the eval (varied) split with its Wilson interval and k/n;
                        episodes = training episodes per task; model = policy preset
    text_diversity      div (paper Eq. 1) with its bootstrap interval, one row per group of the run; model =
                        embedding
    quality             task_completion: the mean over tasks of each task's mean score; model = judge
    anything else       one row with value None (the run is listed, its numbers stay in result.json)
"""

from __future__ import annotations

from statistics import fmean

COLUMNS = ("metric", "pipeline", "group", "episodes", "model", "seed", "status", "statistic", "value", "ci_low",
           "ci_high", "k", "n", "per_pixel", "path")


def _base(rec: dict) -> dict:
    ident = rec.get("identity") or {}
    return {c: None for c in COLUMNS} | {
        "metric": rec.get("metric"), "pipeline": ident.get("pipeline"), "group": ident.get("task_group"),
        "seed": ident.get("seed", rec.get("seed")), "status": rec.get("status"), "path": rec.get("path")}


def run_rows(records: list[dict]) -> list[dict]:
    """The rows (dicts with the keys of COLUMNS) of `records`, in their order."""
    rows = []
    for rec in records:
        row, ident, values = _base(rec), rec.get("identity") or {}, rec.get("values")
        values = values if isinstance(values, dict) else {}
        metric = rec.get("metric")
        if metric == "dynamics_diversity" and "prediction" in values:  # protocol=heldout: the one-step error
            one = ((values.get("prediction") or {}).get("summary") or {}).get("one_step") or {}
            row.update(episodes=ident.get("episodes"), model=ident.get("preset"), statistic="heldout_one_step_error",
                       value=(one.get("model") or {}).get("error"),
                       per_pixel=(one.get("model") or {}).get("error_per_pixel"))
        elif metric == "dynamics_diversity":
            ev = values.get("eval") or {}
            row.update(episodes=ident.get("episodes"), model=ident.get("preset"), statistic="eval_image_error",
                       value=ev.get("image_error"), per_pixel=ev.get("image_error_per_pixel"))
        elif metric == "generalization":
            s = ((values.get("splits") or {}).get("eval") or {}).get("success") or {}
            ci = s.get("ci") or (None, None)
            row.update(episodes=ident.get("episodes_per_task"), model=ident.get("policy"), statistic="eval_success",
                       value=s.get("rate"), ci_low=ci[0], ci_high=ci[1], k=s.get("k"), n=s.get("n"))
        elif metric == "text_diversity":
            for group, v in values.items():
                if isinstance(v, dict) and "div" in v:
                    ci = v.get("div_ci") or (None, None)
                    rows.append(row | {"group": group, "model": ident.get("embedding"), "statistic": "div",
                                       "value": v["div"], "ci_low": ci[0], "ci_high": ci[1], "n": v.get("n")})
            continue
        elif metric == "quality":
            means = [t["mean"] for t in (values.get("task_completion") or {}).values()
                     if isinstance(t, dict) and t.get("mean") is not None]
            row.update(model=(rec.get("choices") or {}).get("judge") or rec.get("judge"), statistic="task_completion",
                       value=fmean(means) if means else None, n=len(means))
        rows.append(row)
    return rows
