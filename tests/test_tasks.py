"""Task loaders of every pipeline, from real files (../shared/data) and from checkouts built on disk."""

import json
import textwrap

import pytest
import yaml

from simeval.pipelines.task_texts import SourceNotConfigured, TaskSourceError, groups_of, load_tasks, select_group
from simeval.pipelines.gensim.tasks import gensim_groups

ALIASES = {"stack": "stacking", "place": "placement", "pile": "piles", "build": "assembling"}


def test_authors_grouped_file_is_read_verbatim(shared_data):
    path = shared_data / "gensim_descs_grouped.yaml"
    raw = yaml.safe_load(path.read_text())
    tasks = load_tasks("gensim", grouped_file=str(path), group_aliases=ALIASES)
    assert len(tasks) == 81  # duplicates kept: that is what Table 3 embedded
    assert {g: len(select_group(tasks, g)) for g in groups_of(tasks)} == {
        "assembling": 14, "piles": 11, "placement": 19, "stacking": 37}
    assert [t.text for t in select_group(tasks, "stacking")] == raw["stack"]
    assert tasks[0].name == "build-bridge"


def _write_gensim_checkout(root, spec):
    """A GenSim-shaped checkout from the shared static parse: registry, task classes, generated task files."""
    tasks_dir, gen_dir = root / "cliport" / "tasks", root / "cliport" / "generated_tasks"
    tasks_dir.mkdir(parents=True)
    gen_dir.mkdir(parents=True)
    entries, classes = [], {}
    for name, t in spec["template_tasks"].items():
        entries.append(f"    {name!r}: tasks.{t['class']},")
        classes[t["class"]] = t.get("docstring")
    (tasks_dir / "__init__.py").write_text("from cliport.tasks import *\n\nnames = {\n" + "\n".join(entries) + "\n}\n")
    body = "".join(
        f"class {c}(Task):\n" + (f"    {json.dumps(d)}\n" if d else "") + "    pass\n\n" for c, d in classes.items()
    )
    (tasks_dir / "all_tasks.py").write_text("class Task:\n    pass\n\n" + body)
    for name, t in spec["generated_tasks"].items():
        cls = "".join(p.capitalize() for p in name.split("-"))
        doc = f"    {json.dumps(t['docstring'])}\n" if t.get("docstring") else ""
        (gen_dir / f"{name.replace('-', '_')}.py").write_text(f"class {cls}(Task):\n{doc}    pass\n")
    (gen_dir / "__init__.py").write_text("")


def test_gensim_checkout_static_parse_follows_registry_and_groups(shared_data, tmp_path):
    spec = yaml.safe_load((shared_data / "gensim_tasks.yaml").read_text())
    # The shared parse has no grouped task without a docstring; add one so that case is always checked.
    spec["generated_tasks"]["stack-without-docstring"] = {"docstring": None, "authors_groups": ["stack"]}
    _write_gensim_checkout(tmp_path, spec)
    tasks = load_tasks("gensim", source="checkout", root=str(tmp_path))
    expected = {}
    for kind in ("template_tasks", "generated_tasks"):
        for name, t in spec[kind].items():
            for g in t["authors_groups"]:
                expected.setdefault(ALIASES[g], set()).add(name)
    got = {g: {t.name for t in select_group(tasks, g)} for g in groups_of(tasks)}
    assert got == expected
    by_name = {t.name: t for t in tasks}
    assert by_name["build-bridge"].text.startswith("Task: build-bridge \n Description: Construct a bridge")
    # what str(cls.__doc__) gives for a class without a docstring, as the authors embedded it
    assert by_name["stack-without-docstring"].description == "None"
    assert by_name["stack-without-docstring"].text == "Task: stack-without-docstring \n Description: None"


def test_gensim_substring_rule():
    assert gensim_groups("stack-block-pyramid") == ["stacking"]
    assert gensim_groups("place-red-in-green") == ["placement"]
    assert set(gensim_groups("build-stack-and-place")) == {"stacking", "placement", "assembling"}
    assert gensim_groups("align-box-corner") == []


def test_gensim_checkout_errors(tmp_path):
    with pytest.raises(TaskSourceError, match="not a GenSim checkout"):
        load_tasks("gensim", source="checkout", root=str(tmp_path))
    (tmp_path / "cliport" / "tasks").mkdir(parents=True)
    (tmp_path / "cliport" / "tasks" / "__init__.py").write_text("names = {'x-stack': tasks.Missing}\n")
    with pytest.raises(TaskSourceError, match="Missing, defined nowhere"):
        load_tasks("gensim", source="checkout", root=str(tmp_path))


def test_robogen_records_and_checkout(shared_data, tmp_path):
    tasks = load_tasks("robogen", tasks_path=str(shared_data / "robogen_tasks.yaml"))
    assert len(tasks) == 46 and {len(select_group(tasks, g)) for g in ("table-top", "ground")} == {21, 25}
    assert tasks[0].text == "Adjust Chair Position: The robot arm will adjust the position of the unfolded chair"
    folder = tmp_path / "example_tasks" / "Open_Laptop"
    folder.mkdir(parents=True)
    (folder / "Open_Laptop_open.yaml").write_text(textwrap.dedent("""\
        - use_table: true
        - {name: Laptop, type: urdf, on_table: true, lang: a laptop}
        - {name: Pen, type: mesh, on_table: true}
        - {task_name: Open Laptop, task_description: The robot opens the laptop lid}
        """))
    (folder / "Close_Laptop.yaml").write_text(textwrap.dedent("""\
        - use_table: false
        - {name: Laptop, type: urdf, on_table: true}
        - {task_name: Close Laptop, task_description: The robot closes the laptop}
        """))
    tasks = load_tasks("robogen", source="checkout", root=str(tmp_path))
    assert {(t.name, t.group) for t in tasks} == {("Open Laptop", "table-top"), ("Close Laptop", "ground")}


def test_bbsea_output_folder_and_list(tmp_path):
    for scene, desc in [("0", "Open the drawer using the drawer handle"), ("0", "Put the red block in the bin"),
                        ("3", "Stack the blocks")]:
        (tmp_path / "trajectory" / scene / desc).mkdir(parents=True)
    tasks = load_tasks("bbsea", root=str(tmp_path))
    assert {t.group for t in tasks if "drawer" in t.text} == {"drawer"}
    assert len(select_group(tasks, "table-top")) == 2
    lst = tmp_path / "bbsea.yaml"
    lst.write_text(yaml.safe_dump(["Close the Drawer", "Gather all objects in the green bin"]))
    assert [t.group for t in load_tasks("bbsea", tasks_path=str(lst))] == ["drawer", "table-top"]


@pytest.mark.parametrize("shape", ["mapping", "list", "records_csv", "records_json"])
def test_custom_file_shapes(tmp_path, shape):
    if shape == "mapping":
        path = tmp_path / "mine.yaml"
        path.write_text(yaml.safe_dump({"push": ["push a", "push b"], "pick": ["pick c"]}))
        expected = {"push": 2, "pick": 1}
    elif shape == "list":
        path = tmp_path / "mine.yaml"
        path.write_text(yaml.safe_dump(["a", "b", "c"]))
        expected = {"mine": 3}
    elif shape == "records_csv":
        path = tmp_path / "mine.csv"
        path.write_text("name,description,group\nt1,push the block,push\nt2,\"pick, then place\",pick\n")
        expected = {"push": 1, "pick": 1}
    else:
        path = tmp_path / "mine.json"
        path.write_text(json.dumps([{"name": "t1", "description": "d1", "group": "g"}]))
        expected = {"g": 1}
    tasks = load_tasks("custom", tasks_path=str(path))
    assert {g: len(select_group(tasks, g)) for g in groups_of(tasks)} == expected


def test_bad_sources_give_clear_errors(tmp_path):
    with pytest.raises(TaskSourceError, match="not found"):
        load_tasks("custom", tasks_path=str(tmp_path / "nope.yaml"))
    bad = tmp_path / "bad.yaml"
    bad.write_text("a: [1, 2\n")
    with pytest.raises(TaskSourceError, match=r"cannot parse .*bad.yaml: line 2, column 1: expected ',' or ']', but "
                                              r"got '<stream end>' \(while parsing a flow sequence at line 1, column "
                                              r"4\)$"):
        load_tasks("custom", tasks_path=str(bad))
    nontext = tmp_path / "nontext.yaml"
    nontext.write_text(yaml.safe_dump({"g": ["fine", 42]}))
    with pytest.raises(TaskSourceError, match="group 'g' item 1"):
        load_tasks("custom", tasks_path=str(nontext))
    rec = tmp_path / "rec.json"
    rec.write_text(json.dumps([{"name": "x", "description": "y"}]))
    with pytest.raises(TaskSourceError, match="lacks group"):
        load_tasks("custom", tasks_path=str(rec))
    with pytest.raises(SourceNotConfigured, match="BBSEA_ROOT") as e:
        load_tasks("bbsea")
    assert "pipeline.tasks_path" in e.value.hint
    with pytest.raises(TaskSourceError, match="choose auto or one of grouped_file, checkout, suite"):
        load_tasks("gensim", source="episodes", root="x")


def test_unknown_group_lists_the_available_ones(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump({"push": ["a", "b"]}))
    with pytest.raises(TaskSourceError, match="unknown task_group 'pull'; available: push, all"):
        select_group(load_tasks("custom", tasks_path=str(path)), "pull")


def test_simeval_suite_is_a_named_source_only():
    tasks = load_tasks("gensim", source="suite", suite="gensim")
    assert {t.group for t in tasks} == {"placement", "stacking", "piles", "assembling"}
    assert all(t.text.startswith(f"Task: {t.name} \n Description: ") for t in tasks)
    with pytest.raises(SourceNotConfigured):  # auto never falls back to the suite
        load_tasks("gensim", suite="gensim")


def test_a_task_file_that_is_a_folder_is_named_as_one(tmp_path):
    with pytest.raises(TaskSourceError, match=rf"^{tmp_path} is a folder; give a task file \(.yaml, .yml, .json or "
                                              r"\.csv\)$"):
        load_tasks("custom", tasks_path=str(tmp_path))
