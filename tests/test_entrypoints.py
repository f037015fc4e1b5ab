"""The real configs composed with Hydra's compose API, and each entrypoint run end to end as a user runs it."""

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

ROOT = Path(__file__).resolve().parents[1]
CONF = str(ROOT / "conf")


def run(script, *args, env=None, cwd=ROOT, timeout=300):
    import os

    full_env = {**os.environ, **(env or {})}
    return subprocess.run([sys.executable, str(ROOT / "src" / script), *args], cwd=cwd, env=full_env,
                          capture_output=True, text=True, timeout=timeout)


def _load_like_the_entrypoint(p):
    from simeval.pipelines.task_texts import load_tasks

    return load_tasks(p.name, p.source, root=p.root, grouped_file=p.grouped_file, tasks_path=p.tasks_path,
                      suite=p.suite, text_template=p.text_template, group_aliases=p.group_aliases)


def test_every_pipeline_config_loads_its_tasks_with_the_paper_groups(shared_data, tmp_path, monkeypatch):
    """Each shipped pipeline config, fed to the loader as src/text_diversity.py does, gives the paper's groups and
    text format (the config's aliases, templates and env sources are what make this true)."""
    from simeval.pipelines.task_texts import groups_of, select_group

    bbsea = tmp_path / "bbsea.yaml"
    bbsea.write_text(yaml.safe_dump(["Open the drawer", "Put the red block in the bin"]))
    monkeypatch.setenv("GENSIM_DESCS", str(shared_data / "gensim_descs_grouped.yaml"))
    monkeypatch.setenv("ROBOGEN_TASKS", str(shared_data / "robogen_tasks.yaml"))
    monkeypatch.setenv("BBSEA_TASKS", str(bbsea))
    for var in ("GENSIM_ROOT", "ROBOGEN_ROOT", "BBSEA_ROOT"):
        monkeypatch.delenv(var, raising=False)
    expected = {
        "gensim": ({"stacking": 37, "placement": 19, "piles": 11, "assembling": 14}, "Task: build-bridge \n Description: "),
        "robogen": ({"table-top": 21, "ground": 25}, "Adjust Chair Position: The robot arm will adjust"),
        "bbsea": ({"drawer": 1, "table-top": 1}, "Open the drawer"),
        "custom": ({"push": 3, "stack": 3}, "push the red block to the zone"),
    }
    with initialize_config_dir(version_base="1.3", config_dir=CONF):
        for pipeline, (groups, first_text) in expected.items():
            overrides = [f"pipeline={pipeline}", "debug=tiny"]
            if pipeline == "custom":
                overrides.append(f"pipeline.tasks_path={_custom_tasks(tmp_path)}")
            tasks = _load_like_the_entrypoint(compose("text_diversity", overrides=overrides).pipeline)
            assert {g: len(select_group(tasks, g)) for g in groups_of(tasks)} == groups, pipeline
            assert tasks[0].text.startswith(first_text), pipeline


def test_shipped_embedding_configs_instantiate_without_loading_models():
    with initialize_config_dir(version_base="1.3", config_dir=CONF):
        for name in ("minilm", "mpnet", "openai"):
            backend = instantiate(compose("text_diversity", overrides=[f"embedding={name}"]).embedding.backend)
            assert backend.model_id
        hf = compose("text_diversity", overrides=["embedding=hf"]).embedding.backend
        with pytest.raises(Exception, match="embedding.backend.model must name"):
            instantiate(hf)


def test_latex_escaping_is_single_pass():
    from simeval.writing.tables import to_latex

    tex = to_latex(["A", "B"], [[r"path\to_x", "{1} & 5%"]])
    assert r"path\textbackslash{}to\_x & \{1\} \& 5\%" in tex


def test_logger_configs_write_what_they_promise(tmp_path, monkeypatch):
    """Each logger config, instantiated as the entrypoints do: none writes nothing, csv writes metrics.csv, and
    wandb stays offline by its config alone (no WANDB_MODE) and never stores a secret from the run config."""
    monkeypatch.delenv("WANDB_MODE", raising=False)
    monkeypatch.setenv("WANDB_API_KEY", "")  # an online run would fail to log in, not upload
    run_config = {"judge": {"provider": {"api_key": "sk-never-stored-anywhere-123456"}}}
    with initialize_config_dir(version_base="1.3", config_dir=CONF):
        for name in ("none", "csv", "wandb"):
            cfg = compose("text_diversity", overrides=[f"logger={name}"])
            run_dir = tmp_path / name
            run_dir.mkdir()
            with instantiate(cfg.logger, _partial_=True)(run_dir=str(run_dir), run_config=run_config) as logger:
                logger.log_metrics({"all": {"div": 0.5, "n": 3}})
            files = [p for p in run_dir.rglob("*") if p.is_file()]
            if name == "none":
                assert files == []
            elif name == "csv":
                assert (run_dir / "metrics.csv").read_text().splitlines() == ["step,key,value", ",all/div,0.5",
                                                                              ",all/n,3"]
            else:
                assert list(run_dir.glob("wandb/offline-run-*/run-*.wandb")), files
            assert not any(b"sk-never-stored" in p.read_bytes() for p in files)


def _custom_tasks(tmp_path):
    path = tmp_path / "tasks.yaml"
    path.write_text(yaml.safe_dump({
        "push": ["push the red block to the zone", "push the pile of beans", "slide the box along the line"],
        "stack": ["stack two blocks", "stack three cups into a tower", "build a pyramid of blocks"],
    }))
    return path


def test_text_diversity_end_to_end_with_multirun_flag_after_an_override(tmp_path, openai_server):
    tasks = _custom_tasks(tmp_path)
    res = run("text_diversity.py", "pipeline=custom", f"pipeline.tasks_path={tasks}", "-m", "embedding=openai",
              f"embedding.backend.base_url={openai_server.base_url}", "debug=tiny", "logger=csv",
              f"hydra.sweep.dir={tmp_path / 'sweep'}", f"cache_dir={tmp_path / 'cache'}", "task_group=each,push")
    assert res.returncode == 0, res.stderr
    results = sorted((tmp_path / "sweep").rglob("result.json"))
    assert len(results) == 2
    rec = json.loads(results[0].read_text())
    assert rec["metric"] == "text_diversity" and rec["version"] and rec["status"] == "ok"
    assert rec["choices"]["pipeline"] == "custom" and rec["choices"]["embedding"] == "openai"
    assert set(rec["values"]) == {"push", "stack", "all"}
    assert rec["values"]["all"]["n"] == 6 and rec["values"]["push"]["div"] > 0
    assert (results[0].parent / ".hydra" / "config.yaml").is_file()
    assert (results[0].parent / "metrics.csv").is_file()
    assert set(json.loads(results[1].read_text())["values"]) == {"push"}
    # the identity the report merges by: the same tasks and model, a different task_group
    ident, ident1 = rec["identity"], json.loads(results[1].read_text())["identity"]
    assert ident["pipeline"] == "custom" and ident["embedding"] == "openai" and ident["seed"] == 0
    assert ident["model"] == "text-embedding-3-small" and ident["settings"]["n_boot"] == 20
    assert (ident["task_group"], ident1["task_group"]) == ("each", "push") and ident["tasks_sha"] == ident1["tasks_sha"]
    assert len(openai_server.requests) == 1  # the second job found every text in the cache


def test_config_errors_are_clear_and_fast(tmp_path):
    tasks = _custom_tasks(tmp_path)
    res = run("text_diversity.py", "pipeline=custom", f"pipeline.tasks_path={tasks}", "task_group=pull",
              f"hydra.run.dir={tmp_path / 'r'}", "embedding=openai", "embedding.backend.base_url=http://127.0.0.1:9/v1")
    assert res.returncode != 0 and "unknown task_group 'pull'; available: push, stack, all" in res.stderr
    res = run("text_diversity.py", "pipeline=bbsea", f"hydra.run.dir={tmp_path / 'r2'}", env={"BBSEA_ROOT": "",
                                                                                               "BBSEA_TASKS": ""})
    assert res.returncode != 0 and "pipeline.tasks_path" in res.stderr
    res = run("text_diversity.py", "--help")
    assert res.returncode == 0 and "pipeline: bbsea, custom, gensim, gensim_own, metaworld, robogen" in res.stdout


@pytest.mark.timeout(900)  # two real embedding models over 6 sweep jobs: ~90 s on 2 busy cores; its sweep may take 900
def test_table3_reproduces_the_paper_gensim_rows(shared_data, tmp_path):
    """The whole `make table3` path on the authors' file: sweep -> result.json -> report -> table3.csv."""
    env = {"GENSIM_DESCS": str(shared_data / "gensim_descs_grouped.yaml"),
           "ROBOGEN_TASKS": str(shared_data / "robogen_tasks.yaml"), "BBSEA_ROOT": "", "BBSEA_TASKS": ""}
    runs = tmp_path / "runs"
    res = run("text_diversity.py", "-m", "experiment=table3", "debug=tiny", f"hydra.sweep.dir={runs}",
              f"cache_dir={tmp_path / 'cache'}", env=env, timeout=900)
    assert res.returncode == 0, res.stderr[-3000:]
    out = tmp_path / "tables"
    res = run("report.py", "report=table3", f"report.runs_dir={runs}", f"report.out_dir={out}")
    assert res.returncode == 0, res.stderr
    rows = {(r["Method"], r["Task Group"]): r for r in csv.DictReader((out / "table3.csv").open())}
    paper = {"Stacking": ("0.49", "0.48"), "Placement": ("0.55", "0.52"), "Piles": ("0.42", "0.45"),
             "Assembling": ("0.53", "0.44"), "All": ("0.75", "0.70")}
    for group, (minilm, mpnet) in paper.items():
        assert (rows[("GenSim", group)]["MiniLM-L6-v2"], rows[("GenSim", group)]["Mpnet-base-v2"]) == (minilm, mpnet)
    assert rows[("RoboGen", "All")]["MiniLM-L6-v2"] not in ("—", "")
    assert rows[("BBSEA", "Drawer")]["MiniLM-L6-v2"] == "—"  # not configured: shown as missing, not dropped
    md = (out / "table3.md").read_text()
    assert "BBSEA [MiniLM-L6-v2] missing: set pipeline.root=... (or env BBSEA_ROOT)" in md
    assert (out / "table3.tex").read_text().count(r"\midrule") >= 3
    agreement = list(csv.DictReader((out / "table3_rank_agreement.csv").open()))
    gensim = next(r for r in agreement if r["Scope"] == "GenSim")
    assert gensim["Groups"] == "4" and float(gensim["Kendall tau"]) == pytest.approx(1 / 3, abs=0.01)
    # once committed, the table is replaced only when asked (one line naming the file and the key otherwise)
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-c", "commit.gpgsign=false"]
    subprocess.run(["git", "init", "-q"], cwd=out, check=True)
    subprocess.run([*git, "add", "-A"], cwd=out, check=True)
    subprocess.run([*git, "commit", "-qm", "committed"], cwd=out, check=True)
    (out / "table3.md").write_text("committed\n")
    res = run("report.py", "report=table3", f"report.runs_dir={runs}", f"report.out_dir={out}")
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "is a committed result" in res.stderr
    assert res.stderr.rstrip().endswith("replace it with overwrite=true (make: OVERWRITE=1)")
    assert (out / "table3.md").read_text() == "committed\n"
    res = run("report.py", "report=table3", f"report.runs_dir={runs}", f"report.out_dir={out}", "overwrite=true")
    assert res.returncode == 0 and (out / "table3.md").read_text() == md


@pytest.mark.parametrize("script,args,job_error", [
    ("quality.py", ["seed=1", "-m", "repeats=2"], "set bundles_dir=DIR"),
    ("agreement.py", ["seed=1", "-m", "n_boot=10"], "scores_path is not set"),
    ("report.py", ["report.digits=3", "-m", "report.runs_dir=/nonexistent/runs"],
     "report.runs_dir=/nonexistent/runs: no such folder"),
    ("collect.py", ["episodes=1", "-m", "task_group=nope"], "unknown task_group 'nope'"),
    ("import_data.py", ["format=ravens", "-m", "src=/nonexistent/demos"], "src=/nonexistent/demos does not exist; give the folder that holds the demonstrations"),
])
def test_every_entrypoint_accepts_multirun_flag_after_an_override(script, args, job_error, tmp_path):
    res = run(script, *args, f"hydra.sweep.dir={tmp_path}")
    out = res.stdout + res.stderr
    assert "unrecognized arguments" not in out  # what plain Hydra says to `-m` after an override
    assert job_error in out  # the sweep's job ran and met its own, clear, config error
    if script != "report.py":  # report.yaml silences Hydra's own log lines
        assert "Launching 1 jobs locally" in out
