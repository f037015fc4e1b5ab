"""Judges against a real OpenAI-compatible server on loopback: retries, parse failures and re-asks, cache hits,
resume after a killed run, cost ledger, budget, dry run, replay, per-task errors, the caption path."""

import json
import os
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from simeval.judges.cache import JudgeCache
from simeval.judges.ledger import BudgetExceeded, Ledger, Prices
from simeval.judges.parse import parse_score
from simeval.judges.prompts import load_template
from simeval.httpretry import FatalHTTPError
from simeval.judges.providers import Image, OpenAIChatProvider
from simeval.judges.runner import JudgeItem, JudgeSettings, ReplayMiss, dry_run, run_judge
from simeval.measures.quality.bundle import load_bundles, sample_frame_indices
from simeval.measures.quality.run import oracle_completion, summarize
from helpers import _png, make_bundles

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"


@pytest.mark.parametrize("reply,expected", [
    ("Score: 4", 4.0), ("score:3.5", 3.5), ("**Score:** 5", 5.0), ("Reasoning... Score = 2", 2.0),
    ("Format is Score: X. My answer. Score: 3", 3.0), ("4", 4.0), ("Score: 4/5", 4.0),
    ("Score: 7", None), ("I like it", None), ("", None), ("Score: -1", None),
])
def test_parse_score(reply, expected):
    assert parse_score(reply, 1, 5).value == expected


def test_frame_sampling_includes_first_and_last_in_order():
    idx = sample_frame_indices(100, 8)
    assert idx[0] == 0 and idx[-1] == 99 and len(idx) == 8 and idx == sorted(idx)
    assert sample_frame_indices(5, 8) == [0, 1, 2, 3, 4]


def _items(n=2, metric="scene_alignment", template="scene_alignment_vlm"):
    tpl = load_template(f"builtin:{template}")
    return [JudgeItem(f"t{i}", metric, tpl, {"description": f"task {i}"}, [Image.from_png(_png(i))], (1, 5))
            for i in range(n)]


def _provider(srv, **kw):
    return OpenAIChatProvider(base_url=srv.base_url, model="judge-test", backoff_s=0.01, **kw)


def test_repeats_cache_and_ledger(openai_server, tmp_path):
    cache = JudgeCache(tmp_path / "c.sqlite")
    ledger = Ledger(Prices(input_per_1m=1000.0, output_per_1m=2000.0))
    recs = run_judge(_items(3), _provider(openai_server), cache, ledger, JudgeSettings(repeats=5, concurrency=4,
                                                                                       progress=False))
    assert len(recs) == 15 and all(r.score == 3.0 for r in recs)
    assert len(openai_server.requests) == 15 and len(cache) == 15
    assert ledger.new_calls == 15 and ledger.prompt_tokens == 1500 and ledger.completion_tokens == 75
    assert ledger.cost_usd == pytest.approx(15 * (100 * 1000 + 5 * 2000) / 1e6)
    ledger2 = Ledger(Prices(input_per_1m=1000.0, output_per_1m=2000.0))
    again = run_judge(_items(3), _provider(openai_server), JudgeCache(tmp_path / "c.sqlite"), ledger2,
                      JudgeSettings(repeats=5, progress=False))
    assert len(openai_server.requests) == 15  # a second identical run makes zero HTTP calls
    assert ledger2.new_calls == 0 and ledger2.cached_calls == 15 and ledger2.cost_usd == 0
    assert [r.score for r in again] == [r.score for r in recs]


def test_request_carries_images_and_the_rendered_prompt(openai_server, tmp_path):
    items = _items(1)
    run_judge(items, _provider(openai_server), JudgeCache(tmp_path / "c.sqlite"), Ledger(Prices()),
              JudgeSettings(repeats=1, progress=False))
    msgs = openai_server.requests[0]["payload"]["messages"]
    assert msgs[0]["role"] == "system" and "Score: X" in msgs[0]["content"]
    user = msgs[1]["content"]
    assert "Task description: task 0" in user[0]["text"]
    assert user[1]["image_url"]["url"] == items[0].images[0].data_url()


def test_429_500_retried_and_unparseable_reply_reasked(openai_server, tmp_path):
    openai_server.faults.extend([{"status": 429, "retry_after": "0.05"}, {"status": 500}, {"reply": "looks fine"},
                                 {"reply": "Score: 9"}, {"reply": "Score: 4"}])
    ledger = Ledger(Prices())
    recs = run_judge(_items(1), _provider(openai_server), JudgeCache(tmp_path / "c.sqlite"), ledger,
                     JudgeSettings(repeats=1, max_reasks=3, concurrency=1, progress=False))
    rec = recs[0]
    assert rec.score == 4.0
    assert [a["error"] for a in rec.asks] == ["no 'Score: X' in reply", "score 9 outside [1, 5]", None]
    assert len(openai_server.requests) == 5  # 2 retried HTTP faults + 3 asks
    # the retries are recorded with the ask they delayed, and counted in the ledger
    assert [r["status"] for r in rec.asks[0]["retries"]] == [429, 500] and rec.asks[1]["retries"] == []
    assert rec.asks[0]["retries"][0]["waited_s"] >= 0.05
    assert ledger.totals()["retries"] == 2


def test_reasks_are_bounded_and_invalid_is_recorded_not_a_number(openai_server, tmp_path):
    openai_server.default_reply = "no score here"
    recs = run_judge(_items(1), _provider(openai_server), JudgeCache(tmp_path / "c.sqlite"), Ledger(Prices()),
                     JudgeSettings(repeats=2, max_reasks=1, progress=False))
    assert all(r.score is None and len(r.asks) == 2 for r in recs)
    summary = summarize(recs)["scene_alignment"]["t0"]
    assert summary["n_valid"] == 0 and summary["n_invalid"] == 2 and summary["mean"] is None


def test_401_stops_the_run_with_a_clear_message(openai_server, tmp_path):
    openai_server.faults.extend([{"status": 401, "message": "invalid api key"}] * 4)
    with pytest.raises(FatalHTTPError, match="HTTP 401 .*API key"):
        run_judge(_items(4), _provider(openai_server), JudgeCache(tmp_path / "c.sqlite"), Ledger(Prices()),
                  JudgeSettings(repeats=1, concurrency=1, progress=False))
    assert len(openai_server.requests) == 1


def test_hanging_server_times_out_and_is_retried(openai_server, tmp_path):
    openai_server.faults.append({"hang": 1.0})
    recs = run_judge(_items(1), _provider(openai_server, timeout_s=0.2), JudgeCache(tmp_path / "c.sqlite"),
                     Ledger(Prices()), JudgeSettings(repeats=1, progress=False))
    assert recs[0].score == 3.0 and len(openai_server.requests) == 2


def test_budget_stops_before_exceeding(openai_server, tmp_path):
    prices = Prices(input_per_1m=10_000.0, output_per_1m=0.0, image_tokens=0)
    system, user = _items(1)[0].rendered()
    estimate = prices.estimate(len(system) + len(user), 1, 64)
    ledger = Ledger(prices, budget_usd=3.5 * estimate)  # room for a few calls, not ten
    with pytest.raises(BudgetExceeded, match="would be exceeded") as e:
        run_judge(_items(10), _provider(openai_server), JudgeCache(tmp_path / "c.sqlite"), ledger,
                  JudgeSettings(repeats=1, concurrency=1, progress=False))
    assert ledger.cost_usd <= 3.5 * estimate and 1 <= len(e.value.partial) == len(openai_server.requests) < 10


def test_dry_run_calls_nothing(openai_server, tmp_path):
    plan = dry_run(_items(4), _provider(openai_server), JudgeCache(tmp_path / "c.sqlite"),
                   Ledger(Prices(input_per_1m=2.5, output_per_1m=10)), JudgeSettings(repeats=5))
    assert plan["calls"] == 20 and plan["images"] == 20 and plan["estimated_usd"] > 0
    assert openai_server.requests == []


def test_replay_answers_from_cache_and_names_a_miss(openai_server, tmp_path):
    cache = JudgeCache(tmp_path / "c.sqlite")
    run_judge(_items(2), _provider(openai_server), cache, Ledger(Prices()), JudgeSettings(repeats=2, progress=False))
    n = len(openai_server.requests)
    recs = run_judge(_items(2), _provider(openai_server), cache, Ledger(Prices()),
                     JudgeSettings(repeats=2, replay=True, progress=False))
    assert len(recs) == 4 and len(openai_server.requests) == n
    with pytest.raises(ReplayMiss, match="item 't2'") as miss:
        run_judge(_items(3), _provider(openai_server), cache, Ledger(Prices()),
                  JudgeSettings(repeats=2, replay=True, concurrency=1, progress=False))
    # the endpoint is part of the key: a replay without the live run's base_url misses, and the message says so
    assert f"endpoint {_provider(openai_server).endpoint}," in str(miss.value)
    assert "part of the cache key" in str(miss.value)


def test_bundles_with_errors_and_video(tmp_path):
    root = make_bundles(tmp_path / "b", n=3, corrupt="task1", video="task2")
    (tmp_path / "b" / "broken").mkdir()
    (tmp_path / "b" / "broken" / "task.yaml").write_text("description: [unclosed\n")
    bundles, errors = load_bundles(root)
    assert [b.name for b in bundles] == ["task0", "task1", "task2"] and "broken" in errors
    frames = bundles[2].trajectory_frames(8)
    assert len(frames) == 8
    with pytest.raises(Exception, match="unreadable image .*view0.png"):
        bundles[1].scene_images()
    assert oracle_completion(bundles)["task2"]["mean"] == 10.0


def run_quality(*args, env=None, **kw):
    return subprocess.run([sys.executable, str(ROOT / "src" / "quality.py"), *args], cwd=ROOT,
                          env={**os.environ, **(env or {})}, capture_output=True, text=True, timeout=300, **kw)


def test_quality_end_to_end_with_failures_reported(openai_server, tmp_path, monkeypatch):
    root = make_bundles(tmp_path / "b", n=3, corrupt="task1")
    res = run_quality(f"bundles_dir={root}", f"judge.provider.base_url={openai_server.base_url}", "repeats=2",
                      f"cache_dir={tmp_path / 'cache'}", f"hydra.run.dir={tmp_path / 'run'}",
                      env={"OPENAI_API_KEY": "sk-should-never-be-written"})
    assert res.returncode == 0, res.stderr[-2000:]
    rec = json.loads((tmp_path / "run" / "result.json").read_text())
    assert set(rec["values"]["scene_alignment"]) == {"task0", "task2"}  # task1's views are unreadable
    assert set(rec["values"]["task_completion"]) == {"task0", "task1", "task2"}
    assert "unreadable image" in rec["errors"]["task1"]
    assert rec["values"]["task_completion"]["task0"] == {"scores": [3.0, 3.0], "n_invalid": 0, "n_valid": 2,
                                                         "mean": 3.0, "var": 0.0}
    assert rec["cost"]["new_calls"] == 10 and rec["cost"]["cost_usd"] > 0
    per = rec["cost"]["by_metric_pipeline"]
    assert per["scene_alignment/gensim"]["new_calls"] == 4 and per["task_completion/gensim"]["new_calls"] == 6
    assert per["scene_alignment/gensim"]["images"] == 16 and per["task_completion/gensim"]["images"] == 48
    assert sum(v["cost_usd"] for v in per.values()) == pytest.approx(rec["cost"]["cost_usd"], abs=1e-5)
    lines = [json.loads(x) for x in (tmp_path / "run" / "scores.jsonl").read_text().splitlines()]
    assert len(lines) == 10 and all(len(x["template_sha256"]) == 64 and x["asks"][0]["reply"] for x in lines)
    assert sum(len(x["image_sha256"]) for x in lines) == 2 * 2 * 4 + 3 * 2 * 8  # 4 views, 8 frames
    written = "".join(p.read_text(errors="ignore") for p in (tmp_path / "run").rglob("*") if p.is_file())
    assert "sk-should-never-be-written" not in written
    res = run_quality(f"bundles_dir={root}", "judge=replay", f"judge.provider.base_url={openai_server.base_url}",
                      "repeats=2", f"cache_dir={tmp_path / 'cache'}", f"hydra.run.dir={tmp_path / 'run2'}")
    assert res.returncode == 0, res.stderr[-2000:]
    assert len(openai_server.requests) == 10  # the replay made no call
    res = run_quality(f"bundles_dir={root}", "dry_run=true", "repeats=3", f"cache_dir={tmp_path / 'cache'}",
                      f"judge.provider.base_url={openai_server.base_url}", f"hydra.run.dir={tmp_path / 'run3'}")
    plan = json.loads(res.stdout[res.stdout.index("{"):])
    assert plan["cached"] == 10 and plan["calls"] == 5 and len(openai_server.requests) == 10


def test_killed_run_resumes_without_repeating_a_stored_call(tmp_path):
    """The server kills the run (kill -9) as the 10th request arrives, before answering it: mid-run at a known
    point, whatever the machine's speed. The rerun asks exactly what the cache does not hold."""
    from simeval.devserver import LoopbackOpenAI

    root = make_bundles(tmp_path / "b", n=4)
    victim: list = []

    def reply_or_kill(payload):
        with srv.lock:
            arrived = len(srv.requests)
        if arrived == 10 and victim:
            os.kill(victim.pop().pid, signal.SIGKILL)
        return "Score: 3"

    with LoopbackOpenAI(latency_s=0.05, default_reply=reply_or_kill) as srv:
        args = [f"bundles_dir={root}", f"judge.provider.base_url={srv.base_url}", "repeats=5", "judge.concurrency=2",
                f"cache_dir={tmp_path / 'cache'}"]
        proc = subprocess.Popen([sys.executable, str(ROOT / "src" / "quality.py"), *args,
                                 f"hydra.run.dir={tmp_path / 'r1'}"], cwd=ROOT, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        victim.append(proc)
        assert proc.wait(timeout=120) == -signal.SIGKILL
        assert not (tmp_path / "r1" / "result.json").exists()
        stored = sqlite3.connect(tmp_path / "cache" / "judge_calls.sqlite").execute("SELECT COUNT(*) FROM calls").fetchone()[0]
        assert 0 < stored < 40
        before = len(srv.requests)
        res = run_quality(*args, f"hydra.run.dir={tmp_path / 'r2'}")
        assert res.returncode == 0, res.stderr[-2000:]
        assert len(srv.requests) - before == 40 - stored  # 4 tasks x 2 metrics x 5 repeats, stored ones not re-asked
    rec = json.loads((tmp_path / "r2" / "result.json").read_text())
    assert rec["cost"]["cached_calls"] == stored and rec["cost"]["new_calls"] == 40 - stored


def test_caption_path_scores_captions_without_images(openai_server, tmp_path):
    root = make_bundles(tmp_path / "b", n=1)
    openai_server.default_reply = lambda payload: ("A red block on a table." if "Describe this view" in json.dumps(
        payload) else "Score: 4")
    res = run_quality(f"bundles_dir={root}", "metric=scene_alignment", "scene_alignment_mode=caption",
                      "captioner=openai", f"captioner.provider.base_url={openai_server.base_url}",
                      f"judge.provider.base_url={openai_server.base_url}", "repeats=3",
                      f"cache_dir={tmp_path / 'cache'}", f"hydra.run.dir={tmp_path / 'run'}")
    assert res.returncode == 0, res.stderr[-2000:]
    caption_calls = [r for r in openai_server.requests if "Describe this view" in json.dumps(r["payload"])]
    judge_calls = [r for r in openai_server.requests if r not in caption_calls]
    assert len(caption_calls) == 4 and len(judge_calls) == 3
    user = judge_calls[0]["payload"]["messages"][1]["content"]
    assert len(user) == 1 and "View 4: A red block on a table." in user[0]["text"]
    rec = json.loads((tmp_path / "run" / "result.json").read_text())
    assert rec["values"]["scene_alignment"]["task0"]["mean"] == 4.0


def test_figure4_from_two_labelled_quality_runs(openai_server, tmp_path):
    root = make_bundles(tmp_path / "b", n=2)
    for label, reply in (("GenSim-P", "Score: 4"), ("GenSim-G", "Score: 2")):
        openai_server.default_reply = reply
        res = run_quality(f"bundles_dir={root}", f"label={label}", f"judge.provider.base_url={openai_server.base_url}",
                          "repeats=2", f"cache_dir={tmp_path / label}", f"hydra.run.dir={tmp_path / 'runs' / label}")
        assert res.returncode == 0, res.stderr[-2000:]
    res = subprocess.run([sys.executable, str(ROOT / "src" / "report.py"), "report=figure4",
                          f"report.runs_dir={tmp_path / 'runs'}", f"report.out_dir={tmp_path / 'fig'}"],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    assert (tmp_path / "fig" / "figure4.png").stat().st_size > 5_000
    rows = (tmp_path / "fig" / "figure4.csv").read_text().splitlines()
    assert "GenSim-P,4.00,4.00,0.00,2" in rows and "GenSim-G,2.00,2.00,0.00,2" in rows


def test_quality_and_agreement_configs_compose():
    from hydra import compose, initialize_config_dir
    from hydra.utils import instantiate

    with initialize_config_dir(version_base="1.3", config_dir=str(CONF)):
        for judge in ("openai", "replay", "hf", "oracle"):
            cfg = compose("quality", overrides=[f"judge={judge}"])
            assert cfg.judge.kind in ("model", "oracle")
        assert compose("quality", overrides=["judge=replay"]).judge.replay is True
        cap = compose("quality", overrides=["captioner=openai", "scene_alignment_mode=caption"]).captioner
        assert cap.provider.temperature == 0.0 and cap.provider.model == "gpt-4o"
        provider = instantiate(compose("quality").judge.provider)
        assert provider.url.endswith("/chat/completions")
        azure = compose("quality", overrides=["judge.provider.api_style=azure", "judge.provider.api_version=2024-02-15-preview",
                                              "judge.provider.base_url=https://x.openai.azure.com"]).judge.provider
        assert "deployments/gpt-4o/chat/completions?api-version=2024-02-15-preview" in instantiate(azure).url
        with pytest.raises(Exception, match="not a local model directory"):
            instantiate(compose("quality", overrides=["judge=hf"]).judge.provider)
        for name in ("task_completion", "scene_alignment_vlm", "scene_alignment_captions", "caption"):
            assert load_template(compose("quality").prompts[name]).sha256
        assert compose("agreement").n_boot == 2000


def test_bad_template_is_a_clear_error(tmp_path):
    (tmp_path / "t.txt").write_text("no separator here")
    with pytest.raises(ValueError, match="---user---"):
        load_template(tmp_path / "t.txt")
    (tmp_path / "u.txt").write_text("sys {what}\n---user---\n{description}")
    with pytest.raises(ValueError, match="unknown placeholder"):
        load_template(tmp_path / "u.txt")
