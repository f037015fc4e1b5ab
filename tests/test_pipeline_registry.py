"""simeval.pipelines.registry: which Pipeline class a `conf/pipeline/<name>.yaml` selects (its `_target_`, else its
`kind`, else its
own code where it has `native:` settings, else its simeval suite), and the one-line errors where it selects none;
src/collect.py goes through it, so a pipeline without a collector is refused there in one line."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from simeval.errors import UserError
from simeval.pipelines.base import SuitePipeline
from simeval.pipelines.gensim_own.pipeline import GensimOwnPipeline
from simeval.pipelines.metaworld.pipeline import MetaworldPipeline
from simeval.pipelines.registry import KINDS, own_code_args, pipeline_class, pipeline_from_config
from simeval.sim.tasks.spec import suite_dir

ROOT = Path(__file__).resolve().parents[1]


def test_a_suite_pipeline_and_a_native_one_get_their_classes():
    built = pipeline_from_config({"name": "bbsea", "suite": "bbsea"})
    assert isinstance(built, SuitePipeline) and built.suite_dir == suite_dir("bbsea") and built.name == "bbsea"
    assert pipeline_class({"name": "gensim_own", "suite": None, "native": {"hz": 240}}) is GensimOwnPipeline
    assert pipeline_class({"name": "x", "kind": "suite", "suite": "gensim", "native": {"hz": 240}}) is SuitePipeline
    assert pipeline_class({"name": "metaworld", "kind": "metaworld", "suite": None}) is MetaworldPipeline
    assert set(KINDS) == {"suite", "gensim_checkout", "metaworld", "gymnasium"}
    assert pipeline_class({"name": "p", "_target_": "simeval.pipelines.base.SuitePipeline", "kind": "metaworld"}) \
        is SuitePipeline  # a plugin's _target_ is its class, whatever else the config says


def test_a_pipeline_with_nothing_to_run_or_an_unknown_kind_is_one_line():
    with pytest.raises(UserError) as e:
        pipeline_class({"name": "custom", "suite": None}, needs="collection")
    assert str(e.value) == ("pipeline=custom has no simeval suite (pipeline.suite is null) and no code of its own to "
                            "run (pipeline.native): collection needs one")
    with pytest.raises(UserError) as e:
        pipeline_class({"name": "mine", "kind": "mujoco"})
    assert str(e.value) == "pipeline.kind='mujoco': expected one of gensim_checkout, gymnasium, metaworld, suite"
    with pytest.raises(UserError) as e:
        pipeline_class({"name": "mine", "_target_": "simeval.errors.UserError"})
    assert str(e.value) == ("pipeline._target_=simeval.errors.UserError: is not a simeval.pipelines.base.Pipeline "
                            "class")
    for config, needs in (({"name": "custom", "kind": "suite", "suite": None}, "pipeline.suite"),
                          ({"name": "gensim", "kind": "gensim_checkout", "suite": "gensim"}, "pipeline.native")):
        with pytest.raises(UserError) as e:
            pipeline_class(config)
        assert str(e.value) == f"pipeline.kind={config['kind']} needs {needs} (pipeline={config['name']} sets none)"


def test_collect_refuses_a_pipeline_without_a_collector_in_one_line(tmp_path):
    r = subprocess.run([sys.executable, str(ROOT / "src" / "collect.py"), "pipeline=custom", f"store={tmp_path / 's'}",
                        f"hydra.run.dir={tmp_path / 'run'}"], cwd=tmp_path, capture_output=True, text=True,
                       env={**os.environ, "HYDRA_FULL_ERROR": "0"}, timeout=300, check=False)
    assert r.returncode == 2 and r.stderr.strip() == (
        "error: pipeline=custom has no simeval suite (pipeline.suite is null) and no code of its own to run "
        "(pipeline.native): collection needs one"), r.stderr[-2000:]
    assert not (tmp_path / "s").exists()
    r = subprocess.run([sys.executable, str(ROOT / "src" / "collect.py"), "pipeline=gensim", "pipeline.kind=nope",
                        f"store={tmp_path / 's'}", f"hydra.run.dir={tmp_path / 'run2'}"], cwd=tmp_path,
                       capture_output=True, text=True, env={**os.environ, "HYDRA_FULL_ERROR": "0"}, timeout=300,
                       check=False)
    assert r.returncode == 2 and r.stderr.strip() == ("error: pipeline.kind='nope': expected one of gensim_checkout, "
                                                      "gymnasium, metaworld, suite"), r.stderr[-2000:]


def test_a_missing_episode_message_names_the_collect_command_of_the_pipelines_own_code(tmp_path):
    assert own_code_args({"name": "gensim_own", "kind": "gensim_checkout", "native": {"hz": 240}}) == \
        " pipeline.root=<checkout>"
    assert own_code_args({"name": "metaworld", "kind": "metaworld"}) == ""
    assert own_code_args({"name": "bbsea", "kind": "suite", "suite": "bbsea"}) is None
    assert own_code_args({"name": "custom", "kind": None, "suite": None}) is None
    r = subprocess.run([sys.executable, str(ROOT / "src" / "diversity.py"), "pipeline=metaworld",
                        f"store={tmp_path / 'store'}", f"hydra.run.dir={tmp_path / 'run'}"], cwd=tmp_path,
                       capture_output=True, text=True, env={**os.environ, "HYDRA_FULL_ERROR": "0"}, timeout=300,
                       check=False)
    assert r.returncode == 2 and r.stderr.strip().endswith(
        f"collect them with the pipeline's own code: python src/collect.py pipeline=metaworld task_group=ml10 "
        f"episodes=50 store={tmp_path / 'store'}"), r.stderr[-2000:]
