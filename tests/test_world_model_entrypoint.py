"""src/diversity.py end to end (debug=tiny on a synthetic store), its user errors, and the Table 4 builder."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from simeval.errors import UserError

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "HYDRA_FULL_ERROR": "0"}


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "src" / "diversity.py"), *args], cwd=cwd, env=ENV,
                          capture_output=True, text=True, timeout=600)


def test_debug_overlay_is_the_tiny_preset_whatever_preset_is_chosen():
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    tiny = yaml.safe_load((ROOT / "conf" / "world_model" / "tiny.yaml").read_text())
    with initialize_config_dir(version_base="1.3", config_dir=str(ROOT / "conf")):
        for preset in ("cpu", "paper"):
            cfg = compose("diversity", overrides=["debug=tiny", f"world_model={preset}"])
            assert OmegaConf.to_container(cfg.world_model) == tiny
            assert cfg.protocol.steps == 40
        assert compose("diversity").world_model.name == "cpu"


def test_pipeline_without_suite_or_episodes_is_one_line_naming_what_is_missing(tmp_path):
    r = run("pipeline=custom", "task_group=drawer", f"store={tmp_path}/store", cwd=tmp_path)
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "custom" in r.stderr and "no simeval suite" in r.stderr
    assert "src/import_data.py" in r.stderr
    r = run("pipeline=bbsea", "task_group=drawer", f"store={tmp_path}/store", cwd=tmp_path)
    # the hint names this run's store, so following it fills the store the run reads; protocol=heldout (the
    # default) evaluates episodes 41-50, so it asks for 50 per task, protocol=paper for 40
    assert r.returncode == 2 and f"src/collect.py pipeline=bbsea task_group=drawer episodes=50 store={tmp_path}/store" in r.stderr
    r = run("pipeline=bbsea", "task_group=drawer", f"store={tmp_path}/store", "protocol=paper", cwd=tmp_path)
    assert r.returncode == 2 and f"src/collect.py pipeline=bbsea task_group=drawer episodes=40 store={tmp_path}/store" in r.stderr
    r = run("pipeline=gensim", "task_group=stacking", f"store={tmp_path}/store", cwd=tmp_path)
    assert r.returncode == 2 and "src/collect.py pipeline=gensim task_group=stacking" in r.stderr


def test_sweep_end_to_end_writes_results_and_table(tmp_path):
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    write_group(tmp_path / "store", "diverse", n_tasks=2, episodes=41, n_actions=10, size=16, pipeline="gensim")
    r = run("debug=tiny", "pipeline=gensim", "task_group=diverse", f"store={tmp_path}/store",
            f"checkpoint_dir={tmp_path}/ck", "logger=csv", "progress=false", "protocol=paper", "heldout_episodes=[41,41]",
            "hydra.sweep.dir=" + str(tmp_path / "sweep"), "-m", "episodes=10,40", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    recs = [json.loads(p.read_text()) for p in sorted((tmp_path / "sweep").rglob("result.json"))]
    assert [rec["identity"]["episodes"] for rec in recs] == [10, 40]
    for rec in recs:
        ident, ev = rec["identity"], rec["values"]["eval"]
        assert (ident["pipeline"], ident["task_group"], ident["preset"], ident["seed"]) == ("gensim", "diverse",
                                                                                            "tiny", 0)
        assert ev["frames"] == 2 * 40 * 11  # every row of the first 40 episodes of both tasks
        assert ev["image_error_per_pixel"] == pytest.approx(ev["image_error"] / (16 * 16 * 3))
        assert rec["values"]["heldout"]["episodes"] == [41, 41]
    assert (tmp_path / "sweep" / "0" / "metrics.csv").read_text().startswith("step,key,value")
    # the same command again: training is found finished in the checkpoint, the evaluation is the same number
    again = run("debug=tiny", "pipeline=gensim", "task_group=diverse", f"store={tmp_path}/store",
                f"checkpoint_dir={tmp_path}/ck", "progress=false", "protocol=paper", "heldout_episodes=[41,41]", "episodes=10",
                "hydra.run.dir=" + str(tmp_path / "again"), cwd=tmp_path)
    assert again.returncode == 0, again.stderr[-2000:]
    rec = json.loads((tmp_path / "again" / "result.json").read_text())
    assert rec["values"]["eval"]["image_error"] == recs[0]["values"]["eval"]["image_error"]
    table = subprocess.run([sys.executable, str(ROOT / "src" / "report.py"), "report=table4",
                            f"report.runs_dir={tmp_path / 'sweep'}", f"report.out={tmp_path / 't4'}",
                            f"report.figure={tmp_path / 't4.png'}"], env=ENV, capture_output=True, text=True, check=True)
    assert "| gensim | diverse | tiny |" in table.stdout and "115.0 / —" in table.stdout  # paper row, not run
    assert (tmp_path / "t4.png").stat().st_size > 0


def test_a_joblib_sweep_reads_windows_in_a_loader_worker(tmp_path):
    """hydra/launcher=joblib runs each job in a loky process, whose default start method is loky's: a DataLoader
    worker (world_model.train.num_workers=1, the paper preset's setting) could not start there ('Process' object
    has no attribute 'env'). The loader names its start method."""
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    write_group(tmp_path / "store", "diverse", n_tasks=2, episodes=2, n_actions=10, size=16, pipeline="gensim")
    r = run("debug=tiny", "pipeline=gensim", "task_group=diverse", f"store={tmp_path}/store", "protocol=paper", "eval_episodes=[1,2]",
            "heldout_episodes=null", "world_model.train.num_workers=1", "progress=false", "videos=0",
            f"checkpoint_dir={tmp_path}/ck", f"hydra.sweep.dir={tmp_path / 'sweep'}", "hydra/launcher=joblib",
            "hydra.launcher.n_jobs=2", "-m", "episodes=1,2", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    recs = [json.loads(p.read_text()) for p in sorted((tmp_path / "sweep").rglob("result.json"))]
    assert sorted(rec["identity"]["episodes"] for rec in recs) == [1, 2]
    assert all(rec["values"]["train"]["steps"] > 0 for rec in recs)


def test_sweep_on_collected_simulator_episodes(tiny_sim_store, tmp_path):
    """src/diversity.py on real episodes of simeval's simulator (3 of stack-two-blocks, src/collect.py debug=tiny):
    training on the first 2 and 3, evaluating on all 3, finite numbers under the right identity."""
    import math

    from simeval.episodes.store import read_meta

    rows = sum(read_meta(p)["n_steps"] for p in (tiny_sim_store / "gensim" / "stack-two-blocks").glob("episode_*.h5"))
    r = run("debug=tiny", "pipeline=gensim", "task_group=stacking", f"store={tiny_sim_store}",
            f"checkpoint_dir={tmp_path}/ck", "progress=false", "protocol=paper", "eval_episodes=[1,3]", "heldout_episodes=null",
            "hydra.sweep.dir=" + str(tmp_path / "sweep"), "-m", "episodes=2,3", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert ("gensim/stacking: the store holds 1 of the group's 6 tasks (stack-two-blocks); the reading is of those "
            "only (not read: ") in r.stdout + r.stderr
    recs = [json.loads(p.read_text()) for p in sorted((tmp_path / "sweep").rglob("result.json"))]
    assert [rec["identity"]["episodes"] for rec in recs] == [2, 3]
    for rec in recs:
        ident, v = rec["identity"], rec["values"]
        assert (ident["metric"], ident["pipeline"], ident["task_group"], ident["preset"], ident["camera"],
                ident["seed"]) == ("dynamics_diversity", "gensim", "stacking", "tiny", "front", 0)
        assert v["tasks"] == ["stack-two-blocks"] and v["heldout"] is None
        assert v["model"]["action_space"] == "joint_pos+suction" and v["model"]["action_dim"] == 7
        assert v["model"]["state_dim"] == 14
        ev = v["eval"]
        assert ev["frames"] == rows and ev["episodes"] == [1, 3]  # every row of the 3 episodes
        assert v["train"]["episodes"] == ident["episodes"] and v["train"]["steps"] > 0
        for k in ("image_error", "image_error_per_pixel", "state_error", "kl_dyn", "kl_rep", "open_loop_image_error",
                  "open_loop_state_error"):
            assert math.isfinite(ev[k]) and ev[k] >= 0, k
        assert ev["image_error_per_pixel"] == pytest.approx(ev["image_error"] / (16 * 16 * 3))


def test_too_few_episodes_names_the_collect_command_for_this_store_and_group(tiny_sim_store, tmp_path):
    """Following the hint must fill the store the run reads (not the collector's default) with the tasks it holds
    (collected with tasks=stack-two-blocks: not the group's other five, which would change what the next reading
    reads), recorded as the run's debug overlay records (debug=tiny: 32x32 frames; without it collect records
    64x64)."""
    r = run("debug=tiny", "pipeline=gensim", "task_group=stacking", f"store={tiny_sim_store}", "episodes=5",
            "protocol=paper", "progress=false", f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr[-2000:]
    assert r.stderr.strip() == (
        "error: task 'stack-two-blocks' has 3 episodes; training on 5 and evaluating on episodes 1-40 needs 40 per "
        f"task (collect them: python src/collect.py pipeline=gensim 'tasks=[stack-two-blocks]' episodes=40 "
        f"store={tiny_sim_store} debug=tiny)")
    r = run("debug=tiny", "pipeline=gensim", "task_group=stacking", f"store={tiny_sim_store}", "episodes=5",
            "progress=false", f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)  # protocol=heldout: 41-50
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and (
        f"evaluating on episodes 41-50 needs 50 per task (collect them: python src/collect.py pipeline=gensim "
        f"'tasks=[stack-two-blocks]' episodes=50 store={tiny_sim_store} debug=tiny; or evaluate episodes the store has "
        "past the training ones, eval_episodes=[6,LAST], or use protocol=paper)") in r.stderr, r.stderr


def test_a_damaged_episode_is_named_with_the_command_that_collects_the_stores_tasks_again(tiny_sim_store, tmp_path):
    import shutil

    store = tmp_path / "store"
    shutil.copytree(tiny_sim_store, store)
    damaged = sorted((store / "gensim" / "stack-two-blocks").glob("episode_*.h5"))[1]
    damaged.write_bytes(damaged.read_bytes()[:1000])
    r = run("debug=tiny", "pipeline=gensim", "task_group=stacking", f"store={store}", "episodes=2",
            "protocol=paper", "eval_episodes=[1,3]", "progress=false", f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr[-2000:]
    assert r.stderr.startswith(f"error: {damaged}") and r.stderr.rstrip().endswith(
        "collecting again moves it aside and makes it anew: python src/collect.py pipeline=gensim "
        f"'tasks=[stack-two-blocks]' episodes=3 store={store} debug=tiny"), r.stderr


def test_a_compile_value_that_is_not_true_or_false_is_one_line(tmp_path):
    r = run("debug=tiny", "compile=fast", f"store={tmp_path}/store", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.strip() == "error: compile='fast': expected true or false", r.stderr[-2000:]


def test_capture_is_true_or_false_and_needs_a_gpu_one_line_each(tmp_path):
    r = run("debug=tiny", "capture=maybe", f"store={tmp_path}/store", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.strip() == "error: capture='maybe': expected true or false", r.stderr[-2000:]
    r = run("debug=tiny", "capture=true", "device=cpu", f"store={tmp_path}/store", cwd=tmp_path)
    fix = ("capture=false or device=cuda" if torch.cuda.is_available() else
           "capture=false (this machine has no CUDA GPU)")
    assert r.returncode == 2 and r.stderr.strip() == ("error: capture=true needs a CUDA GPU (device=cpu resolves to "
                                                      f"cpu here); use {fix}"), r.stderr[-2000:]
    assert not (tmp_path / "store").exists()  # refused before any data is read


def test_a_window_longer_than_every_episode_of_a_task_is_one_line_naming_the_tasks():
    """Hand-made episodes: task a's training episodes have 30 and 41 rows, b's 25 and 28, c's 50 of which only the
    20-row one is a training episode. A window of 40 leaves b and c (training episodes only) with no window; the
    windows' starts (offset, pad_start, a random offset per epoch) count as window_starts places them."""
    from simeval.episodes.dataset import EpisodeInfo, WindowSpec, epoch_offset
    from simeval.measures.dynamics_diversity.run import check_every_task_has_windows

    rows = [("a", 30), ("a", 41), ("b", 25), ("b", 28), ("c", 20), ("c", 50)]
    infos = [EpisodeInfo(task=t, seed=i, group="g", n_rows=n, action_space={}) for i, (t, n) in enumerate(rows)]
    train = np.array([True, True, True, True, True, False])
    with pytest.raises(UserError) as e:
        check_every_task_has_windows(infos, train, WindowSpec(length=40))
    assert str(e.value) == (
        "world_model.window.length=40: 2 of 3 tasks have no training episode that holds a window, so the model would "
        "never see them (longest rows: b (28), c (20)); use world_model.window.length=20 or "
        "world_model.window.pad_end=true")
    # with offsets drawn per epoch, more epochs draw more of them: the message names that remedy too
    remedy = (r"pad_end=true, or more epochs: these 2 draw [12] window offset\(s\) \(world_model.train.epochs; "
              r"under protocol=heldout a larger protocol.steps\)$")
    with pytest.raises(UserError, match=remedy):
        check_every_task_has_windows(infos, train, WindowSpec(length=40, random_offset=True), seed=0, epochs=2)
    check_every_task_has_windows(infos, train, WindowSpec(length=20))  # every task has a 20-row episode
    check_every_task_has_windows(infos, train, WindowSpec(length=40, pad_end=True))  # padded windows reach them
    # windows may begin 20 rows before row 0: [-20, 20) fits c's 20 rows
    check_every_task_has_windows(infos, train, WindowSpec(length=40, stride=10, pad_start=20))
    # a fixed first start at row 1 leaves c's 20 rows no window of 20
    with pytest.raises(UserError, match=r"1 of 3 tasks .* \(longest rows: c \(20\); the windows start 1 row in at the "
                                        r"earliest\); use world_model.window.length=19 "):
        check_every_task_has_windows(infos, train, WindowSpec(length=20, stride=4, offset=1))
    # with a random offset, the offsets the epochs draw count: seed 0 draws 3 and 2 for 2 epochs, seed 1 draws 0
    random = WindowSpec(length=20, stride=4, random_offset=True)
    assert [epoch_offset(random, 0, e) for e in range(2)] == [3, 2] and epoch_offset(random, 1, 0) == 0
    with pytest.raises(UserError, match=r"\(longest rows: c \(20\); the windows start 2 rows in at the earliest\); "
                                        r"use world_model.window.length=18 "):
        check_every_task_has_windows(infos, train, random, seed=0, epochs=2)
    check_every_task_has_windows(infos, train, WindowSpec(length=18, stride=4, random_offset=True), seed=0, epochs=2)
    check_every_task_has_windows(infos, train, random, seed=1, epochs=1)


def test_frames_smaller_than_the_model_are_refused_not_upsampled(tmp_path):
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    write_group(tmp_path / "store", "diverse", n_tasks=2, episodes=2, n_actions=10, size=16, pipeline="gensim")
    common = ("debug=tiny", "pipeline=gensim", "task_group=diverse", f"store={tmp_path}/store", "protocol=paper", "eval_episodes=[1,2]",
              "heldout_episodes=null", "progress=false", "checkpoint_dir=null", "episodes=1")
    r = run(*common, "world_model.model.image_size=32", f"hydra.run.dir={tmp_path / 'up'}", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr[-2000:]
    assert r.stderr.startswith("error: the episodes' frames are 16x16, smaller than the model's "
                               "world_model.model.image_size=32: they would be upsampled")
    r = run(*common, "world_model.model.image_size=8", f"hydra.run.dir={tmp_path / 'down'}", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]  # downsampled, as the cpu preset does with a 128x128 store


def test_a_compiler_that_cannot_build_is_one_line_saying_to_run_without_compile(tmp_path):
    """compile=true where inductor finds no working C++ compiler (CXX names none; an empty compile cache, so
    nothing is reused): one line and exit 2 instead of inductor's traceback after the first step."""
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    write_group(tmp_path / "store", "diverse", n_tasks=2, episodes=2, n_actions=10, size=16, pipeline="gensim")
    env = {**ENV, "CXX": str(tmp_path / "no-such-g++"), "TORCHINDUCTOR_CACHE_DIR": str(tmp_path / "inductor")}
    r = subprocess.run([sys.executable, str(ROOT / "src" / "diversity.py"), "debug=tiny", "pipeline=gensim",
                        "task_group=diverse", f"store={tmp_path}/store", "protocol=paper", "eval_episodes=[1,2]", "heldout_episodes=null",
                        "progress=false", "checkpoint_dir=null", "episodes=1", "compile=true",
                        f"hydra.run.dir={tmp_path / 'run'}"], cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr[-2000:]
    assert r.stderr.startswith("error: compile=true: torch.compile could not build the model's steps (")
    assert r.stderr.rstrip().endswith("); run with compile=false")


def test_a_group_the_suite_lacks_gets_the_suites_groups_not_a_failing_command(tmp_path):
    r = run("pipeline=bbsea", "task_group=table-top", f"store={tmp_path}/store", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1
    assert "the bbsea suite's groups are drawer, table" in r.stderr and "task_group=table-top episodes" not in r.stderr


def test_the_sweep_runs_on_imported_ravens_demos(tmp_path):
    """Imported episodes, not the suite's: GenSim/Ravens demos go through src/import_data.py into a store, and the
    paper's sweep runs on them as typed (pipeline gensim, the importer's group, the Ravens front camera)."""
    from helpers import _write_ravens

    _write_ravens(tmp_path / "data", episodes=3, t=10)
    imp = subprocess.run([sys.executable, str(ROOT / "src" / "import_data.py"), "format=ravens",
                          f"src={tmp_path / 'data'}", f"store={tmp_path / 'store'}", "image_size=[16,16]",
                          f"hydra.run.dir={tmp_path / 'import'}"], cwd=tmp_path, env=ENV, capture_output=True,
                         text=True, timeout=600)
    assert imp.returncode == 0, imp.stderr[-2000:]
    r = run("debug=tiny", "pipeline=gensim", "task_group=stacking", "camera=color_0", f"store={tmp_path}/store",
            f"checkpoint_dir={tmp_path}/ck", "progress=false", "videos=0", "protocol=paper", "eval_episodes=[1,3]",
            "heldout_episodes=null", f"hydra.sweep.dir={tmp_path}/sweep", "-m", "episodes=1,2", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    results = [json.loads((tmp_path / "sweep" / str(i) / "result.json").read_text()) for i in (0, 1)]
    assert [res["identity"]["episodes"] for res in results] == [1, 2]
    for res in results:
        ev = res["values"]["eval"]
        assert res["identity"]["task_group"] == "stacking" and res["identity"]["camera"] == "color_0"
        # 3 imported episodes of 11 rows, evaluated on ranks 1-3: every frame of every episode counts once
        assert ev["frames"] == 33 and 0 < ev["image_error"] < 16 * 16 * 3


def _record(pipeline: str, group: str, episodes: int, error: float) -> dict:
    return {"metric": "dynamics_diversity", "status": "ok",
            "identity": {"pipeline": pipeline, "task_group": group, "episodes": episodes, "preset": "cpu"},
            "values": {"eval": {"image_error": error, "image_error_per_pixel": error / 12288}}}


def test_a_table_row_refuses_runs_of_different_settings_under_one_preset():
    """Seeds of one setting are averaged; runs whose windows differ (or any other world-model setting or the camera)
    are not, though they share a preset name: one line naming the row and the setting."""
    from simeval.measures.dynamics_diversity import table4

    def rec(episodes, error, length, seed=0):
        r = _record("robogen", "ground", episodes, error)
        r["identity"].update(seed=seed, camera="front", settings={"world_model": {"window": {"length": length}}})
        return r

    rows = table4.build([rec(10, 200.0, 20), rec(10, 100.0, 20, seed=1), rec(20, 80.0, 20)])
    assert rows[[r["group"] for r in rows].index("ground")]["ours_10"] == 150.0  # two seeds of one setting
    with pytest.raises(UserError) as e:
        table4.build([rec(10, 200.0, 40), rec(20, 80.0, 20)])
    assert str(e.value) == ("robogen/ground (preset cpu): its runs differ in world_model.window.length "
                            "(world_model.window.length: 20, 40); a row holds runs of one setting: give the report a "
                            "folder with one setting's runs (report.runs_dir=..., or --root where a script takes it)")


def test_a_table_extended_with_keep_holds_the_earlier_cells_and_the_new_runs(tmp_path):
    """--keep: the committed table gathers groups run on different machines; each cell comes from exactly one side."""
    from simeval.errors import UserError
    from simeval.measures.dynamics_diversity import table4

    earlier = table4.build([_record("gensim", "stacking", k, e) for k, e in ((10, 47.195245993035456), (20, 35.5),
                                                                            (40, 27.2))]
                           + [_record("bbsea", "table", 10, 152.8)])
    table4.write(earlier, tmp_path / "earlier")
    kept = table4.read_rows(tmp_path / "earlier.csv")
    assert kept == earlier  # every number survives the CSV exactly (47.195245993035456 included)

    fresh = table4.build([_record("bbsea", "table", 20, 102.4), _record("bbsea", "table", 40, 77.2),
                          _record("gensim", "piles", 10, 70.1)])
    rows = {(r["pipeline"], r["group"]): r for r in table4.merge(kept, fresh)}
    stacking, table, piles = rows[("gensim", "stacking")], rows[("bbsea", "table")], rows[("gensim", "piles")]
    assert [stacking[f"ours_{k}"] for k in (10, 20, 40)] == [47.195245993035456, 35.5, 27.2]  # only in the kept one
    assert [table[f"ours_{k}"] for k in (10, 20, 40)] == [152.8, 102.4, 77.2]  # 10 kept, 20 and 40 new
    assert [table[f"runs_{k}"] for k in (10, 20, 40)] == [1, 1, 1]
    assert [piles[f"ours_{k}"] for k in (10, 20, 40)] == [70.1, None, None]
    assert (stacking["preset"], piles["preset"]) == ("cpu", "cpu")  # the paper-only rows of those groups are gone
    assert rows[("gensim", "assembling")]["preset"] == "" and rows[("gensim", "assembling")]["paper_10"] == 105.4
    assert len(rows) == len(table4.merge(kept, fresh))  # one row per group: nothing doubled

    # a new run of a cell the earlier table has: the new number wins
    newer = table4.merge(kept, table4.build([_record("bbsea", "table", 10, 150.0)]))
    assert next(r for r in newer if r["group"] == "table")["ours_10"] == 150.0

    quick = table4.build([_record("bbsea", "table", 1, 300.0)], episodes=(1, 2, 4))
    with pytest.raises(UserError, match="column 10 holds runs on 10 episodes per task, this table's on 1"):
        table4.merge(kept, quick, episodes=(1, 2, 4))
    (tmp_path / "other.csv").write_text("group,error\nstacking,1\n")
    with pytest.raises(UserError, match="other.csv: not a Table 4 CSV .* header should be pipeline,group,preset"):
        table4.read_rows(tmp_path / "other.csv")


def test_keep_of_a_missing_file_or_without_runs_is_one_line(tmp_path):
    def table(*args):
        return subprocess.run([sys.executable, str(ROOT / "src" / "report.py"), "report=table4",
                               f"report.out={tmp_path / 't4'}", f"report.figure={tmp_path / 't4.png'}", *args], env=ENV,
                              capture_output=True, text=True)

    r = table(f"report.runs_dir={tmp_path}", f"report.keep=[{tmp_path / 'nope.csv'}]")
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "report.keep: " in r.stderr and "nope.csv: cannot read it" in r.stderr
    # a mistyped runs_dir beside keep is an error, not the kept table written again as if nothing were new
    from simeval.measures.dynamics_diversity import table4

    table4.write(table4.build([_record("gensim", "stacking", 10, 47.2)]), tmp_path / "earlier")
    r = table(f"report.runs_dir={tmp_path / 'typo'}", f"report.keep=[{tmp_path / 'earlier.csv'}]")
    assert r.returncode == 2 and f"report.runs_dir={tmp_path / 'typo'}: no such folder" in r.stderr
    assert not (tmp_path / "t4.csv").exists()
    # a blank line at the end and a byte-order mark (a spreadsheet's save) are read as the table
    text = (tmp_path / "earlier.csv").read_text()
    (tmp_path / "edited.csv").write_text("\ufeff" + text + "\n\n", encoding="utf-8")
    assert table4.read_rows(tmp_path / "edited.csv") == table4.read_rows(tmp_path / "earlier.csv")
    lines = text.splitlines()
    (tmp_path / "extra.csv").write_text("\n".join([lines[0], lines[1] + ",7", *lines[2:]]) + "\n")
    with pytest.raises(UserError, match="extra.csv, line 2: 19 cells, expected 18"):
        table4.read_rows(tmp_path / "extra.csv")


def test_kept_rows_must_have_runs_on_this_tables_episodes(tmp_path):
    """A 10/20/40 table kept under report.episodes=[1,2,4] would put 10-episode numbers in a column labelled 1."""
    from simeval.measures.dynamics_diversity import table4

    kept = table4.build([_record("gensim", "stacking", 10, 47.2)])
    fresh = table4.build([_record("bbsea", "table", 1, 300.0)], episodes=(1, 2, 4))
    with pytest.raises(UserError, match="gensim/stacking: the kept table's column 10 holds runs on 10 episodes per "
                                        "task, this table's on 1"):
        table4.merge(kept, fresh, episodes=(1, 2, 4))


def test_a_kept_cell_that_is_not_a_number_names_its_line_and_column(tmp_path):
    from simeval.measures.dynamics_diversity import table4

    table4.write(table4.build([_record("gensim", "stacking", 10, 47.2)]), tmp_path / "t4")
    text = (tmp_path / "t4.csv").read_text().replace("47.2", "abc")
    (tmp_path / "bad.csv").write_text(text)
    line = next(i for i, ln in enumerate(text.splitlines(), start=1) if "abc" in ln)
    with pytest.raises(UserError, match=f"bad.csv, line {line}, column ours_10: 'abc' is not a number"):
        table4.read_rows(tmp_path / "bad.csv")
