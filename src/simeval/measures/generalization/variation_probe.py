"""Which scenes does an `eval` variation change? Before training a policy for hours: reset each eval task of a
group at the evaluation seeds under its train variation and under its eval variation, and compare the first
observations (every camera's pixels and the state, simeval.measures.generalization.rollouts.observation_digest), as
src/generalization.py does before it rolls an eval seed out. Nothing is trained and nothing rolled out.

    python src/generalization_tools.py variation-probe [--out-dir DIR] [--overwrite] <generalization overrides>
      e.g. pipeline=gensim_own pipeline.root=../shared/gensim task_group=placement eval.seeds=4
      -> DIR (default paths.tables: <paths.root>/tables)/eval_variation_<pipeline>_<group>.md / .json: per eval
         task, the seeds whose first observation the variation changed (the rest would be recorded unvaried: the
         eval split would read the train split there), and the knobs no first observation shows (friction: such a
         task is rolled out on every seed). One name per pipeline and group whatever tasks= selects: an existing
         table is kept unless --overwrite (the table records its overrides).

The overrides are src/generalization.py's (conf/generalization.yaml), checked as it checks them, so the probe
reads the eval split of the run it stands for: its pipeline, group, tasks, held-out tasks, eval.variation,
eval.seeds, eval.seed_offset, eval.max_steps and the policy's cameras, frame size and action space (eval.splits
is not read: the probe is about the eval split).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from simeval.cli import OneLineParser
from simeval.errors import UserError
from simeval.results import atomic_write_text, dumps_strict


def plan(pipeline, task_group: str, tasks, heldout_tasks, evaluation: dict, model: dict
         ) -> tuple[list, dict, list[int], str]:
    """What the probe resets, every setting checked as src/generalization.py checks it (nothing reset yet):
    ([(eval task, its eval variation)], {task: its train variation}, the eval seeds, the policy's action space)."""
    from simeval.errors import require_whole
    from simeval.measures.generalization.run import eval_override, names, resolve_action_space

    require_whole("eval.seeds", evaluation["seeds"], 1)
    require_whole("eval.seed_offset", evaluation["seed_offset"], 0)
    if evaluation["max_steps"] is not None:
        require_whole("eval.max_steps", evaluation["max_steps"], 1)
    specs, heldout = pipeline.group_and_heldout(task_group, tasks, names(heldout_tasks))
    train = {s.name: dict(v or {}) for s, v in pipeline.split_tasks(specs, "train", heldout)}
    pairs = [(s.name, dict(v or {})) for s, v in pipeline.split_tasks(specs, "eval", heldout,
                                                                         eval_override=eval_override(evaluation))]
    if not pairs:
        raise UserError(f"task_group={task_group}: no task of the group has an eval variation; nothing to probe")
    seeds = list(range(evaluation["seed_offset"], evaluation["seed_offset"] + evaluation["seeds"]))
    return pairs, train, seeds, resolve_action_space(model["action_space"], specs)


def probe(pipeline, pairs: list, train: dict, seeds: list[int], max_steps: int | None, model: dict,
          action_space: str) -> list[dict]:
    """Per eval task of `pairs` (plan's): {"task", "train_variation", "eval_variation", "seeds", "varied":
    [seed...], "unseen_knobs": [...]} (varied: the seeds whose first observation under the eval variation differs
    from the train variation's)."""
    from simeval.measures.generalization.rollouts import first_observations
    from simeval.measures.generalization.random_baseline import RandomActions

    # the observation the policy would see: its cameras and frame size (the action space only picks the env)
    actor = RandomActions(action_space, model["cameras"], model["image_size"])
    rows = []
    for task, variation in pairs:
        before = first_observations(actor, task, seeds, variation=train.get(task, {}), max_steps=max_steps,
                                    make_env=pipeline.make_env)
        after = first_observations(actor, task, seeds, variation=variation, max_steps=max_steps,
                                   make_env=pipeline.make_env)
        rows.append({"task": task, "train_variation": train.get(task, {}), "eval_variation": variation,
                     "seeds": seeds, "varied": [s for s in seeds if before[s] != after[s]],
                     "unseen_knobs": pipeline.unseen_knobs(variation)})
        print(f"{task}: {len(rows[-1]['varied'])} of {len(seeds)} scenes changed", flush=True)
    return rows


def markdown(rows: list[dict], pipeline: str, task_group: str, overrides: list[str]) -> str:
    lines = [f"# Eval variation probe: {pipeline} / {task_group}", "",
             f"`python src/generalization_tools.py variation-probe {' '.join(overrides)}`", "",
             "| task | eval variation | scenes changed | seeds changed | knobs no first observation shows |",
             "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['task']} | `{json.dumps(r['eval_variation'], sort_keys=True)}` | "
                     f"{len(r['varied'])}/{len(r['seeds'])} | {', '.join(map(str, r['varied'])) or '-'} | "
                     f"{', '.join(r['unseen_knobs']) or '-'} |")
    changed = sum(len(r["varied"]) for r in rows)
    total = sum(len(r["seeds"]) for r in rows)
    unvaried = ("none would be left out as unvaried" if changed == total else
                "src/generalization.py records the others as unvaried and does not roll them out, except in a task "
                "with knobs no first observation shows (rolled out on every seed)")
    lines += ["", (f"- {changed} of {total} eval scenes differ from the train scene at the same seed (first "
                   f"observation: every camera's pixels and the state): {unvaried}.")]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None, conf_dir: Path = Path("conf")) -> None:
    """The probe above; `conf_dir` is the entrypoint's conf/ (src/generalization_tools.py passes it)."""
    ap = OneLineParser(prog="generalization_tools.py variation-probe", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out-dir", default=None, help="where the tables go (default: paths.tables, i.e. "
                    "<paths.root>/tables)")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing probe table")
    ap.add_argument("overrides", nargs="*", help="src/generalization.py's overrides")
    a = ap.parse_args(argv)
    a.conf_dir = conf_dir
    try:
        run(a)
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(2) from None


def run(a) -> None:
    from simeval.measures.generalization.offline import compose_generalization
    from simeval.pipelines.registry import pipeline_from_config

    cfg = compose_generalization(a.overrides, a.conf_dir)
    pipeline = pipeline_from_config(cfg["pipeline"])
    pairs, train, seeds, action_space = plan(pipeline, cfg["task_group"], cfg["tasks"], cfg["heldout_tasks"],
                                             cfg["eval"], cfg["policy"]["model"])
    out_dir = Path(a.out_dir or cfg["paths"]["tables"])
    name = f"eval_variation_{cfg['pipeline']['name']}_{cfg['task_group']}"
    md, js = out_dir / f"{name}.md", out_dir / f"{name}.json"
    if not a.overwrite and (existing := [str(p) for p in (md, js) if p.exists()]):
        raise UserError(f"{', '.join(existing)}: already there; pass --overwrite to replace it, or --out-dir elsewhere")
    rows = probe(pipeline, pairs, train, seeds, cfg["eval"]["max_steps"], cfg["policy"]["model"], action_space)
    md.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(js, dumps_strict({"overrides": a.overrides, "pipeline": cfg["pipeline"]["name"],
                                        "task_group": cfg["task_group"], "tasks": rows}))
    atomic_write_text(md, markdown(rows, cfg["pipeline"]["name"], cfg["task_group"], a.overrides))
    print(f"wrote {md} and {js}")
