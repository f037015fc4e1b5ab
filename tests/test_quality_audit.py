"""Quality runs that must not look fine when they are not: two bundles with one task name, invalid ground truth,
a judge that never gives a parseable score, bundles a dry run would skip; and the library call, the packaged
prompts and the single decode of a video."""

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
import yaml

from simeval.judges.cache import JudgeCache
from simeval.judges.ledger import Ledger, Prices
from simeval.judges.prompts import builtin_names, load_template
from simeval.judges.providers import OpenAIChatProvider
from simeval.judges.runner import JudgeSettings, ScoreRecord
from simeval.measures.quality.bundle import BundleError, load_bundles, read_video_frames
from simeval.measures.quality.run import ModelJudge, Scoring, run_quality, write_scores
from helpers import make_bundles

ROOT = Path(__file__).resolve().parents[1]


def strict_json(text: str):
    def refuse(name):
        raise ValueError(f"non-standard JSON constant {name}")
    return json.loads(text, parse_constant=refuse)


def _quality(*args, timeout=300):
    return subprocess.run([sys.executable, str(ROOT / "src" / "quality.py"), *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout)


def _judge(srv, tmp_path, repeats=2, max_reasks=1):
    return ModelJudge(provider=OpenAIChatProvider(base_url=srv.base_url, model="judge-test", backoff_s=0.01),
                      templates={n: load_template(f"builtin:{n}") for n in builtin_names()},
                      cache=JudgeCache(tmp_path / "cache.sqlite"), ledger=Ledger(Prices(input_per_1m=1.0)),
                      settings=JudgeSettings(repeats=repeats, max_reasks=max_reasks, concurrency=2, progress=False))


def _set_yaml(path: Path, **changes):
    data = yaml.safe_load(path.read_text())
    data.update(changes)
    path.write_text(yaml.safe_dump(data))


def test_two_bundles_with_one_name_are_an_error_naming_both_folders(tmp_path):
    root = make_bundles(tmp_path / "b", n=3)
    _set_yaml(root / "task0" / "task.yaml", name="stack")
    _set_yaml(root / "task2" / "task.yaml", name="stack")
    with pytest.raises(BundleError, match="task name 'stack' is used by 2 bundles") as e:
        load_bundles(root)
    assert str(root / "task0") in str(e.value) and str(root / "task2") in str(e.value)
    res = _quality(f"bundles_dir={root}", "judge=oracle", f"hydra.run.dir={tmp_path / 'run'}")
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and res.stderr.startswith("error: ")
    assert str(root / "task0") in res.stderr and str(root / "task2") in res.stderr
    assert not (tmp_path / "run" / "result.json").exists()  # nothing judged, nothing pooled


def test_invalid_ground_truth_is_a_per_task_error_and_json_stays_strict(tmp_path):
    root = make_bundles(tmp_path / "b", n=5)
    bad = {"task0": {"success": "false"}, "task1": {"progress": float("nan")}, "task2": {"progress": "abc"},
           "task3": {"progress": 70}}
    for task, gt in bad.items():
        _set_yaml(root / task / "task.yaml", ground_truth=gt)
    assert ".nan" in (root / "task1" / "task.yaml").read_text()
    out = run_quality(tmp_path / "run", bundles_dir=root, judge="oracle")
    rec = strict_json((tmp_path / "run" / "result.json").read_text())  # no bare NaN
    assert rec["status"] == "ok" and out.scored == ["task4"]
    assert rec["values"]["task_completion"] == {"task4": {"mean": 10.0, "var": None, "n_valid": 1, "n_invalid": 0,
                                                          "scores": [10.0]}}
    assert rec["errors"]["task0"].endswith("ground_truth.success must be true or false, got 'false' (str)")
    assert rec["errors"]["task1"].endswith("ground_truth.progress must be a number in [0, 1], got nan (float)")
    assert rec["errors"]["task2"].endswith("ground_truth.progress must be a number in [0, 1], got 'abc' (str)")
    assert rec["errors"]["task3"].endswith("ground_truth.progress must be a number in [0, 1], got 70 (int)")
    assert str(root / "task0" / "task.yaml") in rec["errors"]["task0"]
    assert rec["failed"] == ["task0", "task1", "task2", "task3"]


def test_scores_jsonl_is_strict_json(tmp_path):
    rec = ScoreRecord("t", "task_completion", 0, "openai", "m", "0" * 64, [], [{"latency_s": float("nan")}],
                      score=float("inf"))
    line = write_scores(tmp_path / "scores.jsonl", [rec]).read_text()
    assert strict_json(line)["score"] is None and strict_json(line)["asks"][0]["latency_s"] is None


def test_a_judge_that_never_scores_fails_the_run(openai_server, tmp_path):
    root = make_bundles(tmp_path / "b", n=2)
    openai_server.default_reply = "I cannot tell from these images."
    custom = tmp_path / "my_completion.txt"
    custom.write_text("You grade robots (custom rubric).\n---user---\n{description}\nAnswer 'Score: X'.")
    res = _quality(f"bundles_dir={root}", f"judge.provider.base_url={openai_server.base_url}", "repeats=3",
                   "max_reasks=1", f"prompts.task_completion={custom}", f"cache_dir={tmp_path / 'cache'}",
                   f"hydra.run.dir={tmp_path / 'run'}")
    assert res.returncode == 1, res.stderr[-2000:]
    error = res.stderr.strip().splitlines()[-1]  # the lines before it are the progress bar
    assert error.startswith("error: every task failed (2 of 2; task0: scene_alignment: no valid score in 6 replies")
    assert "24 new calls paid for nothing" in error and "Traceback" not in res.stderr
    calls = 2 * 2 * 3 * 2  # tasks x metrics x repeats x (1 + max_reasks)
    assert len(openai_server.requests) == calls
    assert sum("custom rubric" in json.dumps(r["payload"]) for r in openai_server.requests) == calls // 2
    rec = strict_json((tmp_path / "run" / "result.json").read_text())
    assert rec["status"] == "failed" and rec["failed"] == ["task0", "task1"] and rec["scored"] == 0
    assert rec["errors"]["task0"] == ("scene_alignment: no valid score in 6 replies (last: no 'Score: X' in reply); "
                                      "task_completion: no valid score in 6 replies (last: no 'Score: X' in reply)")
    assert rec["cost"]["new_calls"] == rec["cost"]["invalid_calls"] == calls
    assert rec["cost"]["invalid_cost_usd"] == rec["cost"]["cost_usd"] > 0
    assert rec["values"]["task_completion"]["task0"]["mean"] is None
    assert (f"quality (model): 2 tasks, 0 scored, 2 failed (task0, task1); {calls} new calls "
            f"(${rec['cost']['cost_usd']:.4f}), {calls} of them paid for nothing") in res.stdout + res.stderr


def test_one_task_failing_is_reported_and_the_others_scored(openai_server, tmp_path):
    root = make_bundles(tmp_path / "b", n=2)
    openai_server.default_reply = lambda payload: "Score: 4" if "block 0" in json.dumps(payload) else "no idea"
    out = run_quality(tmp_path / "run", bundles_dir=root, scoring=Scoring(metric="task_completion"),
                      judge=_judge(openai_server, tmp_path))
    assert out.status == "ok" and out.scored == ["task0"] and out.failed == ["task1"]
    assert out.errors == {"task1": "task_completion: no valid score in 4 replies (last: no 'Score: X' in reply)"}
    assert out.cost["new_calls"] == 2 + 4 and out.cost["invalid_calls"] == 4
    assert out.summary.startswith("quality (model): 2 tasks, 1 scored, 1 failed (task1); 6 new calls")
    assert "4 of them paid for nothing" in out.summary
    again = run_quality(tmp_path / "run2", bundles_dir=root, scoring=Scoring(metric="task_completion"),
                        judge=_judge(openai_server, tmp_path))
    assert again.cost["new_calls"] == again.cost["invalid_calls"] == 0  # cached replies were not paid for again


def test_dry_run_lists_every_bundle_it_would_skip(openai_server, tmp_path):
    root = make_bundles(tmp_path / "b", n=6, corrupt="task1")
    (root / "task2" / "task.yaml").write_text("description: [unclosed\n")
    _set_yaml(root / "task3" / "task.yaml", ground_truth={"success": "yes"})
    for f in (root / "task4" / "frames").glob("*.png"):
        f.unlink()
    (root / "notes").mkdir()  # a folder without task.yaml
    res = _quality(f"bundles_dir={root}", "dry_run=true", f"judge.provider.base_url={openai_server.base_url}",
                   f"cache_dir={tmp_path / 'cache'}", f"hydra.run.dir={tmp_path / 'run'}")
    assert res.returncode == 0, res.stderr[-2000:]
    plan = json.loads(res.stdout)  # stdout is the plan and nothing else
    assert plan["bundles"] == 7 and plan["skipped"] == 5 and len(openai_server.requests) == 0
    skip = plan["skip"]
    assert set(skip) == {"task1", "task2", "task3", "task4", "notes"}
    assert skip["task1"].startswith("unreadable image") and "view0.png" in skip["task1"]
    assert "task2/task.yaml: not readable YAML" in skip["task2"] and "ground_truth.success must be true or false" in skip["task3"]
    assert "no trajectory" in skip["task4"] and "needs a mapping with a `description`" in skip["notes"]
    res = _quality(f"bundles_dir={root}", "dry_run=true", "judge=oracle", f"hydra.run.dir={tmp_path / 'run2'}")
    plan = json.loads(res.stdout)
    assert plan["calls"] == 0 and set(plan["skip"]) == {"task2", "task3", "notes"}


def test_a_video_is_decoded_once(tmp_path, monkeypatch):
    import imageio.v3 as iio

    video = tmp_path / "t.mp4"
    frames = np.random.default_rng(0).integers(0, 255, (30, 32, 32, 3), dtype=np.uint8)
    iio.imwrite(video, frames, fps=10, codec="libx264")
    decoded = np.stack(list(iio.imiter(video)))
    passes = []
    real = iio.imiter

    def counting(*a, **kw):
        passes.append(1)
        return real(*a, **kw)

    monkeypatch.setattr(iio, "imiter", counting)
    got = read_video_frames(video, 8)
    assert len(passes) == 1
    idx = np.linspace(0, 29, 8).round().astype(int)
    np.testing.assert_array_equal(np.stack(got), decoded[idx])  # first and last included, in order


def test_run_quality_is_a_plain_call_and_prompts_are_package_data(openai_server, tmp_path):
    root = make_bundles(tmp_path / "b", n=2)
    out = run_quality(tmp_path / "run", bundles_dir=root, judge=_judge(openai_server, tmp_path, repeats=1))
    assert out.status == "ok" and out.values["scene_alignment"]["task1"]["mean"] == 3.0
    assert strict_json(out.result_path.read_text())["summary"] == out.summary
    package = ROOT / "src" / "simeval"
    shipped = sorted(p.relative_to(package) for p in (package / "judges" / "templates").glob("*.txt"))
    assert [p.stem for p in shipped] == builtin_names() == ["caption", "scene_alignment_captions",
                                                           "scene_alignment_vlm", "task_completion"]
    patterns = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["simeval"]
    assert all(any(p.match(g) for g in patterns) for p in shipped)  # an installed simeval carries them
    assert not (ROOT / "conf" / "prompts").exists()
    with pytest.raises(ValueError, match="builtin templates: builtin:caption"):
        load_template("builtin:nope")
    lines = (ROOT / "src" / "quality.py").read_text().splitlines()
    assert len(lines) <= 60  # the entrypoint only wires objects into run_quality


def test_budget_stop_keeps_what_finished_and_ends_in_one_line(openai_server, tmp_path):
    root = make_bundles(tmp_path / "b", n=3)
    res = _quality(f"bundles_dir={root}", f"judge.provider.base_url={openai_server.base_url}", "repeats=2",
                   "budget_usd=0.012", "judge.concurrency=1", f"cache_dir={tmp_path / 'cache'}",
                   f"hydra.run.dir={tmp_path / 'run'}")
    last = res.stderr.strip().splitlines()[-1]
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert last.startswith("error: budget_usd=0.012 would be exceeded")
    rec = strict_json((tmp_path / "run" / "result.json").read_text())
    assert rec["status"] == "stopped" and 0 < rec["cost"]["new_calls"] < 10


@pytest.mark.parametrize("override,named", [
    ("repeats=0", "repeats must be a whole number >= 1, got 0"),
    ("repeats=abc", "repeats='abc': expected a whole number"),
    ("max_reasks=-1", "max_reasks must be a whole number >= 0"),
    ("judge.concurrency=0", "judge.concurrency (or captioner.concurrency) must be a whole number >= 1"),
    ("judge.rate_limit_per_min=0", "judge.rate_limit_per_min (or captioner.rate_limit_per_min) must be a number > 0"),
    ("budget_usd=abc", "budget_usd='abc': expected a number"),
    ("budget_usd=-1", "budget_usd must be a number of US dollars >= 0 or null"),
    ("n_frames=0", "n_frames must be a whole number >= 2"),
])
def test_bad_quality_settings_are_one_line_before_any_call(openai_server, tmp_path, override, named):
    root = make_bundles(tmp_path / "b", n=1)
    res = _quality(f"bundles_dir={root}", f"judge.provider.base_url={openai_server.base_url}", override,
                   f"cache_dir={tmp_path / 'cache'}", f"hydra.run.dir={tmp_path / 'run'}")
    assert res.returncode == 2 and res.stderr.strip() == f"error: {res.stderr.strip()[7:]}"
    assert named in res.stderr and "Traceback" not in res.stderr and openai_server.requests == []


def test_replies_of_another_endpoint_are_never_served_from_the_cache(tmp_path):
    from simeval.devserver import LoopbackOpenAI

    root = make_bundles(tmp_path / "b", n=1)
    common = [f"bundles_dir={root}", "repeats=1", "metric=task_completion", f"cache_dir={tmp_path / 'cache'}"]
    with LoopbackOpenAI() as a, LoopbackOpenAI() as b:  # two servers answering to the same model name
        a.default_reply, b.default_reply = "Score: 2", "Score: 9"
        first = _quality(*common, f"judge.provider.base_url={a.base_url}", f"hydra.run.dir={tmp_path / 'r1'}")
        second = _quality(*common, f"judge.provider.base_url={b.base_url}/", f"hydra.run.dir={tmp_path / 'r2'}")
        again = _quality(*common, f"judge.provider.base_url={a.base_url}", f"hydra.run.dir={tmp_path / 'r3'}")
        assert first.returncode == second.returncode == again.returncode == 0, second.stderr[-500:]
        assert len(a.requests) == 1 and len(b.requests) == 1  # b asked anew; a's re-run came from the cache
    means = [strict_json((tmp_path / r / "result.json").read_text())["values"]["task_completion"]["task0"]["mean"]
             for r in ("r1", "r2", "r3")]
    assert means == [2.0, 9.0, 2.0]
