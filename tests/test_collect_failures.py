"""How collection fails and recovers: mistakes on the command line are one line naming the key (exit 2, no
traceback), the README's variation command works and a variation naming an object the task lacks is refused,
and an unreadable episode already in the store is moved aside and collected again."""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from simeval.collect import collect
from simeval.episodes.store import EpisodeStore, read_meta
from simeval.sim.rollout import RecordSettings
from simeval.sim.tasks.spec import suite_dir, SpecError, check_variation, load_suite

ROOT = Path(__file__).resolve().parents[1]
SUITE = {s.name: s for s in load_suite(suite_dir("gensim"))}
TINY = ["record.image_size=[16,16]", "record.scene_view_size=[16,16]"]


def _collect(tmp_path, *args):
    return subprocess.run([sys.executable, str(ROOT / "src" / "collect.py"), f"store={tmp_path / 'store'}",
                           f"hydra.run.dir={tmp_path / 'run'}", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)


@pytest.mark.parametrize("args,expected", [
    (["record.image_size=[0,0]"], "error: record.image_size must be [H, W] with whole numbers H, W >= 1, got [0, 0]"),
    (["record.image_size=[12]"], "error: record.image_size must be [H, W] with whole numbers H, W >= 1, got [12]"),
    (["workers=-1"], "error: workers must be 0 (one per CPU core) or a positive number of processes, got -1"),
    (["tasks=stack-two-blok"], "error: unknown task(s) ['stack-two-blok']; available: align-balls-in-zones, "),
    (["tasks=[build-bridge]", "variation.knobs={pilar: {colors: [white]}}"],
     "error: variation.pilar: task build-bridge has no object 'pilar'; its objects: pad, pillar, deck (and robot)"),
])
def test_collect_command_line_mistakes_are_one_line(tmp_path, args, expected):
    res = _collect(tmp_path, "episodes=1", *args)
    assert res.returncode == 2, res.stderr[-2000:]
    assert "Traceback" not in res.stderr and res.stderr.strip().splitlines() == [res.stderr.strip()], res.stderr
    assert res.stderr.startswith(expected), res.stderr
    assert not (tmp_path / "store").exists()  # refused before any work


def test_the_readme_variation_command_works_with_a_single_task_name(tmp_path):
    # README: python src/collect.py tasks=[build-bridge] episodes=10 variation.knobs='{pillar: {colors: [white]}}' ...
    res = _collect(tmp_path, "tasks=build-bridge", "episodes=1", "workers=1", "variation.knobs={pillar: {colors: [white]}}",
                   *TINY)
    assert res.returncode == 0, res.stderr[-2000:]
    summary = json.loads((tmp_path / "run" / "result.json").read_text())["values"]
    assert list(summary["tasks"]) == ["build-bridge"]  # one task, not one per letter of its name
    # a varied episode is stored beside the plain one of its seed (episode_000000.v<hash>.h5), never over it
    meta = read_meta(EpisodeStore(tmp_path / "store").path_for("gensim", "build-bridge", 0,
                                                                 {"pillar": {"colors": ["white"]}}))
    assert meta["variation"] == {"pillar": {"colors": ["white"]}}
    objects = meta["extra"]["objects"]
    assert [o["color"] for k, o in objects.items() if k.startswith("pillar")] == ["white", "white"]
    assert "white blocks" in meta["description"]


def test_variation_is_checked_against_the_tasks():
    bridge, stack = SUITE["build-bridge"], SUITE["stack-two-blocks"]
    assert check_variation([bridge], {"pillar": {"colors": "white"}}) == {"pillar": {"colors": ["white"]}}
    # one variation may cover several tasks: each takes the objects it has; a name none has is a typo
    assert check_variation([bridge, stack], {"pillar": {"count": 2}, "robot": {"home_noise": 0.1}})
    with pytest.raises(SpecError, match=r"variation.pilar: none of the tasks has an object 'pilar'; their objects "
                                        r"\(and robot\): build-bridge: pad, pillar, deck; stack-two-blocks: "):
        check_variation([bridge, stack], {"pilar": {"colors": ["white"]}})
    for bad, match in [({"pillar": {"colors": ["mauve"]}}, "variation.pillar.colors: expected a list of colours"),
                       ({"pillar": {"count": [3, 1]}}, "variation.pillar.count: expected a count >= 0"),
                       ({"pillar": {"colour": ["red"]}}, r"unknown knob\(s\) \['colour'\]; valid for an object"),
                       ({"robot": {"home_noise": -1}}, "variation.robot.home_noise: expected radians >= 0")]:
        with pytest.raises(SpecError, match=match):
            check_variation([bridge], bad)


def test_an_unreadable_episode_in_the_store_is_moved_aside_and_collected_again(tmp_path, caplog):
    store = EpisodeStore(tmp_path)
    empty = store.path_for("gensim", "put-block-in-zone", 0)
    empty.parent.mkdir(parents=True)
    empty.write_bytes(b"")  # a full disk or a crashed copy
    settings = RecordSettings(cameras=("top",), image_size=(16, 16), scene_view_size=(16, 16))
    summary = collect([SUITE["put-block-in-zone"]], [0], store, settings, workers=1, progress=False)
    assert summary["skipped"] == 0 and len(summary["new"]) == 1 and summary["tasks"]["put-block-in-zone"]["rate"] == 1
    assert read_meta(empty)["n_steps"] > 0  # a real episode in its place
    aside = list(empty.parent.glob("episode_000000.h5.corrupt-*"))
    assert len(aside) == 1 and aside[0].stat().st_size == 0  # kept for inspection, never read as an episode
    assert re.search(r"episode_000000\.h5: unreadable episode moved aside to episode_000000\.h5\.corrupt-", caplog.text)
