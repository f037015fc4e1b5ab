"""src/controls.py at tiny sizes: the dose-response control collects a real suite task at four
pose-range levels, trains and scores every level on held-out episodes, and its verdict's numbers are the ratios of
the run records' per-episode sums (computed here by hand); reruns reuse the runs, other settings are refused."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "src" / "controls.py"
TINY_DOSE = ["dose", "--preset", "tiny", "--steps", "6", "--seeds", "0", "--episodes", "2", "--heldout", "3", "4",
             "--threads", "1"]


def control(*args: str, out: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args, "--out", str(out)], capture_output=True, text=True,
                          timeout=900, cwd=ROOT)


def test_dose_control_end_to_end_and_its_verdict_by_hand(tmp_path):
    r = control(*TINY_DOSE, out=tmp_path)
    assert r.returncode == 0, r.stderr
    levels = ["range000", "range033", "range067", "range100"]
    for name in levels:
        assert f"{name} (pose_range" in r.stdout and "oracle success 1.00" in r.stdout
    episodes = sorted((tmp_path / "control_episodes").rglob("*.h5"))
    assert len(episodes) == 4 * 4  # four levels x episode seeds 0-3, each level its own variation file
    result = json.loads((tmp_path / "tables" / "control_dose.json").read_text())
    assert result["task"] == "gensim/put-blocks-in-matching-zones" and result["exclude_robot_from_loss"] is True
    md = (tmp_path / "tables" / "control_dose.md").read_text()
    assert [line.split("|")[2].strip() for line in md.splitlines()[2:6]] == levels  # rows in level order
    verdict = result["verdict"]
    by_hand = {}
    for name in levels:
        rec = json.loads((tmp_path / "controls" / "dose" / "runs" / f"{name}_k2_s0.json").read_text())
        assert rec["settings"]["exclude_robot_from_loss"] is True  # the episodes carry robot masks
        assert rec["values"]["protocol"]["robot_excluded_from_loss"] is True
        assert sorted(e["seed"] for e in rec["values"]["prediction"]["per_episode"]) == [2, 3]  # held out
        sums = [e["sums"] for e in rec["values"]["prediction"]["per_episode"]]
        by_hand[name] = (sum(s["one_step/model/object"] for s in sums)
                         / (3 * sum(s["one_step/kept_pixels"] for s in sums)))
        point, lo, hi = verdict["one_step_object"]["by_level"][name]
        np.testing.assert_allclose(point, by_hand[name], rtol=1e-9)
        assert lo <= point <= hi
    steps = verdict["one_step_object"]["steps"]
    for a, b in zip(levels, levels[1:]):
        np.testing.assert_allclose(steps[f"{b}_minus_{a}"][0], by_hand[b] - by_hand[a], rtol=1e-9)
    assert verdict["passes"]["rises_at_every_level"] == all(by_hand[b] > by_hand[a] for a, b in zip(levels, levels[1:]))
    figure = tmp_path / "figures" / "control_dose.png"
    assert figure.stat().st_size > 10_000
    drawn = figure.read_bytes()
    figure.unlink()  # --replot draws it again from the table alone: same bytes, no run or episode read
    (tmp_path / "control_episodes").rename(tmp_path / "episodes_aside")
    replot = control("dose", "--replot", out=tmp_path)
    assert replot.returncode == 0 and figure.read_bytes() == drawn, replot.stderr
    (tmp_path / "episodes_aside").rename(tmp_path / "control_episodes")
    refused = control("dose_push", "--replot", out=tmp_path)
    assert refused.returncode == 2 and refused.stderr.strip().splitlines()[-1] == (
        f"error: --replot: no {tmp_path / 'tables' / 'control_dose_push.json'}; run `python "
        f"src/controls.py dose_push --out {tmp_path}` first")
    edited = json.loads((tmp_path / "tables" / "control_dose.json").read_text())
    edited["rows"] = []  # valid JSON, edited by hand
    (tmp_path / "tables" / "control_dose.json").write_text(json.dumps(edited))
    broken = control("dose", "--replot", out=tmp_path)
    assert broken.returncode == 2 and "is not a control table this script wrote (IndexError" in broken.stderr

    again = control(*TINY_DOSE, out=tmp_path)  # every run saved: the table is rebuilt without collecting or training
    assert again.returncode == 0 and "collected" not in again.stdout and "one-step" not in again.stdout
    assert again.stdout.count("saved already") == 4  # each reused run says so
    assert (tmp_path / "tables" / "control_dose.json").read_text() == json.dumps(result, indent=1) + "\n"
    runs = sorted((tmp_path / "controls" / "dose" / "runs").glob("*.json"))
    def training(paths):  # what each run's training record says, less its clock (the checkpoint keeps its own)
        return [{k: v for k, v in json.loads(r.read_text())["values"]["train"].items() if k != "seconds"}
                for r in paths]

    trained = training(runs)
    scored = control(*TINY_DOSE, "--reevaluate", out=tmp_path)  # scored again from the checkpoints, not trained
    assert scored.returncode == 0, scored.stderr
    assert scored.stdout.count("evaluated again from its checkpoint") == 4 and "saved already" not in scored.stdout
    assert scored.stdout.count(" 0 episodes collected") == 4  # the store's episodes, nothing collected again
    assert training(runs) == trained  # each checkpoint's record: no step taken again
    again_verdict = json.loads((tmp_path / "tables" / "control_dose.json").read_text())["verdict"]
    np.testing.assert_allclose(again_verdict["one_step_object"]["by_level"]["range100"][0],
                               verdict["one_step_object"]["by_level"]["range100"][0], rtol=1e-6)
    for checkpoint in (tmp_path / "checkpoints" / "controls").glob("*.pt"):
        checkpoint.unlink()
    gone = control(*TINY_DOSE, "--reevaluate", out=tmp_path)  # no checkpoint: refused, not trained again
    assert gone.returncode == 2 and "Traceback" not in gone.stderr
    # (pybullet's import prints its build time on stderr before it)
    assert gone.stderr.strip().splitlines()[-1].startswith("error: no checkpoint to evaluate from")
    other = control(*[("7" if a == "6" else a) for a in TINY_DOSE], out=tmp_path)
    assert other.returncode == 2 and "other settings (steps: 6)" in other.stderr
    assert len(other.stderr.strip().splitlines()) == 1 and "Traceback" not in other.stderr


def _record(level: str, seed: int, moving: list[tuple[float, float]]) -> dict:
    """A run record with per-episode sums where only the one-step moving-pixel sums matter: (model se, pixels)."""
    from simeval.measures.dynamics_diversity.prediction import SUM_KEYS

    episodes = []
    for e, (se, pixels) in enumerate(moving):
        sums = dict.fromkeys(SUM_KEYS, 1.0)
        sums.update({"one_step/model/moving": se, "one_step/moving_pixels": pixels, "one_step/last/moving": 2 * pixels})
        episodes.append({"task": "bbsea-close-drawer", "seed": 10 + e, "sums": sums})
    return {"identity": {"task_group": level, "episodes": 10, "seed": seed},
            "values": {"prediction": {"per_episode": episodes}}}


def test_a_dose_judged_by_moving_pixels_reads_their_ratio_of_sums_and_no_motion_passes_nothing():
    from simeval.measures.dynamics_diversity.controls import fixed as dc

    levels = tuple(dc.DOSES["dose_drawer"].levels)
    assert dc.DOSES["dose_drawer"].metric == "one_step_moving" and dc.DOSES["dose"].metric == "one_step_object"
    # per level, two seeds x two held-out episodes; the error per moving pixel and channel rises with the level
    data = {lv: [[(3.0 * (i + 1) * px, px) for px in (40.0, 60.0)] for _ in range(2)] for i, lv in enumerate(levels)}
    records = [_record(lv, s, eps) for lv, runs in data.items() for s, eps in enumerate(runs)]
    verdict = dc.dose_verdict(records, levels, n_boot=200, primary="one_step_moving")
    assert verdict["judged_by"] == "one_step_moving"
    for i, lv in enumerate(levels):  # sum se / (3 sum pixels) = i + 1
        np.testing.assert_allclose(verdict["one_step_moving"]["by_level"][lv][0], i + 1, rtol=1e-12)
    assert verdict["passes"] == {"rises_at_every_level": True, "top_minus_bottom_above_zero": True}
    # a task where nothing moves outside the robot gives no reading, and so no pass
    still = [_record(lv, 0, [(0.0, 0.0)]) for lv in levels]
    verdict = dc.dose_verdict(still, levels, n_boot=50, primary="one_step_moving")
    assert not any(verdict["passes"].values())
    assert all(not np.isfinite(v[0]) for v in verdict["one_step_moving"]["by_level"].values())


def test_moving_share_by_margin_counts_changed_pixels_outside_the_grown_robot_mask_by_hand(tmp_path):
    """A dose with no reading says whether the motion was there but inside the margin around the robot: counted
    here on hand-made frames (a 1-pixel block moving one pixel right beside a 1-pixel robot, and a far one)."""
    import h5py
    from simeval.measures.dynamics_diversity.controls.fixed import DOSES, moving_share_by_margin

    from simeval.episodes.store import EpisodeStore
    from simeval.sim.tasks.spec import suite_dir, check_variation, load_suite

    dose = DOSES["dose_push"]
    pipeline, task = dose.task
    spec = next(s for s in load_suite(suite_dir(pipeline)) if s.name == task)
    store = EpisodeStore(tmp_path / "control_episodes")
    rgb = np.zeros((2, 8, 8, 3), np.uint8)
    robot = np.zeros((2, 8, 8), bool)
    robot[:, 0, 0] = True  # the robot's one pixel, the same in both frames
    rgb[0, 0, 1] = rgb[1, 0, 2] = 255  # a block next to it moves right: pixels (0,1) and (0,2) change
    rgb[0, 6, 6] = 255  # a far block vanishes: pixel (6,6) changes
    for level in dose.levels.values():
        path = store.path_for(pipeline, task, 0, check_variation([spec], dose.variation(level)))
        path.parent.mkdir(parents=True, exist_ok=True)
        with h5py.File(path, "w") as f:
            f[f"obs/rgb/{dose.camera}"] = rgb
            f[f"obs/robot_mask/{dose.camera}"] = robot
    shares = moving_share_by_margin(dose, tmp_path, (1, 1))
    # margin 0: 3 changed pixels, 63 kept; margin 1: (0,1) is inside the grown mask, 60 kept; margin 2: (0,1) and
    # (0,2) are, 55 kept (a 3 x 3 corner of 64 cells)
    expect = {"margin_0": (3, 63), "margin_1": (2, 60), "margin_2": (1, 55)}
    for level in dose.levels:
        for m, (moving, kept) in expect.items():
            assert shares[level][m]["moving_pixels"] == moving and shares[level][m]["share"] == moving / kept


@pytest.mark.parametrize("name", ["dynamics", "visual", "dose", "dose_drawer", "dose_push"])
def test_each_committed_control_figure_is_what_the_code_draws_from_its_committed_table(name, tmp_path):
    """A change to the plotting code must come with the committed figures redrawn (--replot --overwrite): a stale
    figure made `make controls` refuse to replace it on a fresh clone."""
    (tmp_path / "tables").mkdir()
    shutil.copy(ROOT / "outputs" / "tables" / f"control_{name}.json", tmp_path / "tables")
    r = control(name, "--replot", out=tmp_path)
    assert r.returncode == 0, r.stderr
    committed = ROOT / "outputs" / "figures" / f"control_{name}.png"
    assert (tmp_path / "figures" / committed.name).read_bytes() == committed.read_bytes(), name
