"""A scorecard of one pipeline's episodes in the store: every aspect simeval measures that the episodes allow, each
beside the committed reference rows (simeval.report.scorecard). See conf/evaluate.yaml.

The measures run as the entrypoints a user would type (src/quality.py, src/diversity.py, src/generalization.py),
as subprocesses writing into `out`/<stage>-<key>/ (the key: the stage's settings and the episodes), so a
scorecard's numbers are those runs' result.json files and a finished stage with the same key is not run again.
Text diversity runs here (one embedding call)."""

import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

from simeval.cli import exit_cleanly_on_user_error, launch
from simeval.errors import REFUSAL_FILE_ENV, UserError, read_refusal

log = logging.getLogger("evaluate")
SRC = Path(__file__).resolve().parent


def _stage(cmd: list[str], log_path: Path) -> tuple[str, bool] | None:
    """Run an entrypoint; None when it finished, else (why it stopped, whether the episodes cannot serve the
    measure: simeval.errors.EpisodesUnfit, recorded through REFUSAL_FILE_ENV). Why: its one-line error, or for a
    run that stopped otherwise its exit status and last line; with its log."""
    log_path.parent.mkdir(parents=True, exist_ok=True)
    refusal = log_path.with_suffix(".refusal.json")
    refusal.unlink(missing_ok=True)
    with log_path.open("a") as f:
        res = subprocess.run([sys.executable, *cmd], stdout=f, stderr=subprocess.STDOUT,
                             env={**os.environ, REFUSAL_FILE_ENV: str(refusal)})
    if res.returncode == 0:
        return None
    said = read_refusal(refusal)
    if said is not None and said.get("episodes_unfit") is True:
        return f"{said['error']} (log {log_path})", True
    if said is not None:
        return f"{Path(cmd[0]).name}: {said['error']} (log {log_path})", False
    tail = [x for x in log_path.read_text().strip().splitlines() if x.strip()][-1:] or ["(no output)"]
    return (f"{Path(cmd[0]).name} stopped (exit {res.returncode}; log {log_path}): {tail[0].removeprefix('error: ')}",
            False)


def _stage_dir(out: Path, stage: str, settings: dict) -> Path:
    """The folder of a stage's runs, named by what its numbers depend on (its settings and the episodes' list): a
    rerun with the same ones reuses them, one with others runs anew beside them."""
    import hashlib

    key = hashlib.sha1(json.dumps(settings, sort_keys=True, default=str).encode()).hexdigest()[:10]
    return out / f"{stage}-{key}"


def _fingerprint(metas) -> list:
    return sorted((m["task"], int(m["seed"]), int(m["n_steps"]), bool(m["success"]), m.get("variation_id", ""),
                   m["description"]) for m in metas)


def _text(metas, cfg) -> dict:
    from hydra.utils import instantiate

    from simeval.measures.text_diversity.run import text_diversity_by_group
    from simeval.embeddings import CachedEmbedder, EmbeddingCache
    from simeval.report.scorecard import aspect
    from simeval.pipelines.task_records import TaskText

    texts = {}
    for m in metas:
        texts.setdefault(m["description"], m["task"])
    if len(texts) < 2:
        return aspect("text_diversity", "no reading", f"{len(texts)} distinct task text; Eq. 1 needs at least 2")
    tasks = [TaskText(pipeline=cfg.episodes.pipeline, group="all", name=name, description=text, text=text)
             for text, name in texts.items()]
    Path(cfg.cache_dir).mkdir(parents=True, exist_ok=True)
    embedder = CachedEmbedder(instantiate(cfg.embedding.backend), EmbeddingCache(f"{cfg.cache_dir}/embeddings.sqlite"))
    v = text_diversity_by_group(tasks, embedder.encode, "all", subsample_n=None)["all"]
    lo, hi = v["div_ci"] if "div_ci" in v else (None, None)
    interval = f" [{lo:.2f}, {hi:.2f}]" if lo is not None else ""
    n_tasks = len({m["task"] for m in metas})
    return aspect("text_diversity", "reads", f"{v['div']:.2f}{interval} over {len(texts)} distinct task texts of "
                  f"{n_tasks} task{'s' * (n_tasks != 1)} ({cfg.embedding.name})", value=float(v["div"]))


def _quality(metas, cfg, out: Path, per_task: int) -> dict:
    from simeval.report.scorecard import aspect

    if not all(m["success_known"] for m in metas):
        unknown = sum(not m["success_known"] for m in metas)
        return aspect("quality", "skipped", f"{unknown} of {len(metas)} episodes record no success, so the oracle "
                      "judge cannot score them; a VLM judge can: python src/quality.py judge=openai "
                      f"episodes.store={cfg.episodes.store} episodes.pipeline={cfg.episodes.pipeline}")
    args = ["judge=oracle", f"episodes.store={cfg.episodes.store}", f"episodes.pipeline={cfg.episodes.pipeline}",
            f"episodes.group={cfg.episodes.group}", f"episodes.per_task={per_task}", *cfg.quality.overrides]
    run = _stage_dir(out, "quality", {"args": args, "episodes": _fingerprint(metas)})
    if not (run / "result.json").is_file():
        stopped = _stage([str(SRC / "quality.py"), *args, f"cache_dir={cfg.cache_dir}", f"hydra.run.dir={run}"],
                         out / "logs" / "quality.log")
        if stopped:  # a judge that cannot run is a mistake to fix, not a reading: the last card stays as it was
            raise UserError(stopped[0])
    values = json.loads((run / "result.json").read_text())["values"]
    scores = [v["mean"] for v in values.get("task_completion", {}).values() if v.get("mean") is not None]
    mean = sum(scores) / len(scores) if scores else None
    if mean is None:
        return aspect("quality", "no reading", f"the oracle judge scored no task (see {run / 'result.json'})")
    return aspect("quality", "reads", f"{mean:.2f} / 10 task completion (oracle judge, recorded success; "
                  f"{len(scores)} episodes scored)", value=float(mean))


def _dynamics(metas, cfg, out: Path, camera: str, n: int, settings: tuple[int, list[int], list[int]]) -> dict:
    """Table 4 held-out on the last `held` of the `n` episodes every task has (the fewest any task has)."""
    from simeval.report.scorecard import aspect

    held, wanted, seeds = settings
    counts = [k for k in wanted if k + held <= n]
    if not counts:
        return aspect("dynamics_diversity", "no reading", f"{n} episodes per task (fewest); the held-out protocol "
                      f"needs {wanted[0]} to train on and {held} to score (dynamics.counts, dynamics.heldout)")
    args = ["pipeline=custom", f"pipeline.name={cfg.episodes.pipeline}", f"task_group={cfg.episodes.group}",
            f"camera={camera}", f"store={cfg.episodes.store}", f"eval_episodes=[{n - held + 1},{n}]",
            f"episodes={','.join(map(str, counts))}", f"seed={','.join(map(str, seeds))}",
            *([f"debug={cfg.dynamics.debug}"] if cfg.dynamics.debug != "none" else []), *cfg.dynamics.overrides]
    sweep = _stage_dir(out, "dynamics", {"args": args, "episodes": _fingerprint(metas)})
    if len(list(sweep.glob("*/result.json"))) < len(counts) * len(seeds):
        stopped = _stage([str(SRC / "diversity.py"), "-m", *args, f"hydra.sweep.dir={sweep}"],
                         out / "logs" / "dynamics.log")
        if stopped and not stopped[1]:  # a value of dynamics.* refused: a mistake to fix, as quality's
            raise UserError(stopped[0])
        if stopped:  # the episodes cannot serve the world model: no reading, and the card is still written
            return aspect("dynamics_diversity", "no reading", "the episodes cannot serve the world model: "
                          f"{stopped[0]}; its settings go through dynamics.overrides, e.g. "
                          "'dynamics.overrides=[\"world_model.window.pad_end=true\"]'")
    from simeval.measures.dynamics_diversity.table4_heldout import build
    from simeval.results import read_results

    rows = build([r for r in read_results(sweep, "dynamics_diversity") if r.get("status", "ok") == "ok"])
    if not rows:
        return aspect("dynamics_diversity", "no reading", f"no held-out run under {sweep}")
    row = rows[0]

    def short(verdict: str) -> str:  # the verdict without its numbers (the sweep's table has them)
        return verdict if verdict == "reads" else verdict.split(" (skill")[0].split(" on ")[0]

    pixel = "; ".join(f"{k}: {short(row[f'gate_{k}'])}" for k in counts)
    state = "; ".join(f"{k}: {short(row[f'state_gate_{k}'])}" for k in counts if f"state_gate_{k}" in row)
    fall = row.get("fall_verdict", "")
    fall = f"; its fall {counts[0]} -> {counts[-1]}: {fall}" if fall and not fall.startswith("no reading") else ""
    reads = [k for k in counts if row[f"gate_passes_{k}"] or row.get(f"state_gate_passes_{k}")]
    line = (f"pixel reading by training episodes per task, {pixel}{fall}" + (f"; state reading, {state}" if state else
            "") + f" (held-out episodes {n - held + 1}-{n} of each task; numbers: {sweep.name}/table4_heldout.md)")
    return aspect("dynamics_diversity", "reads" if reads else "no reading", line)


def _generalization(cfg, out: Path, camera: str, per_task: int, groups: list[str]) -> dict:
    """Table 5 on each group of the pipeline (its policy and the random baseline), where it has an environment."""
    from simeval.report.scorecard import aspect

    if not cfg.environment:
        return aspect("generalization", "skipped", "no environment to roll a policy out in (imported episodes have "
                      "none; a pipeline with one: environment=<its pipeline config>)")
    from hydra.core.hydra_config import HydraConfig

    searchpath = list(HydraConfig.get().searchpath)
    common = [f"pipeline={cfg.environment}", f"store={cfg.episodes.store}", f"policy.model.cameras=[{camera}]",
              f"eval.video_camera={camera}", *([f"hydra.searchpath=[{','.join(searchpath)}]"] if searchpath else [])]
    if cfg.generalization.debug != "none":
        sizes = [f"debug={cfg.generalization.debug}"]
    else:  # the paper's 40 demonstrations per task where the store has them, 2 more for the sampler check
        sizes = [f"episodes_per_task={min(40, per_task - 2)}", "val_episodes_per_task=2"]
    lines, rates = [], []
    for group in groups:
        runs = {"policy": [*common, f"task_group={group}", *sizes, *cfg.generalization.overrides]}
        if cfg.generalization.random_baseline:  # chance: the same rollouts with uniform random actions
            runs["random"] = [*common, f"task_group={group}", "policy=random",
                              *(["eval.seeds=1", "eval.max_steps=40"] if cfg.generalization.debug != "none" else [])]
        parts = []
        for name, run_args in runs.items():
            folder = _stage_dir(out, f"generalization_{name}", {"args": run_args})
            if not (folder / "result.json").is_file():
                stopped = _stage([str(SRC / "generalization.py"), *run_args, f"checkpoint_dir={out / 'policies'}",
                                  f"hydra.run.dir={folder}"], out / "logs" / f"generalization_{name}.log")
                if stopped:  # the environment or the policy could not run: a mistake to fix, not a reading
                    raise UserError(stopped[0])
            splits = json.loads((folder / "result.json").read_text())["values"]["splits"]
            shown = []
            for split in ("eval", "train", "heldout"):
                if split in splits:
                    x = splits[split]["success"]
                    shown.append(f"{split} {x['k']}/{x['n']} = {x['rate']:.2f} [{x['ci'][0]:.2f}, {x['ci'][1]:.2f}]")
            parts.append(f"{name}: " + ", ".join(shown))
            if name == "policy":
                main = splits.get("eval") or splits.get("train")
                rates.append(main["success"]["rate"] if main else None)
        lines.append(f"group {group}: " + "; ".join(parts))
    value = rates[0] if len(rates) == 1 else None
    return aspect("generalization", "reads", "success (k/n, 95% interval), " + " | ".join(lines), value=value)


def dynamics_settings(cfg) -> tuple[int, list[int], list[int]]:
    """(heldout, counts, seeds) of `dynamics`, checked (one line naming the key)."""
    from omegaconf import OmegaConf

    from simeval.config_schemas import EvaluateConfig, check_values
    from simeval.errors import require_whole

    check_values(cfg, EvaluateConfig)
    out = []
    for key, low in (("counts", 1), ("seeds", 0)):
        values = OmegaConf.to_container(cfg.dynamics[key]) if OmegaConf.is_config(cfg.dynamics[key]) else \
            cfg.dynamics[key]
        if not isinstance(values, list) or not values:
            raise UserError(f"dynamics.{key}={values!r}: expected a list of whole numbers >= {low}, e.g. "
                            + ("[10,20,40]" if key == "counts" else "[0,1,2]"))
        for v in values:
            require_whole(f"dynamics.{key}", v, low)
        out.append(sorted(set(values)))
    from hydra.core.global_hydra import GlobalHydra

    from simeval.errors import require_choice

    debug_overlays = tuple(o for o in GlobalHydra.instance().config_loader().get_group_options("debug")
                           if "/" not in o)  # the stage's own overlays (conf/debug/*.yaml), not evaluate's
    for stage in ("dynamics", "generalization"):  # before any stage runs, not when the stage gets to it
        require_choice(f"{stage}.debug", cfg[stage].debug, debug_overlays)
    overrides = cfg.dynamics.overrides
    if not OmegaConf.is_list(overrides) or not all(isinstance(x, str) for x in overrides):
        raise UserError("dynamics.overrides: expected a list of quoted overrides for src/diversity.py, e.g. "
                        "'dynamics.overrides=[\"world_model=paper\",\"device=cuda\"]'")
    _check_dynamics_overrides(cfg, out[0][0], out[1][0])
    return int(cfg.dynamics.heldout), out[0], out[1]


def _check_dynamics_overrides(cfg, count: int, seed: int) -> None:
    """The dynamics stage's config composed here, before any stage runs, with its first count and seed: a key or
    value of dynamics.overrides that src/diversity.py would refuse is one line now, not after the other stages ran
    (nor never, where the episodes are too few for the stage to run)."""
    from hydra import compose
    from hydra.errors import HydraException
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    from simeval.cli import composition_error_line, config_mistakes, entry_conf_dir
    from simeval.config_schemas import DiversityConfig, check_values
    from simeval.measures.dynamics_diversity.run import DiversityRun

    args = ["pipeline=custom", f"pipeline.name={cfg.episodes.pipeline}", f"task_group={cfg.episodes.group}",
            f"episodes={count}", f"seed={seed}",
            *([f"debug={cfg.dynamics.debug}"] if cfg.dynamics.debug != "none" else []), *cfg.dynamics.overrides]
    line = config_mistakes(args, entry_conf_dir(), "diversity")
    if line is None:
        try:
            composed = compose("diversity", overrides=args)
            check_values(composed, DiversityConfig)
            plain = OmegaConf.to_container(composed, resolve=True)
            _ = DiversityRun.from_config(plain).configs  # every world_model.* and protocol.* value checked
        except (HydraException, OmegaConfBaseException) as e:
            line = composition_error_line(e, "diversity", entry_conf_dir())
        except UserError as e:
            line = str(e)
    if line is not None:
        raise UserError(f"dynamics.overrides: {line}")


@hydra.main(version_base="1.3", config_path="../conf", config_name="evaluate")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig

    from simeval.episodes.store import pipeline_episodes
    from simeval.report import scorecard
    from simeval.results import RunFolder

    settings = dynamics_settings(cfg)  # before anything runs
    src = cfg.episodes
    metas = pipeline_episodes(src.store, src.pipeline, src.group)
    cameras = metas[0]["cameras"]
    camera = cfg.camera or cameras[0]
    if camera not in cameras:
        raise UserError(f"camera={camera}: the episodes record {', '.join(cameras)}")
    out = Path(str(cfg.out)).resolve()
    from collections import Counter

    fewest = min(Counter(m["task"] for m in metas).values())  # episodes of the task with the fewest
    aspects = [_text(metas, cfg), _quality(metas, cfg, out, fewest),
               _dynamics(metas, cfg, out, camera, fewest, settings),
               _generalization(cfg, out, camera, fewest, sorted({m["group"] for m in metas}))]
    card = scorecard.build(src.pipeline, aspects, cfg.tables)
    if HydraConfig.get().runtime.choices.get("debug", "none") != "none":
        card["note"] = (f"debug={HydraConfig.get().runtime.choices['debug']}: a first look at small sizes, not a "
                        "reading at the protocol's")
    paths = scorecard.write(card, out)
    RunFolder.of(cfg).write(metric="scorecard", version="1.0", values=card)
    for line in scorecard.lines(card):
        print(line)
    print(f"scorecard: {paths['html']} (and .md, .csv, .json, .png beside it)")
    log.info("wrote %s", ", ".join(str(p) for p in paths.values()))


if __name__ == "__main__":
    launch(main)
