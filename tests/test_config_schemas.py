"""The entrypoints' typed schemas (simeval.config_schemas): every schema key is set by its YAML, a value of the wrong
type stops at composition with one line naming the key, and a lower bound stops before any data is read."""

import dataclasses
import re
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.errors import ConfigCompositionException
from omegaconf import OmegaConf

from simeval.cli import composition_error_line
from simeval.config_schemas import SCHEMAS, check_values
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
    check_values(cfg, SCHEMAS[name])  # the shipped defaults are in bounds


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
    ("diversity", "heldout_episodes=abc", "heldout_episodes='abc': expected a list in brackets, e.g. [a,b]"),
    ("agreement", "figure_formats=png", "figure_formats='png': expected a list in brackets, e.g. [a,b]"),
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
    ("quality", "episodes.max_frames=1", "episodes.max_frames must be a whole number >= 2, got 1"),
    ("generalization", "tasks=5", "tasks=5: expected a task name, a list of names (e.g. tasks=[a,b]) or null"),
    ("collect", "tasks=[a,3]", "tasks=['a', 3]: expected a task name, a list of names (e.g. tasks=[a,b]) or null"),
    ("import_data", "groups=abc", "groups='abc': expected a mapping, e.g. groups={task: group}"),
])
def test_a_value_outside_its_rule_names_the_dotted_key(name, override, message):
    with pytest.raises(UserError, match=re.escape(message)):
        check_values(composed(name, [override]), SCHEMAS[name])


def test_an_optional_bounded_key_may_be_null_but_not_below_its_bound():
    check_values(composed("generalization", ["torch_threads=null", "eval.max_steps=null"]), SCHEMAS["generalization"])
    with pytest.raises(UserError, match="torch_threads must be a whole number >= 1, got 0"):
        check_values(composed("generalization", ["torch_threads=0"]), SCHEMAS["generalization"])


def test_a_notebook_composes_without_importing_simeval_first(tmp_path):
    """The schemas register from Hydra's plugin scan, so `compose` finds `<entrypoint>_schema` in a fresh process."""
    script = ("from hydra import compose, initialize_config_dir\n"
              f"with initialize_config_dir(config_dir={str(CONF)!r}, version_base='1.3'):\n"
              "    print(compose('diversity').episodes)\n")
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=tmp_path,
                       env={"PYTHONPATH": str(ROOT / "src"), "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0 and r.stdout.strip() == "40", r.stderr[-2000:]


@dataclasses.dataclass
class _Settings:
    count: int = 1
    rate: float = 0.5
    cap: "int | None" = None
    flag: bool = True
    name: str = "a"
    sizes: tuple = (1, 2)


@pytest.mark.parametrize("field, value, line", [
    ("count", "3", "s.count='3': expected a whole number"),
    ("count", True, "s.count=True: expected a whole number"),
    ("count", 2.0, "s.count=2.0: expected a whole number"),
    ("rate", "fast", "s.rate='fast': expected a number"),
    ("cap", 1.5, "s.cap=1.5: expected a whole number or null"),
    ("flag", 1, "s.flag=1: expected true or false"),
    ("name", 5, "s.name=5: expected text"),
])
def test_a_config_groups_settings_refuse_a_value_of_the_wrong_type(field, value, line):
    """Settings classes of config groups (world model, policy) check their scalar fields' types from the
    annotations (simeval.errors.check_field_types), worded as a schema's composition error."""
    from simeval.errors import check_field_types

    with pytest.raises(UserError) as e:
        check_field_types(_Settings(**{field: value}), "s")
    assert str(e.value) == line


def test_values_of_the_right_type_pass_a_settings_check():
    from simeval.errors import check_field_types

    check_field_types(_Settings(count=3, rate=2, cap=None, flag=False, name="b", sizes="not read"), "s")
    check_field_types(_Settings(cap=4), "s")


@pytest.mark.parametrize("kind, override, message", [
    ("table3", "report.statistic=foo", "report.statistic='foo': expected one of div, vendi, cos_dist, self_bleu"),
    ("table3", "report.digits=-1", "report.digits must be a whole number >= 0, got -1"),
    ("table3", "report.digits=abc", "report.digits='abc': expected a whole number"),
    ("table3", "report.rows=5", "report.rows=5: expected a list of mappings with pipeline, display, groups"),
    ("table4", "report.episodes=abc", "report.episodes='abc': expected a list of episode counts, e.g. [10,20,40]"),
    ("table4", "report.episodes=[10,0,40]", "report.episodes[] must be a whole number >= 1, got 0"),
    ("table4_heldout", "report.keep=5", "report.keep=5: expected a CSV path or a list of them"),
    ("table5", "+report.polcy=x", "report: unknown key(s) polcy; expected kind, runs_dir, out, figure, policy, keep"),
])
def test_a_report_kinds_settings_are_checked_before_anything_is_read(kind, override, message):
    from simeval.report.specs import check_report

    spec = OmegaConf.to_container(composed("report", [f"report={kind}", override]).report, resolve=True)
    with pytest.raises(UserError, match=re.escape(message)):
        check_report(spec)


def test_every_shipped_report_kind_passes_its_check():
    from simeval.report.specs import KIND_SETTINGS, check_report

    for kind in KIND_SETTINGS:
        check_report(OmegaConf.to_container(composed("report", [f"report={kind}"]).report, resolve=True))
    every = OmegaConf.to_container(composed("report", ["report=all"]).report, resolve=True)
    for step in every["steps"]:
        check_report(every[step], f"report.{step}")


@pytest.mark.parametrize("override, message", [
    ("profile.tasks_per_group=0", "profile.tasks_per_group must be a whole number >= 1, got 0"),
    ("profile.episodes=abc", "profile.episodes must be a whole number >= 1, got 'abc'"),
    ("profile.world_model_episodes=[0,1]", "profile.world_model_episodes[] must be a whole number >= 1, got 0"),
    ("profile.world_model_episodes=[1,2,8]", "8 is more than the profile.episodes=4 collected per task"),
    ("+profile.extra=1", "profile: unknown key(s) extra"),
])
def test_a_profiles_values_are_checked_whichever_stages_run(override, message):
    from simeval.orchestrate import check_profile

    with pytest.raises(UserError, match=re.escape(message)):
        check_profile(OmegaConf.to_container(composed("paper", [override]).profile, resolve=True))
    for name in ("quick", "cpu", "paper"):
        check_profile(OmegaConf.to_container(composed("paper", [f"profile={name}"]).profile, resolve=True))


SECTIONS = {"protocol.gate": "gate", "protocol.state_model": "state_model"}  # key in conf/protocol/heldout.yaml


def test_each_settings_section_is_in_the_diversity_config_and_lists_only_settings_its_dataclass_takes():
    from simeval.cli import SETTINGS_SECTIONS

    import yaml

    assert set(SETTINGS_SECTIONS) == set(SECTIONS)
    heldout = yaml.safe_load((CONF / "protocol" / "heldout.yaml").read_text())
    cfg = composed("diversity")
    for section, (module, name, owner) in SETTINGS_SECTIONS.items():
        assert owner == "protocol=heldout"  # the default protocol: composed here
        fields = {f.name for f in dataclasses.fields(getattr(__import__(module, fromlist=[name]), name))}
        listed = set(heldout[SECTIONS[section]])
        assert listed < fields, section  # some settings are left out of the yaml: what the error lines are for
        assert set(OmegaConf.select(cfg, section)) == listed


@pytest.mark.parametrize("section, key, default, value", [("protocol.gate", "n_boot", 1000, 500),
                                                          ("protocol.gate", "seed", 0, 7),
                                                          ("protocol.state_model", "lr", 1e-3, 0.01),
                                                          ("protocol.state_model", "hidden", 128, 64)])
def test_a_setting_the_yaml_leaves_out_names_its_default_and_the_plus_that_sets_it(section, key, default, value):
    from simeval.measures.dynamics_diversity.gate import GateConfig
    from simeval.measures.dynamics_diversity.state_reading import StateModelConfig

    with pytest.raises(ConfigCompositionException) as e:
        composed("diversity", [f"{section}.{key}={value}"])
    assert composition_error_line(e.value) == (f"override {section}.{key}: a setting the config does not list "
                                               f"(default {default!r}); to set it, write +{section}.{key}={value}")
    cfg = composed("diversity", [f"+{section}.{key}={value}"])  # the advice, followed, sets it
    settings = {"protocol.gate": GateConfig, "protocol.state_model": StateModelConfig}[section].from_dict(
        OmegaConf.to_container(OmegaConf.select(cfg, section)))
    assert getattr(settings, key) == value


def test_an_unknown_key_of_a_settings_section_lists_the_yaml_keys_and_those_set_with_a_plus():
    import yaml

    listed = list(yaml.safe_load((CONF / "protocol" / "heldout.yaml").read_text())["gate"])
    with pytest.raises(ConfigCompositionException) as e:
        composed("diversity", ["protocol.gate.nope=1"])
    assert composition_error_line(e.value) == (f"override protocol.gate.nope: no such key (valid here: "
                                               f"{', '.join(listed)}; with a leading +: n_boot, seed)")
    with pytest.raises(ConfigCompositionException) as e:  # a typo of a left-out setting: no '+' of the typo itself
        composed("diversity", ["protocol.gate.n_bot=1"])
    assert "(did you mean +protocol.gate.n_boot? valid here: " in composition_error_line(e.value)


def test_the_heldout_only_settings_are_the_keys_the_paper_protocol_lacks():
    import yaml

    from simeval.measures.dynamics_diversity.run import HELDOUT_BUDGET, HELDOUT_ONLY

    keys = {name: set(yaml.safe_load((CONF / "protocol" / f"{name}.yaml").read_text()))
            for name in ("heldout", "paper")}
    assert set(HELDOUT_ONLY) | set(HELDOUT_BUDGET) == keys["heldout"] - keys["paper"]
    assert keys["paper"] < keys["heldout"]


@pytest.mark.parametrize("override, section, form", [
    ("protocol.gate.n_boot=500", "gate", "+protocol.gate.n_boot="),  # a setting the heldout yaml leaves out
    ("protocol.gate.margin=0.1", "gate", "protocol.gate.margin="),
    ("protocol.state_model.lr=0.1", "state_model", "+protocol.state_model.lr=")])
def test_a_heldout_section_set_under_the_paper_protocol_says_which_protocol_has_it(override, section, form):
    with pytest.raises(ConfigCompositionException) as e:
        composed("diversity", ["protocol=paper", override])
    assert composition_error_line(e.value, "diversity", CONF) == (
        f"override {override.split('=')[0]}: protocol=paper has no {section} (a section of protocol=heldout); drop "
        f"it, or run it with protocol=heldout: protocol=heldout {form}...")
    value = override.split("=")[1]
    assert composed("diversity", ["protocol=heldout", form + value])  # the advice, followed, composes


def test_a_plus_on_a_key_the_config_has_says_to_drop_the_plus():
    with pytest.raises(ConfigCompositionException) as e:
        composed("diversity", ["+protocol.gate.margin=0.1"])
    line = composition_error_line(e.value)
    assert line.endswith("; to set it, drop the +: protocol.gate.margin=0.1")
    assert composed("diversity", ["protocol.gate.margin=0.1"]).protocol.gate.margin == 0.1  # the advice, followed
