"""Mistakes on the command line or in a config file stop before any data is read or model trained, with one line
naming the key, value or file and what is valid, exit code 2 and no traceback (Hydra itself prints a block of
text and exits 1 for most of them)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from simeval.cli import config_mistakes

ROOT = Path(__file__).resolve().parents[1]


def run(entrypoint: str, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    env.pop("HYDRA_FULL_ERROR", None)
    return subprocess.run([sys.executable, str(ROOT / "src" / f"{entrypoint}.py"), *args,
                           f"store={cwd / 'no-store'}", f"hydra.run.dir={cwd / 'run'}", f"hydra.sweep.dir={cwd / 'sweep'}"],
                          cwd=cwd, env=env, capture_output=True, text=True, timeout=120)


def one_line_exit_2(r: subprocess.CompletedProcess) -> str:
    assert r.returncode == 2, r.stderr[-2000:]
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("error: ")
    return lines[0]


@pytest.mark.parametrize("args, expected", [
    (["pipeline=nope"], "pipeline=nope: no conf/pipeline/nope.yaml; valid: bbsea, custom, gensim, robogen"),
    (["-m", "world_model=cpu,nope"], "world_model=nope: no conf/world_model/nope.yaml; valid: cpu, paper, tiny"),
    (["episodes=abc"], "episodes must be a whole number >= 1, got 'abc'"),
    (["episodes=1.5"], "episodes must be a whole number >= 1, got 1.5"),
    (["threads=0"], "threads must be a whole number >= 1, got 0"),
    (["eval_episodes=[1,2,3]"], "eval_episodes=[1, 2, 3]: expected [first, last] episode numbers"),
])
def test_diversity_names_the_bad_value_before_reading_the_store(args, expected, tmp_path):
    # the store does not exist: an error about the store would mean the value was checked too late
    assert expected in one_line_exit_2(run("diversity", *args, cwd=tmp_path))


@pytest.mark.parametrize("args, expected", [
    (["eval.seeds=-1"], "eval.seeds must be a whole number >= 1, got -1"),
    (["eval.seeds=abc"], "eval.seeds must be a whole number >= 1, got 'abc'"),
    (["episodes_per_task=abc"], "episodes_per_task must be a whole number >= 1, got 'abc'"),
    (["eval.max_steps=0"], "eval.max_steps must be a whole number >= 1, got 0"),
    (["policy=nope"], "policy=nope: no conf/policy/nope.yaml; valid: authors_gensim, cpu, official, tiny"),
    (["eval.variation={robot: {home_noise: 0.2}"], "override 'eval.variation={robot: {home_noise: 0.2}'"),
])
def test_generalization_names_the_bad_value_before_training(args, expected, tmp_path):
    assert expected in one_line_exit_2(run("generalization", *args, cwd=tmp_path))


def test_a_group_file_that_is_not_yaml_is_named_with_its_line(tmp_path):
    conf = tmp_path / "conf"
    (conf / "world_model").mkdir(parents=True)
    (conf / "world_model" / "mine.yaml").write_text("model:\n  image_size: 16\n  deter: [8\n")
    line = config_mistakes(["world_model=mine"], conf)
    assert line.startswith(f"{conf / 'world_model' / 'mine.yaml'}: line 4, column 1 is not valid YAML"), line


def test_what_hydra_resolves_itself_is_left_to_it(tmp_path):
    conf = tmp_path / "conf"
    (conf / "pipeline").mkdir(parents=True)
    (conf / "pipeline" / "a.yaml").write_text("name: a\n")
    assert config_mistakes(["pipeline=a", "episodes=3", "hydra/launcher=joblib", "~logger", "+x=1"], conf) is None


def test_group_files_on_a_searchpath_override_count_as_valid_choices(tmp_path):
    conf, extra = tmp_path / "conf", tmp_path / "extra"
    (conf / "embedding").mkdir(parents=True)
    (conf / "embedding" / "minilm.yaml").write_text("name: minilm\n")
    (extra / "embedding").mkdir(parents=True)
    (extra / "embedding" / "leaky.yaml").write_text("name: leaky\n")
    assert config_mistakes(["embedding=leaky", f"hydra.searchpath=[file://{extra}]"], conf) is None
    assert config_mistakes(["embedding=nope", f"hydra.searchpath=[file://{extra}]"], conf) == \
        "embedding=nope: no conf/embedding/nope.yaml; valid: leaky, minilm"
    # a package on the search path is opaque from here: Hydra decides
    assert config_mistakes(["embedding=nope", "hydra.searchpath=[pkg://somepkg.conf]"], conf) is None


def test_an_override_of_a_key_the_config_lacks_is_one_line_naming_the_valid_keys(tmp_path):
    """Hydra prints 'Could not override ...' as a block and exits 1; the keys listed as valid are the top-level
    keys of conf/collect.yaml and its defaults' groups (read here from the file, not from the product)."""
    import yaml

    line = one_line_exit_2(run("collect", "progress=false", cwd=tmp_path))
    doc = yaml.safe_load((ROOT / "conf" / "collect.yaml").read_text())
    groups = ["pipeline", "variation", "logger"]  # from its defaults; debug is an overlay (@package _global_)
    expected = [k for k in doc if k != "defaults"] + groups
    valid = line.split("valid here: ")[1].split(")")[0].split(", ")
    assert line.startswith("error: override progress: no such key (") and sorted(valid) == sorted(expected)
    assert line.endswith("to add a new key, write +progress=false")


def test_a_typo_in_a_nested_key_in_a_sweep_names_the_closest_keys(tmp_path):
    line = one_line_exit_2(run("diversity", "-m", "world_model.train.epoks=3", "episodes=1,2", cwd=tmp_path))
    assert "override world_model.train.epoks: no such key (did you mean " in line and "epochs" in line.split("?")[0]
    assert not (tmp_path / "sweep").exists() or not list((tmp_path / "sweep").glob("*/result.json"))


def test_hydra_full_error_keeps_hydras_own_report_of_a_composition_error(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "HYDRA_FULL_ERROR": "1"}
    r = subprocess.run([sys.executable, str(ROOT / "src" / "collect.py"), "progress=false",
                        f"hydra.run.dir={tmp_path / 'run'}"], cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 1 and "Traceback" in r.stderr and "ConfigCompositionException" in r.stderr


def test_a_launcher_that_does_not_exist_is_one_line_naming_the_installed_ones(tmp_path):
    """hydra/* groups also come from plugins, so config_mistakes leaves them to Hydra; its composition error is
    then made one line with the options Hydra found (the launcher plugins of requirements.txt among them)."""
    line = one_line_exit_2(run("diversity", "hydra/launcher=nope", cwd=tmp_path))
    assert line.startswith("error: In 'hydra/config': Could not find 'hydra/launcher/nope'; valid: ")
    assert {"basic", "joblib", "submitit_local", "slurm"} <= set(line.split("valid: ")[1].split(", "))
