"""`logger=wandb` (offline) on the cheap entrypoints, read back from the run's `.wandb` file: config, summary
metrics equal to result.json's values, group `<metric>/<pipeline>`, tags with the config choices and the git sha,
the per-task quality table with its images; and an API key set in the environment appears in no written file.
(diversity.py and generalization.py take the same logger; they train models, so they are not run here.)"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from helpers import _no_secret_anywhere, _run, make_bundles, wandb_records

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"


def read_offline_run(run_dir: Path) -> dict:
    """{group, job_type, tags, config, summary, artifacts: [{type, files: {path: local_path}}]} of the one offline
    W&B run under run_dir."""
    [path] = list(run_dir.glob("wandb/offline-run-*/run-*.wandb"))
    out = {"config": {}, "summary": {}, "artifacts": []}
    for r in wandb_records(path):
        kind = r.WhichOneof("record_type")
        if kind == "run":
            out |= {"group": r.run.run_group, "job_type": r.run.job_type, "tags": list(r.run.tags)}
            out["config"] |= {i.key: json.loads(i.value_json) for i in r.run.config.update}
        elif kind == "config":
            out["config"] |= {i.key: json.loads(i.value_json) for i in r.config.update}
        elif kind == "summary":
            out["summary"] |= {i.key or "/".join(i.nested_key): json.loads(i.value_json) for i in r.summary.update}
        elif kind == "artifact":
            out["artifacts"].append({"type": r.artifact.type,
                                     "files": {e.path: e.local_path for e in r.artifact.manifest.contents}})
    return out


def _check_run(run_dir: Path, metric: str, group: str) -> tuple[dict, dict]:
    rec = json.loads((run_dir / "result.json").read_text())
    run = read_offline_run(run_dir)
    assert run["group"] == group and run["job_type"] == metric
    expected = {f"{k}={v}" for k, v in rec["choices"].items() if k not in ("hydra", "logger") and v is not None}
    assert expected and expected <= set(run["tags"]), run["tags"]
    sha = rec["git_sha"]
    assert f"git={sha[:12]}" + ("-dirty" if sha.endswith("-dirty") else "") in run["tags"]
    # the resolved config, redacted as result.json's, is the run's W&B config
    assert {k: v for k, v in run["config"].items() if k != "_wandb"} == rec["config"]
    return rec, run


def test_text_diversity_logs_config_metrics_group_and_tags(openai_server, wandb_env, tmp_path):
    tasks = tmp_path / "tasks.yaml"
    tasks.write_text(yaml.safe_dump({"push": ["push the red block", "push the pile of beans", "slide the box"],
                                     "stack": ["stack two blocks", "stack three cups", "build a pyramid"]}))
    res = _run("text_diversity.py", "pipeline=custom", f"pipeline.tasks_path={tasks}", "embedding=openai",
               f"embedding.backend.base_url={openai_server.base_url}", "debug=tiny", f"cache_dir={tmp_path / 'c'}",
               f"hydra.run.dir={tmp_path / 'run'}", env=wandb_env, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    rec, run = _check_run(tmp_path / "run", "text_diversity", "text_diversity/custom")
    assert {"pipeline=custom", "embedding=openai", "debug=tiny"} <= set(run["tags"])
    for group in ("push", "stack", "all"):
        assert run["summary"][f"{group}/div"] == pytest.approx(rec["values"][group]["div"])
    assert run["config"]["embedding"]["backend"]["api_key_env"] == "OPENAI_API_KEY"  # the name, not the key
    _no_secret_anywhere(tmp_path)


def test_quality_logs_a_per_task_table_with_scene_and_frame_images(openai_server, wandb_env, tmp_path):
    # task0 has an unreadable scene view: no alignment score, its other views still shown; task2 is a video
    bundles = make_bundles(tmp_path / "bundles", n=3, video="task2", corrupt="task0")
    openai_server.default_reply = lambda payload: "Score: 1" if "block 1 " in json.dumps(payload) else "Score: 4"
    res = _run("quality.py", f"bundles_dir={bundles}", f"judge.provider.base_url={openai_server.base_url}",
               "debug=tiny", "label=GenSim-P", f"cache_dir={tmp_path / 'c'}", f"hydra.run.dir={tmp_path / 'run'}",
               env=wandb_env, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    rec, run = _check_run(tmp_path / "run", "quality", "quality/GenSim-P")
    assert {"judge=openai", "captioner=none"} <= set(run["tags"])
    assert run["summary"]["cost/new_calls"] == rec["cost"]["new_calls"] > 0
    assert run["summary"]["quality/tasks/nrows"] == 3
    [table] = [a for a in run["artifacts"] if a["type"] == "run_table"]
    [table_json] = [local for path, local in table["files"].items() if path.endswith(".table.json")]
    images = {path: local for path, local in table["files"].items() if path.startswith("media/images/")}
    # staged inside the run folder, so the offline run is whole for `wandb sync`
    assert all(Path(p).is_file() and (tmp_path / "run") in Path(p).parents for p in [table_json, *images.values()])
    t = json.loads(Path(table_json).read_text())
    col = {c: i for i, c in enumerate(t["columns"])}
    assert [r[col["task"]] for r in t["data"]][0] == "task1"  # lowest score first
    for row in t["data"]:
        task = row[col["task"]]
        assert row[col["scene_alignment"]] == rec["values"]["scene_alignment"].get(task, {}).get("mean")
        assert row[col["task_completion"]] == rec["values"]["task_completion"][task]["mean"]
        for cell in (row[col["scene"]], row[col["frames"]]):  # one image strip per cell, stored with the run
            assert cell["_type"] == "image-file" and cell["path"] in images
    # 4 views side by side at 128 px high; 2 sampled frames (debug=tiny: n_frames=2), also from the video task
    from PIL import Image

    strips = {row[col["task"]]: [Image.open(images[row[col[c]]["path"]]).size for c in ("scene", "frames")]
              for row in t["data"]}
    assert strips["task1"] == [(4 * 128 + 3 * 4, 128), (2 * 128 + 4, 128)]
    assert strips["task0"][0] == (3 * 128 + 2 * 4, 128)  # the unreadable view left out
    assert strips["task2"][1] == (2 * 128 + 4, 128)
    assert [r[col["scene_alignment"]] for r in t["data"] if r[col["task"]] == "task0"] == [None]
    _no_secret_anywhere(tmp_path)


def test_collect_logs_oracle_success(wandb_env, tmp_path):
    res = _run("collect.py", "pipeline=gensim", "tasks=[stack-two-blocks]", "debug=tiny", "episodes=1", "workers=1",
               f"store={tmp_path / 'store'}", f"hydra.run.dir={tmp_path / 'run'}", env=wandb_env, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    rec, run = _check_run(tmp_path / "run", "collect", "collect/gensim")
    assert run["summary"]["oracle_success/stack-two-blocks"] == rec["values"]["tasks"]["stack-two-blocks"]["rate"]
    _no_secret_anywhere(tmp_path)


@pytest.mark.skipif(not (SHARED_DATA / "human_eval_tables.json").is_file(), reason="../shared/data not beside checkout")
def test_agreement_logs_r_over_mae(wandb_env, tmp_path):
    res = _run("agreement.py", "debug=tiny", f"scores_path={SHARED_DATA / 'human_eval_tables.json'}",
               f"hydra.run.dir={tmp_path / 'run'}", env=wandb_env, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    rec, run = _check_run(tmp_path / "run", "agreement", "agreement/any")
    logged = {k: v for k, v in run["summary"].items() if k.endswith("/r_over_mae")}
    assert len(logged) >= 10
    _no_secret_anywhere(tmp_path)


def test_csv_logger_writes_the_quality_task_table_with_image_paths(tmp_path):
    import csv

    bundles = make_bundles(tmp_path / "bundles", n=3)
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    res = subprocess.run([sys.executable, str(ROOT / "src" / "quality.py"), f"bundles_dir={bundles}", "judge=oracle",
                          "logger=csv", f"hydra.run.dir={tmp_path / 'run'}"], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    rows = list(csv.DictReader((tmp_path / "run" / "quality_tasks.csv").open()))
    # oracle completion = 10 x progress (make_bundles: progress 0, 0.5, 1): lowest first
    assert [(r["task"], float(r["task_completion"])) for r in rows] == [("task0", 0.0), ("task1", 5.0),
                                                                        ("task2", 10.0)]
    assert rows[0]["description"] == "stack block 0 on the pallet" and rows[0]["scene_alignment"] == ""
    scene = rows[0]["scene"].split(";")
    assert [Path(p).name for p in scene] == ["view0.png", "view1.png", "view2.png", "view3.png"]
    assert all(Path(p).is_file() for p in scene + rows[0]["frames"].split(";"))
    assert len(rows[0]["frames"].split(";")) == 8  # quality.yaml n_frames: the 8 of 12 frames a model judge sees
