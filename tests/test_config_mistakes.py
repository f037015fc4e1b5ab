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
    (["pipeline=nope"], "pipeline=nope: no conf/pipeline/nope.yaml; valid: bbsea, custom, gensim, gensim_own, metaworld, robogen"),
    (["-m", "world_model=cpu,nope"], "world_model=nope: no conf/world_model/nope.yaml; valid: cpu, paper, tiny"),
    (["episodes=abc"], "episodes='abc': expected a whole number"),
    (["episodes=1.5"], "episodes=1.5: expected a whole number"),
    (["threads=0"], "threads must be a whole number >= 1, got 0"),
    (["eval_episodes=[1,2,3]"], "eval_episodes=[1, 2, 3]: expected [first, last] episode numbers"),
    (["eval.context=100"], "eval.context=100: expected 1 <= context < window length (20)"),
    (["checkpoint_dir=a_file"], "checkpoint_dir=a_file: is a file, not a folder"),
    (["protocol.exclude_robot_from_loss=maybe"], "protocol.exclude_robot_from_loss='maybe': expected true or false"),
    (["protocol.mask_margin=-1"], "protocol.mask_margin=-1: expected a whole number of pixels >= 0"),
    (["protocol.mask_margin=null"], "protocol.mask_margin=null: expected a whole number of pixels >= 0"),
    (["protocol.steps=0"], "protocol.steps=0: the heldout protocol trains every episode count"),
    (["protocol.gate.margin=2"], "protocol.gate.margin=2: expected a skill in [0, 1)"),
    (["protocol.gate.margin=abc"], "protocol.gate.margin='abc': expected a number"),
    (["protocol.state_model.max_steps=abc"], "protocol.state_model.max_steps must be a whole number >= 1"),
    (["+protocol.gate.margn=0.1"], "protocol.gate: unknown key(s) margn; expected margin, min_task_share"),
    (["protocol.gate=5"], "protocol.gate=5: expected a mapping of its settings (margin, min_task_share, n_boot, seed)"),
    (["protocol.gate=[1,2]"], "override protocol.gate=[1,2]: protocol.gate is a section of settings, not one value; "
                              "set its keys one by one (protocol.gate.<key>=...; keys: margin, min_task_share)"),
    (["protocol.state_model=5"], "protocol.state_model=5: expected a mapping of its settings (hidden, layers, lr"),
    (["protocol.state_model=5"], "with a leading + for one the yaml does not list); or null for no state reading"),
    (["+protocol.gate.n_boot=0"], "protocol.gate.n_boot must be a whole number >= 100, got 0"),
    (["protocol=paper", "+protocol.gate.n_boot=500"], "+protocol.gate.n_boot=500: protocol=paper has no gate (a "
                                                      "section of protocol=heldout); drop it, or run it with "
                                                      "protocol=heldout: protocol=heldout +protocol.gate.n_boot=500"),
    (["protocol=paper", "+protocol.pixels=false"], "drop it, or run it with protocol=heldout: protocol=heldout "
                                                   "protocol.pixels=false"),  # heldout lists pixels: no '+'
    # in either order, before the heldout job runs (as the run's own check, it would refuse only the paper job)
    (["-m", "protocol=heldout,paper", "+protocol.gate.n_boot=500"], "this sweep runs protocol=paper; drop it, or "
                                                                    "sweep protocol=heldout alone: protocol=heldout "
                                                                    "+protocol.gate.n_boot=500"),
    (["-m", "protocol=paper,heldout", "protocol.gate.margin=0.1"], "sweep protocol=heldout alone: protocol=heldout "
                                                                   "protocol.gate.margin=0.1"),
    (["protocol=paper", "protocol.pixels=false"], "protocol=paper has no pixels (a setting of protocol=heldout)"),
    (["-m", "episodes=10,20", "--cfg", "job"], "-m and --cfg: one at a time"),
    (["protocol.state_model.val_share=1"], "protocol.state_model.val_share=1: expected a share in (0, 1)"),
    (["protocol.state_model.lr_schedule=linear"], "protocol.state_model.lr_schedule='linear': expected constant or "
                                                    "cosine"),
    (["protocol.state_model.patience=0"], "protocol.state_model.patience must be a whole number >= 1"),
    (["protocol.pixels=maybe"], "protocol.pixels='maybe': expected true (the world model's reading beside the state"),
    (["protocol.pixels=false", "protocol.state_model=null"], "protocol.pixels=false with protocol.state_model=null: "
                                                              "the run would read nothing"),
    (["protocol.model.pixel_norm=zscore"], "world_model.model.pixel_norm='zscore': expected one of none, standardise"),
    (["world_model.train.lr=fast"], "world_model.train.lr='fast': expected a number"),
    (["world_model.train.max_steps=1.5"], "world_model.train.max_steps=1.5: expected a whole number or null"),
    (["world_model.model.free_nats=abc"], "world_model.model.free_nats='abc': expected a number"),
    (["world_model.unimix=0.1"], "override world_model.unimix: no such key (did you mean world_model.model.unimix? "
                                 "valid here: name, model, train, window)"),
])
def test_diversity_names_the_bad_value_before_reading_the_store(args, expected, tmp_path):
    (tmp_path / "a_file").write_text("")
    # the store does not exist: an error about the store would mean the value was checked too late
    assert expected in one_line_exit_2(run("diversity", *args, cwd=tmp_path))


@pytest.mark.parametrize("args, expected", [
    (["eval.seeds=-1"], "eval.seeds must be a whole number >= 1, got -1"),
    (["eval.seeds=abc"], "eval.seeds='abc': expected a whole number"),
    (["episodes_per_task=abc"], "episodes_per_task='abc': expected a whole number"),
    (["eval.max_steps=0"], "eval.max_steps must be a whole number >= 1, got 0"),
    (["policy=nope"], "policy=nope: no conf/policy/nope.yaml; valid: authors_gensim, authors_gensim_cpu, cpu, official, random, tiny"),
    (["eval.variation={robot: {home_noise: 0.2}"], "override 'eval.variation={robot: {home_noise: 0.2}'"),
    (["eval.variation={robot: {home_nois: 0.2}}"], "variation.robot: unknown knob(s) ['home_nois']"),
    (["eval.variation=[1]"], "eval.variation=[1]: expected a mapping of knobs"),
    (["eval.variation={}"], "eval.variation={}: expected a mapping of knobs"),  # would vary nothing
    (["eval.variation=false"], "eval.variation=False: expected a mapping of knobs"),
    (["eval.splits=[train,tst]"], "eval.splits: split 'tst' is not one of train, eval, heldout"),
    (["eval.splits=tst"], "eval.splits: split 'tst' is not one of"),  # one name, not the letters t, s, t
    (["heldout_tasks=nope"], "heldout_tasks=['nope']: ['nope'] not in task_group=stacking"),
    (["checkpoint_dir=a_file"], "checkpoint_dir=a_file: is a file, not a folder"),
    (["policy.train.lr=abc"], "policy.train.lr='abc': expected a number"),
    (["policy.model.stem_pool=maybe"], "policy.model.stem_pool='maybe': expected true or false"),
    (["tasks=5"], "tasks=5: expected a task name, a list of names (e.g. tasks=[a,b]) or null"),
])
def test_generalization_names_the_bad_value_before_training(args, expected, tmp_path):
    (tmp_path / "a_file").write_text("")
    assert expected in one_line_exit_2(run("generalization", *args, cwd=tmp_path))


# the held-out budget and loss too: protocol=paper once listed them as null, so a value given there was taken and
# never read (a fresh-clone trial's protocol=paper protocol.steps=100 ran on the preset's epochs, exit 0)
@pytest.mark.parametrize("setting", ["+protocol.gate.n_boot=500", "+protocol.pixels=false", "protocol.steps=100",
                                     "protocol.lr=0.5", "protocol.horizon=2", "protocol.mask_margin=3",
                                     "protocol.exclude_robot_from_loss=true"])
@pytest.mark.parametrize("protocol", [["protocol=paper"], ["-m", "protocol=heldout,paper"]])
def test_a_heldout_setting_under_the_paper_protocol_stops_before_hydra_makes_a_folder(setting, protocol, tmp_path):
    # with '+' Hydra composes it; refused only in the run, a kill in that second would leave an empty run folder,
    # and a sweep's heldout job would run first
    line = one_line_exit_2(run("diversity", *protocol, setting, cwd=tmp_path))
    assert line.startswith(f"error: {setting}: protocol=paper has no ")
    assert not (tmp_path / "run").exists() and not (tmp_path / "sweep").exists()


def test_a_glob_sweep_over_the_protocol_is_checked_like_a_list_and_does_not_crash_the_check(tmp_path):
    # Hydra expands glob() with its config loader, which does not exist before Hydra runs (a trial's traceback)
    assert config_mistakes(["-m", "protocol=glob(*)"], ROOT / "conf", "diversity") is None
    line = one_line_exit_2(run("diversity", "-m", "protocol=glob(*)", "protocol.steps=100", cwd=tmp_path))
    assert "and this sweep runs protocol=paper" in line
    assert config_mistakes(["-m", "protocol=glob(*,exclude=paper)", "protocol.steps=100"], ROOT / "conf",
                           "diversity") is None


def test_without_the_pre_hydra_check_the_run_still_refuses_a_heldout_setting_under_the_paper_protocol(tmp_path):
    """Another config folder (--config-dir) skips the check before Hydra; the run reads its own overrides."""
    (tmp_path / "mine").mkdir()
    line = one_line_exit_2(run("diversity", "--config-dir", str(tmp_path / "mine"), "protocol=paper",
                               "++protocol.lr=0.1", cwd=tmp_path))
    assert line == ("error: ++protocol.lr=0.1: protocol=paper has no lr (a setting of protocol=heldout); drop it, or "
                    "run it with protocol=heldout")


def test_an_os_error_of_a_runs_own_work_is_not_said_to_be_hydras_run_folder(tmp_path):
    from simeval.cli import _hydra_making_a_folder

    (tmp_path / "a_file").write_text("")
    with pytest.raises(FileExistsError) as e:
        (tmp_path / "a_file").mkdir(parents=True)  # a mkdir of simeval's (or a test's), not Hydra's
    assert not _hydra_making_a_folder(e.value)


def test_the_protocol_a_setting_is_checked_against_is_the_configs_default_when_not_given(tmp_path):
    conf = tmp_path / "conf"
    (conf / "protocol").mkdir(parents=True)
    (conf / "protocol" / "a.yaml").write_text("name: a\nsteps: 1\n")
    (conf / "protocol" / "b.yaml").write_text("name: b\nsteps: 1\ngate:\n  margin: 0.1\n")
    (conf / "main.yaml").write_text("defaults:\n  - protocol: a\n  - _self_\n")
    assert config_mistakes(["+protocol.gate.margin=0.2"], conf, "main") == (
        "+protocol.gate.margin=0.2: protocol=a has no gate (a section of protocol=b); drop it, or run it with "
        "protocol=b: protocol=b protocol.gate.margin=0.2")
    assert config_mistakes(["+protocol.gate.margin=0.2", "protocol=b,a"], conf, "main").startswith(
        "+protocol.gate.margin=0.2: protocol=a has no gate (a section of protocol=b), and this sweep runs protocol=a")
    assert config_mistakes(["protocol=b", "+protocol.gate.seed=1"], conf, "main") is None  # b has the section
    assert config_mistakes(["+protocol.nope=1"], conf, "main") is None  # no option has it: left to Hydra and the run
    assert config_mistakes(["++protocol.gate.margin=0.2"], conf, "main").startswith(
        "++protocol.gate.margin=0.2: protocol=a has no gate")  # as given
    assert config_mistakes(["+protocol.gate.margin=0.2"], conf) is None  # no primary config named: not checked
    (conf / "protocol" / "c.yaml").write_text("defaults:\n  - b\n  - _self_\nname: c\n")
    assert config_mistakes(["protocol=c", "protocol.gate.margin=0.2"], conf, "main") is None  # b's keys, by defaults


@pytest.mark.parametrize("entry, args", [
    ("diversity", ["pipeline=gensim_own", "pipeline.root=/x"]),  # root comes from gensim's yaml, by its defaults
    ("quality", ["judge=replay", "judge.provider.base_url=http://127.0.0.1:1/v1"]),  # replay's defaults: openai
    ("diversity", ["world_model=tiny", "world_model.model.deter=8"])])
def test_keys_an_option_takes_from_its_defaults_or_groups_left_to_hydra_are_not_refused(entry, args):
    assert config_mistakes(args, ROOT / "conf", entry) is None


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
    groups = ["paths", "pipeline", "variation", "logger"]  # from its defaults; debug is an overlay (@package _global_)
    expected = [k for k in doc if k != "defaults"] + groups
    valid = line.split("valid here: ")[1].split(")")[0].split(", ")
    assert line.startswith("error: override progress: no such key (") and sorted(valid) == sorted(expected)
    assert line.endswith("to add a new key, write +progress=false")


def test_a_typo_in_a_nested_key_in_a_sweep_names_the_closest_keys(tmp_path):
    line = one_line_exit_2(run("diversity", "-m", "world_model.train.epoks=3", "episodes=1,2", cwd=tmp_path))
    assert "override world_model.train.epoks: no such key (did you mean " in line and "epochs" in line.split("?")[0]
    assert "+world_model" not in line  # '+key=' of a typo adds a key nothing reads: the run would go on without it
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


def run_plain(entrypoint: str, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    env.pop("HYDRA_FULL_ERROR", None)
    return subprocess.run([sys.executable, str(ROOT / "src" / f"{entrypoint}.py"), *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("entrypoint, args, expected", [
    # the oracle judge uses neither metric nor repeats, but a typo in either is still named (it exited 0 before)
    ("quality", ["judge=oracle", "metric=foo"], "metric='foo': expected scene_alignment, task_completion or all"),
    ("quality", ["judge=oracle", "repeats=abc"], "repeats='abc': expected a whole number"),
    ("quality", ["judge=oracle", "cache_dir=a_file"], "cache_dir=a_file: is a file, not a folder"),
    ("text_diversity", ["pipeline.source=suite", "on_missing_source=foo"],
     "on_missing_source='foo': expected error or record"),
    ("text_diversity", ["pipeline.source=suite", "cache_dir=a_file/sub"],
     "cache_dir=a_file/sub: cannot create the folder"),
    ("text_diversity", ["pipeline.source=suite", "hydra.run.dir=a_file"],
     "a_file: File exists; a folder is needed there"),
    # a folder no one can make (a fresh-clone trial's paths.root=/sys/simeval: pathlib's chain of tracebacks)
    ("text_diversity", ["pipeline.source=suite", "hydra.run.dir=/proc/simeval/run"],
     "error: /proc/simeval: No such file or directory; the run's folder cannot be made there: set paths.root"),
    ("diversity", ["paths.root=/proc/simeval", "-m", "episodes=2,4"],
     "error: /proc/simeval: No such file or directory; the run's folder cannot be made there"),
])
def test_quality_and_text_diversity_name_bad_values_and_paths(entrypoint, args, expected, tmp_path):
    (tmp_path / "a_file").write_text("")
    run_dir = [] if any(a.startswith("hydra.run.dir") for a in args) else [f"hydra.run.dir={tmp_path / 'run'}"]
    store = [f"episodes.store={tmp_path / 'no-store'}"] if entrypoint == "quality" else []
    assert expected in one_line_exit_2(run_plain(entrypoint, *args, *store, *run_dir, cwd=tmp_path))


@pytest.mark.parametrize("entrypoint, args, expected", [
    ("text_diversity", ["seed=abc"], "seed='abc': expected a whole number"),
    ("agreement", ["scores_path=x.json", "n_boot=lots"], "n_boot='lots': expected a whole number"),
    ("evaluate", ["episodes.pipeline=mine", "dynamics.heldout=0"], "dynamics.heldout must be a whole number >= 1"),
    ("export_data", ["out=x", "overwrite=maybe"], "overwrite='maybe': expected true or false"),
    ("import_data", ["src=x", "overwrite=maybe"], "overwrite='maybe': expected true or false"),
    ("paper", ["sbatch_args=[a]"], "sbatch_args=['a']: expected text"),
])
def test_every_entrypoint_names_a_value_of_the_wrong_type_before_reading_anything(entrypoint, args, expected,
                                                                                  tmp_path):
    assert expected in one_line_exit_2(run_plain(entrypoint, *args, f"hydra.run.dir={tmp_path / 'run'}",
                                                 cwd=tmp_path))


def test_a_comma_list_without_m_and_a_group_of_another_command_say_what_to_do(tmp_path):
    line = one_line_exit_2(run("diversity", "episodes=2,3", cwd=tmp_path))
    assert "Ambiguous value for argument 'episodes=2,3'; to sweep over the values add -m" in line
    line = one_line_exit_2(run("generalization", "world_model=cpu", cwd=tmp_path))
    assert line.endswith("No match in the defaults list. (this command's config groups: paths, pipeline, policy, logger, "
                         "debug)")


def test_help_into_a_closed_pipe_ends_quietly(tmp_path):
    """`src/x.py --help | head -1`: the reader may be gone before the help is written (here it is closed before the
    process starts writing, so the write always fails); Python's BrokenPipeError traceback is not shown."""
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    proc = subprocess.Popen([sys.executable, str(ROOT / "src" / "diversity.py"), "--help"], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    proc.stdout.close()
    _, err = proc.communicate(timeout=120)
    assert "Traceback" not in err and "BrokenPipeError" not in err, err
    assert proc.returncode == 1


def test_the_value_of_hydras_own_flags_is_not_read_as_an_override(tmp_path):
    """`--cfg job` once failed with "override 'job': Error parsing override" before Hydra could print the config."""
    conf = tmp_path / "conf"
    (conf / "pipeline").mkdir(parents=True)
    (conf / "pipeline" / "a.yaml").write_text("name: a\n")
    assert config_mistakes(["--cfg", "job", "-p", "pipeline", "pipeline=a"], conf) is None
    assert config_mistakes(["-c", "all", "pipeline=b"], conf) == "pipeline=b: no conf/pipeline/b.yaml; valid: a"


@pytest.mark.parametrize("entrypoint, args, expected", [
    ("generalization", ["pipeline=bbsea", "policy.model.down_dims=abc"],
     "policy.model.down_dims=['a', 'b', 'c']: expected a list of channel counts"),
    ("generalization", ["pipeline=bbsea", "policy.model.beta_schedule=foo"], "policy.model.beta_schedule='foo'"),
    ("generalization", ["pipeline=bbsea", "policy.train.betas=[0.9]"], "policy.train.betas=[0.9]: expected two"),
    ("generalization", ["pipeline=bbsea", "policy.train.lr_schedule=foo"], "policy.train.lr_schedule='foo'"),
    ("generalization", ["pipeline=bbsea", "policy.train.warmup_steps=-1"],
     "policy.train.warmup_steps must be a whole number >= 0, got -1"),
    ("diversity", ["pipeline=bbsea", "world_model.window.random_offset=maybe"],
     "world_model.window.random_offset='maybe': expected true or false"),
    ("collect", ["pipeline=bbsea", "record.robot_masks=maybe"], "record.robot_masks='maybe': expected true or false"),
    ("agreement", ["scores_path=x", "figure_formats=[xyz]"], "figure_formats: 'xyz' is not a figure format"),
    ("report", ["report=table4_heldout", "report.figure=t4.xyz"], "report.figure=t4.xyz: 'xyz' is not a figure"),
    ("paper", ["stages=[figure3]", "profile.name=[a]"], "profile.name=['a']: expected a name"),
    ("paper", ["profile.overrides.collect=abc"], "profile.overrides.collect='abc': expected a list of overrides"),
])
def test_a_fresh_clone_trials_mistakes_are_one_line_before_any_work(entrypoint, args, expected, tmp_path):
    """Mistakes a fresh-clone trial found reaching a traceback (torch, diffusers, matplotlib) or a run that went
    on: each is refused first, in one line naming its key."""
    assert expected in one_line_exit_2(run_plain(entrypoint, *args, f"hydra.run.dir={tmp_path / 'run'}",
                                                 cwd=tmp_path))
