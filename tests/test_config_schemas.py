"""The entrypoints' typed schemas (simeval.config_schemas): every schema key is set by its YAML, a value of the wrong
type stops at composition with one line naming the key, and a lower bound stops before any data is read."""

import dataclasses
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.errors import ConfigCompositionException
from omegaconf import OmegaConf

from simeval.cli import composition_error_line
from simeval.config_schemas import SCHEMAS, check_bounds
from simeval.errors import UserError

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"


def composed(name: str, overrides: list[str] = ()):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(name, overrides=list(overrides))


@pytest.mark.parametrize("name", sorted(SCHEMAS))
def test_each_schema_key_has_its_value_in_the_yaml_and_the_yaml_no_key_outside_the_schema(name):
    cfg = composed(name)
    assert OmegaConf.missing_keys(cfg) == set()  # nothing left MISSING: the YAML writes every default
    schema_keys = {f.name for f in dataclasses.fields(SCHEMAS[name])}
    assert set(cfg.keys()) == schema_keys
    check_bounds(cfg, SCHEMAS[name])  # the shipped defaults are in bounds


@pytest.mark.parametrize("name, override, line", [
    ("diversity", "episodes=abc", "episodes='abc': expected a whole number"),
    ("diversity", "episodes=2.5", "episodes=2.5: expected a whole number"),
    ("diversity", "eval.context=x", "eval.context='x': expected a whole number"),
    ("diversity", "compile=fast", "compile='fast': expected true or false"),
    ("diversity", "compile=null", "compile=null: expected true or false"),
    ("diversity", "heldout_episodes=[41,b]", "heldout_episodes[1]='b': expected a whole number"),
    ("quality", "budget_usd=lots", "budget_usd='lots': expected a number"),
    ("report", "overwrite=please", "overwrite='please': expected true or false"),
    ("generalization", "eval.videos=some", "eval.videos='some': expected true or false"),
    ("text_diversity", "seed=abc", "seed='abc': expected a whole number"),
    ("agreement", "n_boot=1e3", "n_boot=1000.0: expected a whole number"),
    ("evaluate", "dynamics.heldout=ten", "dynamics.heldout='ten': expected a whole number"),
    ("evaluate", "generalization.random_baseline=perhaps",
     "generalization.random_baseline='perhaps': expected true or false"),
    ("export_data", "overwrite=maybe", "overwrite='maybe': expected true or false"),
    ("import_data", "overwrite=sure", "overwrite='sure': expected true or false"),
])
def test_a_value_of_the_wrong_type_stops_at_composition_with_the_key_and_the_type(name, override, line):
    with pytest.raises(ConfigCompositionException) as e:
        composed(name, [override])
    assert composition_error_line(e.value) == line


def test_values_omegaconf_converts_are_accepted():
    cfg = composed("diversity", ["episodes=10", "compile=yes", "heldout_episodes=null"])
    assert cfg.episodes == 10 and cfg.compile is True and cfg.heldout_episodes is None


@pytest.mark.parametrize("name, override, message", [
    ("diversity", "episodes=0", "episodes must be a whole number >= 1, got 0"),
    ("diversity", "eval.batch_size=0", "eval.batch_size must be a whole number >= 1, got 0"),
    ("diversity", "videos=-1", "videos must be a whole number >= 0, got -1"),
    ("generalization", "eval.max_steps=0", "eval.max_steps must be a whole number >= 1, got 0"),
    ("collect", "seed_offset=-2", "seed_offset must be a whole number >= 0, got -2"),
    ("evaluate", "dynamics.heldout=0", "dynamics.heldout must be a whole number >= 1, got 0"),
    ("agreement", "seed=-1", "seed must be a whole number >= 0, got -1"),
])
def test_a_lower_bound_names_the_dotted_key(name, override, message):
    with pytest.raises(UserError, match=message.replace("(", r"\(")):
        check_bounds(composed(name, [override]), SCHEMAS[name])


def test_an_optional_bounded_key_may_be_null_but_not_below_its_bound():
    check_bounds(composed("generalization", ["torch_threads=null", "eval.max_steps=null"]), SCHEMAS["generalization"])
    with pytest.raises(UserError, match="torch_threads must be a whole number >= 1, got 0"):
        check_bounds(composed("generalization", ["torch_threads=0"]), SCHEMAS["generalization"])


def test_a_notebook_composes_without_importing_simeval_first(tmp_path):
    """The schemas register from Hydra's plugin scan, so `compose` finds `<entrypoint>_schema` in a fresh process."""
    script = ("from hydra import compose, initialize_config_dir\n"
              f"with initialize_config_dir(config_dir={str(CONF)!r}, version_base='1.3'):\n"
              "    print(compose('diversity').episodes)\n")
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=tmp_path,
                       env={"PYTHONPATH": str(ROOT / "src"), "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0 and r.stdout.strip() == "40", r.stderr[-2000:]
