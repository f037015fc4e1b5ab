"""The `heldout` protocol of dynamics diversity (simeval.measures.dynamics_diversity.run,
simeval.measures.dynamics_diversity.prediction) at tiny sizes: no training read touches an evaluated episode, every
episode count trains the same steps, the baselines are scored on the frames the model is scored on (recomputed here
from the raw episode arrays, not through the dataset), the robot mask removes exactly the robot's pixels (the pixels
that change when the robot is made invisible), and the intervals of simeval.stats.resample have the bootstrap
variance computed by hand."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

import simeval.measures.dynamics_diversity.run as dd
from helpers import ConstantImageModel
from simeval.episodes.dataset import ArraySource, WindowSpec
from simeval.errors import UserError
from simeval.stats import resample
from simeval.measures.dynamics_diversity.controls.synthetic import make_physics_group
from simeval.models.world_model_training import TrainConfig
from simeval.models.world_model import WorldModelConfig

ROOT = Path(__file__).resolve().parents[1]
TINY = yaml.safe_load((ROOT / "conf" / "world_model" / "tiny.yaml").read_text())
torch.set_num_threads(1)


def run(source, k: int, eval_episodes=(8, 12), steps: int = 12, context: int = 3, horizon: int = 5, **kw) -> dict:
    training = dd.Training(WorldModelConfig.from_dict(TINY["model"]),
                           TrainConfig.from_dict({**TINY["train"], "seed": 0}), WindowSpec(**TINY["window"]), steps=steps,
                           exclude_robot_from_loss=kw.pop("exclude_robot_from_loss", False))
    evaluation = dd.Evaluation(protocol="heldout", episodes=eval_episodes, context=context, horizon=horizon,
                               mask_margin=kw.pop("mask_margin", 0))
    return dd.fit_and_evaluate(source, k, training, evaluation, dd.Execution(progress=False, **kw))


class RecordingSource(ArraySource):
    """An ArraySource that notes which episodes each phase reads (`phase` is set by the test around training)."""

    def __init__(self, src: ArraySource) -> None:
        super().__init__(src.infos, src.arrays)
        self.phase, self.reads = "setup", []

    def read(self, e, lo, hi, robot_mask=False):
        self.reads.append((self.phase, int(e)))
        return super().read(e, lo, hi, robot_mask)

    def read_full(self, e, key):
        self.reads.append((self.phase, int(e)))
        return super().read_full(e, key)


def test_no_training_read_touches_an_evaluated_episode(monkeypatch):
    source = RecordingSource(make_physics_group("varied", 3, 12, 20, 16))
    real_train = dd.train

    def train(*args, **kwargs):
        source.phase = "train"
        try:
            return real_train(*args, **kwargs)
        finally:
            source.phase = "eval"

    monkeypatch.setattr(dd, "train", train)
    values = run(source, k=4)
    seeds = np.array([i.seed for i in source.infos])  # rank = seed here: make_physics_group numbers them 0..11
    trained = {e for phase, e in source.reads if phase in ("setup", "train")}
    evaluated = {e for phase, e in source.reads if phase == "eval"}
    assert trained and max(seeds[list(trained)]) < 4  # statistics, mean images and windows: episodes 1-4 only
    assert {int(seeds[e]) for e in evaluated} == set(range(8, 12))  # episodes 9-12, every one of them
    assert sorted({r["seed"] for r in values["prediction"]["per_episode"]}) == list(range(8, 12))
    assert values["protocol"]["trained_on"] == [1, 4] and values["protocol"]["evaluated_on"] == [9, 12]


def test_every_episode_count_trains_the_same_steps_and_overlap_is_refused():
    source = make_physics_group("shared", 2, 12, 20, 16)
    assert run(source, k=2)["train"]["steps"] == run(source, k=6)["train"]["steps"] == 12
    with pytest.raises(UserError, match=r"would train on evaluated episodes.*eval_episodes=\[11,12\]$"):
        run(source, k=10)  # the fix names a range the 12 episodes per task hold, not one past them
    with pytest.raises(UserError, match=r"with more episodes \(the store holds 12 per task, at the fewest\): collect "
                                         r"episodes=22, then eval_episodes=\[13,22\]"):
        run(source, k=12)
    with pytest.raises(UserError, match="protocol.steps"):
        run(source, k=2, steps=None)
    with pytest.raises(UserError, match="at most 21 rows; use protocol.horizon=18 or less"):
        run(source, k=2, horizon=30)


def test_the_one_step_error_does_not_depend_on_the_open_loop_horizon():
    """One step and reconstruction are scored on windows of the training length; only the open loop changes."""
    source = make_physics_group("varied", 2, 12, 20, 16)
    a, b = (run(source, k=4, horizon=h)["prediction"]["summary"] for h in (3, 6))
    for kind in ("one_step", "reconstruction"):
        assert a[kind]["frames"] == b[kind]["frames"]
        assert a[kind]["mean"]["error"] == pytest.approx(b[kind]["mean"]["error"])
    assert a["one_step"]["model"]["error"] == pytest.approx(b["one_step"]["model"]["error"], rel=1e-6)
    assert a["open_loop"]["frames"] != b["open_loop"]["frames"]


def _by_hand(source: ArraySource, k: int, lo: int, hi: int, context: int, horizon: int, masked: bool) -> dict:
    """Baseline sums from the raw arrays: from row 0 of each evaluated episode, windows of the training window's
    length (tiny: 8 rows) for the one step, of context + horizon rows for the open loop."""
    L, S = context + horizon, TINY["window"]["length"]
    means = {}
    for t in sorted({i.task for i in source.infos}):
        frames = [a["image"] for i, a in zip(source.infos, source.arrays) if i.task == t and i.seed < k]
        means[t] = np.concatenate(frames).astype(np.float64).mean(0) / 255
    out = {key: 0.0 for key in ("last1", "mean1", "n1", "lastk", "meank", "nk", "movinglast1", "movingmean1",
                                "moving1", "movinglastk", "movingmeank", "movingk")}
    for info, a in zip(source.infos, source.arrays):
        if not lo <= info.seed < hi:
            continue
        o = a["image"].astype(np.float64) / 255
        free = ~a["robot_mask"] if masked else np.ones(o.shape[:3], bool)
        n = len(o)
        for s in range(0, n, S):
            for t in range(s + 1, min(s + S, n)):  # one step: o_t from o_{t-1}
                keep = free[t] & free[t - 1]
                last, mean = ((o[t] - o[t - 1]) ** 2).sum(-1), ((o[t] - means[info.task]) ** 2).sum(-1)
                out["last1"] += last[keep].sum()
                out["mean1"] += mean[keep].sum()
                out["n1"] += keep.sum() if masked else 1
                moving = keep & (last > 0.01)  # kept pixels whose colour changed
                out["movinglast1"] += last[moving].sum()
                out["movingmean1"] += mean[moving].sum()
                out["moving1"] += moving.sum()
        for s in range(0, n, L):
            if s + context - 1 < n:
                ref = s + context - 1
                for t in range(s + context, min(s + L, n)):  # open loop: o_t against the last observed frame
                    keep = free[t] & free[ref]
                    last, mean = ((o[t] - o[ref]) ** 2).sum(-1), ((o[t] - means[info.task]) ** 2).sum(-1)
                    out["lastk"] += last[keep].sum()
                    out["meank"] += mean[keep].sum()
                    out["nk"] += keep.sum() if masked else 1
                    moving = keep & (last > 0.01)
                    out["movinglastk"] += last[moving].sum()
                    out["movingmeank"] += mean[moving].sum()
                    out["movingk"] += moving.sum()
    return out


def test_baselines_are_scored_on_the_models_frames_computed_by_hand():
    source = make_physics_group("varied", 2, 12, 22, 16)  # 23 rows: windows of 8 leave a short last one
    p = run(source, k=4, context=3, horizon=5)["prediction"]["summary"]
    ref = _by_hand(source, 4, 8, 12, 3, 5, masked=False)
    one, ol = p["one_step"], p["open_loop"]
    assert one["frames"] == ref["n1"] and ol["frames"] == ref["nk"]
    np.testing.assert_allclose(one["last"]["error"], ref["last1"] / ref["n1"], rtol=1e-5)
    np.testing.assert_allclose(one["mean"]["error"], ref["mean1"] / ref["n1"], rtol=1e-5)
    np.testing.assert_allclose(ol["last"]["error"], ref["lastk"] / ref["nk"], rtol=1e-5)
    np.testing.assert_allclose(ol["mean"]["error"], ref["meank"] / ref["nk"], rtol=1e-5)
    np.testing.assert_allclose(one["skill_vs_last"], 1 - one["model"]["error"] / one["last"]["error"])
    assert p["reconstruction"]["frames"] == 4 * 2 * 23  # every held-out row
    # moving pixels: those whose colour changed from the reference frame, chosen and scored here from the raw arrays
    for block, sfx, frames in ((one, "1", ref["n1"]), (ol, "k", ref["nk"])):
        assert 0 < ref[f"moving{sfx}"] < frames * 16 * 16  # the squares move over a static floor
        np.testing.assert_allclose(block["moving_share"], ref[f"moving{sfx}"] / (frames * 16 * 16), rtol=1e-6)
        np.testing.assert_allclose(block["last"]["moving_error_per_pixel"],
                                   ref[f"movinglast{sfx}"] / (3 * ref[f"moving{sfx}"]), rtol=1e-5)
        np.testing.assert_allclose(block["mean"]["moving_error_per_pixel"],
                                   ref[f"movingmean{sfx}"] / (3 * ref[f"moving{sfx}"]), rtol=1e-5)
        assert block["last"]["moving_error_per_pixel"] > 0.01 / 3  # every moving pixel changed by the threshold
        np.testing.assert_allclose(block["moving_skill_vs_last"], 1 - block["model"]["moving_error_per_pixel"]
                                   / block["last"]["moving_error_per_pixel"])


def _with_flickering_robot(source: ArraySource, seed: int = 0) -> ArraySource:
    """The same episodes with a 'robot': a band of rows whose pixels are random noise every frame, masked."""
    rng = np.random.default_rng(seed)
    arrays = []
    for a in source.arrays:
        image, mask = a["image"].copy(), np.zeros(a["image"].shape[:3], bool)
        mask[:, :4] = True
        image[:, :4] = rng.integers(0, 256, image[:, :4].shape, dtype=np.uint8)
        arrays.append({**a, "image": image, "robot_mask": mask})
    return ArraySource(source.infos, arrays)


def test_object_error_excludes_the_masked_pixels():
    plain = make_physics_group("shared", 2, 12, 22, 16)
    source = _with_flickering_robot(plain)
    values = run(source, k=4)
    pred = values["prediction"]
    assert pred["robot_mask"] is True
    ref = _by_hand(source, 4, 8, 12, 3, 5, masked=True)
    one = pred["summary"]["one_step"]
    np.testing.assert_allclose(one["last"]["object_error_per_pixel"], ref["last1"] / (3 * ref["n1"]), rtol=1e-5)
    np.testing.assert_allclose(pred["summary"]["open_loop"]["mean"]["object_error_per_pixel"],
                               ref["meank"] / (3 * ref["nk"]), rtol=1e-5)
    # the flickering band changes every frame but is the robot's: no moving pixel comes from it
    np.testing.assert_allclose(one["moving_share"], ref["moving1"] / ref["n1"], rtol=1e-6)
    np.testing.assert_allclose(one["last"]["moving_error_per_pixel"], ref["movinglast1"] / (3 * ref["moving1"]),
                               rtol=1e-5)
    # the noise band dominates the full-frame baseline error and is absent from the object-focused one
    unmasked = _by_hand(plain, 4, 8, 12, 3, 5, masked=False)
    assert one["last"]["error"] > 5 * unmasked["last1"] / unmasked["n1"]
    assert one["last"]["object_error_per_pixel"] < 2 * unmasked["last1"] / unmasked["n1"] / (3 * 16 * 16) + 1e-9
    without = run(plain, k=4)["prediction"]
    assert without["robot_mask"] is False  # no masks: the object-focused numbers are the full frame's, and say so
    s = without["summary"]["one_step"]["last"]
    np.testing.assert_allclose(s["object_error_per_pixel"], s["error_per_pixel"], rtol=1e-9)


@pytest.mark.parametrize("task", ["stack-two-blocks", "bbsea-press-button"])
def test_robot_mask_is_exactly_the_pixels_the_robot_covers(task):
    """The recorded mask against an independent measurement: render the same state with every visual shape of the
    robot's bodies made transparent; the pixels that change are the robot's."""
    from simeval.sim.core.world import OBS_CAMERAS
    from simeval.sim.env import SimEnv

    env = SimEnv(task, robot_masks=True)
    try:
        obs, _ = env.reset(seed=3)
        c = env.world.c
        for b in env.arm.body_ids:
            for link in range(-1, c.getNumJoints(b)):
                c.changeVisualShape(b, link, rgbaColor=[0, 0, 0, 0])
        seen = 0
        for cam in env.cameras:
            changed = np.any(env.world.render(OBS_CAMERAS[cam], env.image_size) != obs["rgb"][cam], -1)
            seen = max(seen, int(changed.sum()))
            np.testing.assert_array_equal(obs["robot_mask"][cam], changed)
        assert seen > 100  # the robot is in view
    finally:
        env.close()
    plain = SimEnv(task)  # without masks the observation is what it was, the same frames
    try:
        o2, _ = plain.reset(seed=3)
        assert set(o2) == {"rgb", "state"}
        for cam in plain.cameras:
            np.testing.assert_array_equal(o2["rgb"][cam], obs["rgb"][cam])
    finally:
        plain.close()


def test_collected_episodes_store_robot_masks(tmp_path):
    from simeval.episodes.store import read_episode
    from simeval.sim.env import find_task
    from simeval.sim.rollout import RecordSettings, run_episode

    ep = run_episode(find_task("stack-two-blocks"), 0, RecordSettings(cameras=("front",), image_size=(32, 32)))
    assert set(ep.robot_mask) == {"front"} and ep.robot_mask["front"].shape == (ep.n_steps, 32, 32)
    assert ep.robot_mask["front"].any(axis=(1, 2)).mean() > 0.5  # the arm is seen in most frames
    from simeval.episodes.store import write_episode

    back = read_episode(write_episode(tmp_path / "e.h5", ep))
    np.testing.assert_array_equal(back.robot_mask["front"], ep.robot_mask["front"])


def test_bootstrap_variance_of_a_mean_matches_the_formula():
    """With one seed and one frame per episode the statistic is the mean, whose bootstrap variance is
    sum_h (n_h / n)^2 * popvar_h / n_h when episodes are resampled within strata h (here 2 tasks of 30 and 50)."""
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.normal(0, 1, 30), rng.normal(5, 3, 50)])[None]
    strata = np.array([0] * 30 + [1] * 50)
    reps = resample.replicates(x, np.ones_like(x), resample.draws(1, strata, n_boot=6000, seed=1))
    want = sum((len(g) / 80) ** 2 * g.var() / len(g) for g in (x[0, :30], x[0, 30:]))
    assert abs(reps.var() / want - 1) < 0.08
    np.testing.assert_allclose(reps.mean(), x.mean(), atol=3 * np.sqrt(want / 6000) + 1e-9)
    np.testing.assert_allclose(resample.ratio(x, np.full_like(x, 2.0)), x.mean() / 2)


def test_bootstrap_over_seeds_widens_with_the_spread_between_seeds():
    """Three seeds whose errors differ by a constant offset: the seed level adds the variance of the seed means
    ((R - 1) / R^2 * sum of squared deviations ... i.e. popvar / R), the episode level nothing (identical episodes)."""
    offsets = np.array([0.0, 1.0, 5.0])
    x = np.ones((3, 40)) + offsets[:, None]
    reps = resample.replicates(x, np.ones_like(x), resample.draws(3, np.zeros(40), n_boot=6000, seed=2))
    assert abs(reps.var() / (offsets.var() / 3) - 1) < 0.08
    out = resample.ratio_interval(x, np.ones_like(x), np.zeros(40), n_boot=2000)
    assert out["interval"][0] <= out["value"] <= out["interval"][1]


def _diversity(*args: str, cwd: Path):
    import os
    import subprocess
    import sys

    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "HYDRA_FULL_ERROR": "0"}
    return subprocess.run([sys.executable, str(ROOT / "src" / "diversity.py"), *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)


def test_entrypoint_sweep_reports_heldout_numbers_and_its_table(tmp_path):
    """The default protocol from the command line: a 2/4-episode sweep over 2 seeds evaluated on episodes 5-6,
    result.json carrying the prediction numbers and the protocol in its identity, then the table of the runs."""
    import json
    import subprocess
    import sys

    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    write_group(tmp_path / "store", "diverse", n_tasks=2, episodes=6, n_actions=14, size=16, pipeline="gensim")
    common = ("debug=tiny", "pipeline=gensim", "task_group=diverse", f"store={tmp_path}/store", "eval_episodes=[5,6]",
              "progress=false", "videos=0", "threads=1", f"checkpoint_dir={tmp_path}/ck")
    r = _diversity(*common, f"hydra.sweep.dir={tmp_path / 'sweep'}", "-m", "episodes=2,4", "seed=0,1", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    recs = [json.loads(p.read_text()) for p in sorted((tmp_path / "sweep").rglob("result.json"))]
    assert len(recs) == 4
    for rec in recs:
        assert rec["identity"]["protocol"] == "heldout" and rec["identity"]["steps"] == 40
        assert rec["values"]["train"]["steps"] == 40 and "eval" not in rec["values"]
        assert rec["values"]["protocol"]["evaluated_on"] == [5, 6]
        assert {e["seed"] for e in rec["values"]["prediction"]["per_episode"]} == {4, 5}  # ranks 5-6 (seeds 4, 5)
    assert "skill" in r.stdout  # the log line of each run names its skill scores
    # each run's line gives the gate's verdict beside (here: in place of) its numbers, and the state reading
    assert r.stdout.count("pixel reading: no reading: the model does not beat") == 4, r.stdout[-3000:]
    assert r.stdout.count("; state reading: ") == 4
    for rec in recs:
        assert rec["values"]["gate"]["passes"] is False and rec["values"]["state"]["dims"] > 0
        assert all(t["steps_used"] <= 3000 for t in rec["values"]["state"]["training"])
    from simeval.writing.tidy import run_rows

    rows = run_rows(recs)  # the notebook's DataFrame: the one-step error is each run's headline
    assert [row["statistic"] for row in rows] == ["heldout_one_step_error"] * 4
    assert rows[0]["value"] == recs[0]["values"]["prediction"]["summary"]["one_step"]["model"]["error"]
    out = tmp_path / "table4_heldout"
    report = [sys.executable, str(ROOT / "src" / "report.py"), "report=table4_heldout",
              f"report.runs_dir={tmp_path / 'sweep'}", f"report.out={out}"]
    t = subprocess.run([*report, f"report.figure={tmp_path / 't.png'}"], capture_output=True, text=True, timeout=300)
    assert t.returncode == 0, t.stderr
    md = out.with_suffix(".md").read_text()
    assert "gensim | diverse | tiny (40) | 2 | 2 | no reading: the model does not beat" in md
    assert (tmp_path / "t.png").stat().st_size > 10_000
    # the sweep itself ended with the same table and a figure in its folder
    assert (tmp_path / "sweep" / "table4_heldout.md").read_text() == md
    assert (tmp_path / "sweep" / "table4_heldout.png").read_bytes() == (tmp_path / "t.png").read_bytes()
    assert f"sweep table and figure: {tmp_path / 'sweep' / 'table4_heldout.csv'}" in r.stdout
    # keep: the committed table's rows (sweeps whose result.json files are elsewhere) beside this sweep's row
    committed = ROOT / "outputs" / "tables" / "table4_heldout.csv"
    t = subprocess.run([*report, f"report.figure={tmp_path / 't.png'}", f"report.keep=[{committed}]"],
                       capture_output=True, text=True, timeout=300, check=False)
    assert t.returncode == 0, t.stderr
    kept_md = out.with_suffix(".md").read_text()
    assert "gensim | diverse | tiny (40) | 2 | 2 |" in kept_md
    for line in (ROOT / "outputs" / "tables" / "table4_heldout.md").read_text().splitlines()[2:]:
        if line.startswith("|"):
            assert line in kept_md  # every committed row, unchanged
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    t = subprocess.run([*report, f"report.keep=[{bad}]"], capture_output=True, text=True, timeout=300, check=False)
    assert t.returncode == 2 and "not a held-out Table 4 CSV" in t.stderr and "Traceback" not in t.stderr
    assert "report.keep: " in t.stderr and t.stderr.count("\n") == 1  # the key the user typed the path into
    # episodes that would be trained on and evaluated: one line, exit 2, before any training
    r = _diversity(*common, "episodes=5", cwd=tmp_path)
    assert r.returncode == 2 and "would train on evaluated episodes" in r.stderr and "Traceback" not in r.stderr


def test_grow_masks_by_hand():
    from simeval.episodes.dataset import grow_masks

    m = np.zeros((2, 8, 8), bool)
    m[0, 3, 3] = True
    m[1, 0, 7] = True  # at a corner: the grown square is cut by the border
    g = grow_masks(m, 1)
    want = np.zeros_like(m)
    want[0, 2:5, 2:5] = True
    want[1, 0:2, 6:8] = True
    np.testing.assert_array_equal(g, want)
    np.testing.assert_array_equal(grow_masks(m, 0), m)
    assert grow_masks(m, 2)[0].sum() == 25


def test_robot_pixels_carry_no_training_loss_computed_by_hand():
    """WorldModel.step_errors with a robot_mask: the image term is the squared error over the unmasked pixels
    only, checked against the decoder's output summed by hand in numpy."""
    from simeval.models.world_model import WorldModel

    torch.manual_seed(0)
    model = WorldModel(WorldModelConfig.from_dict(TINY["model"]), state_dim=2, action_dim=2)
    size = model.cfg.image_size
    rng = np.random.default_rng(0)
    batch = {"image": torch.as_tensor(rng.integers(0, 256, (2, 3, size, size, 3), dtype=np.uint8)),
             "state": torch.zeros(2, 3, 2), "prev_action": torch.zeros(2, 3, 2),
             "is_first": torch.tensor([[True, False, False]] * 2), "mask": torch.ones(2, 3, dtype=torch.bool)}
    robot = np.zeros((2, 3, size, size), bool)
    robot[:, :, : size // 3] = True
    robot[1, 2] = True  # a frame that is all robot carries no image loss at all
    decoded = {}
    real_decoder = model.image_decoder.forward
    model.image_decoder.forward = lambda feat: decoded.setdefault("x", real_decoder(feat))
    g = torch.Generator().manual_seed(1)
    masked = model.step_errors({**batch, "robot_mask": torch.as_tensor(robot)}, generator=g)["image_se"]
    pred = decoded.pop("x").detach().numpy()
    image = batch["image"].numpy() / 255.0
    by_hand = ((pred - image) ** 2 * ~robot[..., None]).sum((-3, -2, -1))
    np.testing.assert_allclose(masked.detach().numpy(), by_hand, rtol=1e-5)
    assert masked[1, 2] == 0
    g = torch.Generator().manual_seed(1)
    full = model.step_errors(batch, generator=g)["image_se"].detach().numpy()  # no mask: every pixel
    np.testing.assert_allclose(full, ((decoded.pop("x").detach().numpy() - image) ** 2).sum((-3, -2, -1)), rtol=1e-5)


def test_exclude_robot_from_loss_trains_on_masks_where_episodes_have_them():
    plain = make_physics_group("shared", 2, 12, 22, 16)
    masked = run(_with_flickering_robot(plain), k=4, exclude_robot_from_loss=True, mask_margin=1)["protocol"]
    assert masked["exclude_robot_from_loss"] is True and masked["robot_excluded_from_loss"] is True
    without = run(plain, k=4, exclude_robot_from_loss=True)["protocol"]
    assert without["robot_excluded_from_loss"] is False  # no masks: the full frame, and the result says so
    assert run(plain, k=4)["protocol"]["robot_excluded_from_loss"] is False
    with pytest.raises(UserError, match="exclude_robot_from_loss"):
        run(plain, k=4, exclude_robot_from_loss="yes")


def test_pose_range_shrinks_poses_towards_one_anchor_layout():
    from simeval.sim.core.world import WORKSPACE
    from simeval.sim.tasks.spec import suite_dir, SpecError, check_variation, load_suite, sample_instance

    spec = next(s for s in load_suite(suite_dir("gensim")) if s.name == "put-blocks-in-matching-zones")

    def poses(seed, pose_range):
        inst = sample_instance(spec, seed, None, pose_range)
        return inst, {k: (xy.copy(), yaw) for k, (xy, yaw) in inst.poses.items()}

    _, anchor = poses(0, 0.0)
    for seed in range(1, 6):
        _, p0 = poses(seed, 0.0)  # every episode the anchor layout
        assert all(np.array_equal(p0[k][0], anchor[k][0]) and p0[k][1] == anchor[k][1] for k in anchor)
        default, p1 = poses(seed, 1.0)
        usual = sample_instance(spec, seed).poses  # 1 is the suite's usual draw, bit for bit
        assert all(np.array_equal(p1[k][0], usual[k][0]) and p1[k][1] == usual[k][1] for k in usual)
        inst, half = poses(seed, 0.5)
        assert [o.color for o in inst.objects] == [o.color for o in default.objects]  # colours do not move
        extent = np.array([hi - lo for lo, hi in WORKSPACE])
        for k in anchor:  # within half the workspace's extent of the anchor
            assert np.all(np.abs(half[k][0] - anchor[k][0]) <= 0.5 * extent + 1e-9)
    spread = [np.std([np.concatenate([xy for xy, _ in poses(s, f)[1].values()]) for s in range(20)], 0).mean()
              for f in (0.0, 1 / 3, 2 / 3, 1.0)]
    assert spread[0] < 1e-12 and spread[1] < spread[2] < spread[3]
    with pytest.raises(SpecError, match="pose_range"):
        check_variation([spec], {"scene": {"pose_range": 1.5}})


def test_a_store_that_is_a_file_is_named_without_a_collect_command_into_it(tmp_path):
    (tmp_path / "a_file").write_text("")
    r = _diversity("store=a_file", "pipeline=bbsea", "task_group=drawer", cwd=tmp_path)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip() == ("error: store=a_file: is a file, not a folder; give the episode store's folder "
                                "(default outputs/episodes)")


def test_the_run_line_names_the_moving_pixels_with_their_share():
    values = run(make_physics_group("varied", 2, 12, 20, 16), k=4)
    # 12 steps at tiny sizes learn nothing: the gate says so in place of every number
    gated = dd.summary_line(values)
    assert not values["gate"]["passes"] and "pixel reading: no reading: the model does not beat" in gated
    assert "one-step" not in gated and "x1e-3" not in gated
    values = {k: v for k, v in values.items() if k != "gate"}  # a run recorded before the gate: its numbers
    one = values["prediction"]["summary"]["one_step"]
    line = dd.summary_line(values)
    assert f"moving pixels ({100 * one['moving_share']:.2g}% of kept) one-step " \
           f"{1e3 * one['model']['moving_error_per_pixel']:.3f} x1e-3" in line
    assert line.endswith("; no robot masks: object-focused = full frame")
    still = {**values, "prediction": {**values["prediction"], "summary": {
        **values["prediction"]["summary"], "one_step": {**one, "moving_share": None}}}}
    assert "moving pixels none" in dd.summary_line(still)


def test_moving_sums_of_a_model_that_draws_one_constant_image_computed_by_hand():
    from simeval.measures.dynamics_diversity.prediction import MOTION_THRESHOLD, step_sums

    rng = np.random.default_rng(0)
    B, L, H, W = 2, 5, 6, 7
    image = rng.integers(0, 256, (B, L, H, W, 3), dtype=np.uint8)
    image[:, :, :3] = image[:, :1, :3]  # the top rows never change: still pixels
    robot = np.zeros((B, L, H, W), bool)
    robot[:, :, :, :2] = True  # the robot covers the two left columns
    frame = rng.random((H, W, 3)).astype(np.float32)
    batch = {"image": torch.as_tensor(image), "robot_mask": torch.as_tensor(robot), "state": torch.zeros(B, L, 1),
             "prev_action": torch.zeros(B, L, 1), "is_first": torch.zeros(B, L, dtype=torch.bool),
             "mask": torch.ones(B, L, dtype=torch.bool), "task": torch.zeros(B, dtype=torch.long)}
    out = step_sums(ConstantImageModel(torch.as_tensor(frame)), batch, torch.zeros(1, H, W, 3))
    o = image.astype(np.float64) / 255
    keep = ~robot[:, 1:] & ~robot[:, :-1]
    moving = keep & (((o[:, 1:] - o[:, :-1]) ** 2).sum(-1) > MOTION_THRESHOLD)
    assert moving.sum() > 0 and not moving[:, :, :3].any()  # the still rows never count
    model_se = ((o[:, 1:] - frame) ** 2).sum(-1)
    np.testing.assert_allclose(out["one_step/moving_pixels"].numpy(), moving.sum((1, 2, 3)))
    np.testing.assert_allclose(out["one_step/model/moving"].numpy(), (model_se * moving).sum((1, 2, 3)), rtol=1e-5)
    np.testing.assert_allclose(out["one_step/mean/moving"].numpy(), ((o[:, 1:] ** 2).sum(-1) * moving).sum((1, 2, 3)),
                               rtol=1e-5)


def test_a_kept_table_reads_back_as_the_rows_that_wrote_it_and_fresh_rows_replace_whole_rows(tmp_path):
    """The committed held-out Table 4 read from its CSV and written again gives the same bytes (CSV and Markdown);
    a fresh row of a kept group replaces that row whole, the other kept rows stay, in build's order."""
    from simeval.measures.dynamics_diversity.table4_heldout import merge, read_rows, write

    committed = ROOT / "outputs" / "tables" / "table4_heldout"
    kept = read_rows(committed.with_suffix(".csv"))
    written = write(kept, tmp_path / "again")
    assert written["csv"].read_bytes() == committed.with_suffix(".csv").read_bytes()
    assert written["md"].read_bytes() == committed.with_suffix(".md").read_bytes()
    first = kept[0]
    fresh = {**first, "one_step_object_10": 123.0}
    merged = merge(kept, [fresh, {**first, "pipeline": "zzz"}])
    assert len(merged) == len(kept) + 1 and merged[0]["one_step_object_10"] == 123.0
    assert merged[1:len(kept)] == kept[1:]
    assert [(r["pipeline"], r["group"]) for r in merged] == sorted((r["pipeline"], r["group"]) for r in merged)
    with pytest.raises(UserError, match=r"line 2, column steps: 'x' is not a number"):
        (tmp_path / "broken.csv").write_text("counts,group,pipeline,preset,steps\n10,g,p,cpu,x\n")
        read_rows(tmp_path / "broken.csv")


def test_the_table_reads_records_made_before_the_moving_pixels_were_summed(tmp_path):
    from simeval.measures.dynamics_diversity.table4_heldout import build, display

    source = make_physics_group("varied", 2, 12, 20, 16)

    def record(seed: int, old: bool) -> dict:
        values = run(source, k=4)
        episodes = values["prediction"]["per_episode"]
        if old:  # what a record written before this change holds
            episodes = [{**e, "sums": {k: v for k, v in e["sums"].items() if "moving" not in k}} for e in episodes]
        return {"metric": "dynamics_diversity", "status": "ok", "created": str(seed),
                "identity": {"pipeline": "p", "task_group": "g", "preset": "tiny", "steps": 12, "episodes": 4,
                             "seed": seed, "protocol": "heldout"},
                "values": {"prediction": {**values["prediction"], "per_episode": episodes}}}

    new, old = record(0, old=False), record(1, old=True)
    header, _ = display(build([old], n_boot=50))
    assert not any("moving" in h for h in header)  # the table such records gave before
    mixed = build([new, old], n_boot=50)[0]  # a cell of both: the moving ratios need every run's sums
    assert "one_step_moving_4" not in mixed and np.isfinite(mixed["one_step_object_4"])
    alone = build([new], n_boot=50)[0]
    assert np.isfinite(alone["one_step_moving_4"]) and any("moving" in h for h in display([alone])[0])


def _sums(moving_pixels: float, last_object: float) -> dict[str, float]:
    """Summed SUM_KEYS of one run, made by hand: 10 frames, 1,000 kept pixels, the model's object error 6.0."""
    from simeval.measures.dynamics_diversity.prediction import SUM_KEYS

    sums = dict.fromkeys(SUM_KEYS, 1.0)
    for kind in ("one_step", "open_loop", "reconstruction"):
        sums.update({f"{kind}/frames": 10.0, f"{kind}/kept_pixels": 1000.0, f"{kind}/model/object": 6.0,
                     f"{kind}/mean/object": 30.0})
    for kind in ("one_step", "open_loop"):
        sums.update({f"{kind}/moving_pixels": moving_pixels, f"{kind}/last/object": last_object})
    return sums


def test_object_skill_against_a_copy_needs_something_outside_the_robot_to_move():
    """With (nearly) nothing moving outside the robot, the last frame is exact up to 8-bit noise: 1 - model / ~0 read
    -13,823 on the GenSim dose control. No reading there; where enough moved, 1 - 6 / 3 = -1 by hand."""
    from simeval.measures.dynamics_diversity.prediction import MIN_MOVING_PIXELS, summarise
    from simeval.measures.dynamics_diversity.table4_heldout import cell_replicates

    still = summarise(_sums(MIN_MOVING_PIXELS - 1, 1e-4), image_size=8)["one_step"]
    assert still["object_skill_vs_last"] is None
    assert still["object_skill_vs_mean"] == pytest.approx(1 - 6 / 30)  # a constant image still has an error
    moved = summarise(_sums(MIN_MOVING_PIXELS, 3.0), image_size=8)["one_step"]
    assert moved["object_skill_vs_last"] == pytest.approx(-1.0)

    def cell(per_run: list[dict]):
        arrays = {k: np.array([[s[k]] for s in per_run]) for k in per_run[0]}  # (runs, 1 episode)
        draws = resample.draws(len(per_run), np.array(["t"]), 200, 0)
        return cell_replicates(arrays, draws)

    point, reps = cell([_sums(MIN_MOVING_PIXELS * 0.4, 1e-4), _sums(0, 1e-4)])  # no resample reaches 100
    assert np.isnan(point["one_step_object_skill_last"]) and np.isnan(reps["one_step_object_skill_last"]).all()
    assert np.isfinite(point["one_step_object_skill_mean"])
    point, reps = cell([_sums(MIN_MOVING_PIXELS, 3.0), _sums(0, 3.0)])  # 100 moving over both runs: a reading
    assert point["one_step_object_skill_last"] == pytest.approx(-1.0)
    # a resample of the still run twice has too few moving pixels: no reading in it, the others read -1
    gated = np.isnan(reps["one_step_object_skill_last"])
    assert gated.any() and not gated.all()
    np.testing.assert_allclose(reps["one_step_object_skill_last"][~gated], -1.0)


def _state_reading(model_error: float, mean_error: float, spread: float, seed: int = 0) -> dict:
    """A state reading of 2 tasks x 10 held-out episodes of 20 steps, 3 seeds: per-step model error around
    `model_error` (episodes vary by +-`spread`), last state 1.0, mean state `mean_error`."""
    rng = np.random.default_rng(seed)
    rows = []
    for e in range(20):
        wobble = 1 + spread * (rng.uniform(-1, 1))
        rows.append({"task": "ab"[e % 2], "index": e, "frames": 20,
                     "model": [20 * model_error * wobble * (1 + 0.01 * s) for s in range(3)],
                     "last_state": 20.0, "mean_state": 20 * mean_error, "constant_velocity": 20.0})
    return {"per_episode": rows, "gate": {"passes": True, "verdict": "reads"}}


def test_the_state_readings_fall_by_hand_falls_flat_too_wide_and_missing():
    from simeval.measures.dynamics_diversity.table4_heldout import _fall_text, state_fall

    # 0.5 -> 0.2 per step, the mean state unchanged: a fall of 0.3 beyond both baselines' change
    out = state_fall(_state_reading(0.5, 2.0, 0.1), _state_reading(0.2, 2.0, 0.1, seed=1), 10, 40)
    assert out["state_fall_verdict"] == "falls"
    assert out["state_drop"] == pytest.approx(0.5 * 1.01 - 0.2 * 1.01, abs=0.02)
    assert out["state_drop_lo"] < out["state_drop"] < out["state_drop_hi"]
    # the same error at both counts, episodes that barely vary: an interval within +-5% of 0.5
    assert state_fall(_state_reading(0.5, 2.0, 0.01), _state_reading(0.5, 2.0, 0.01), 10, 40)[
        "state_fall_verdict"] == "no fall"
    # episodes that vary by +-90%: the interval reaches past +-0.025 and cannot tell
    wide = state_fall(_state_reading(0.5, 2.0, 0.9), _state_reading(0.5, 2.0, 0.9, seed=1), 10, 40)
    assert wide["state_fall_verdict"].startswith("no reading: too wide")
    gated = {**_state_reading(0.2, 2.0, 0.1), "gate": {"passes": False, "verdict": "no reading: the model does not "
                                                        "beat the last state"}}
    assert state_fall(_state_reading(0.5, 2.0, 0.1), gated, 10, 40)["state_fall_verdict"] == \
        "no reading: the model does not beat the last state at 40 episodes"
    assert state_fall(None, _state_reading(0.2, 2.0, 0.1), 10, 40) == {}
    # an objects' reading (version 5) at 10 against a whole state's (version 4) at 40 is no fall of anything
    v5 = {**_state_reading(0.5, 2.0, 0.1), "version": 5, "reads": "objects"}
    mixed = state_fall(v5, {**_state_reading(0.2, 2.0, 0.1, seed=1), "version": 4}, 10, 40)
    assert mixed == {"state_fall_verdict": "no reading: its counts were read by different versions of the state "
                                           "reading (10: version 5, objects, 40: version 4, state)"}
    assert _fall_text(mixed["state_fall_verdict"], "") == ("no reading (counts read by different versions: rerun "
                                                           "the sweep)")
    assert "state_drop" in state_fall(v5, {**v5, "per_episode": _state_reading(0.2, 2.0, 0.1)["per_episode"]},
                                      10, 40)
    # one version, but 40's episodes recorded the drawer's moving link (7 more values): no fall of one state
    apart = state_fall({**v5, "dims": 30, "read_dims": 14}, {**v5, "dims": 37, "read_dims": 21}, 10, 40)
    assert apart == {"state_fall_verdict": "no reading: its counts read states of different layouts, recorded apart "
                                           "(10: 14 of 30 values, 40: 21 of 37 values)"}
    assert _fall_text(apart["state_fall_verdict"], "") == ("no reading (counts read states recorded apart: rerun the "
                                                           "sweep on one collection)")


def test_a_state_reading_made_with_other_inputs_says_so_in_its_cell_and_is_no_fall_against_the_protocols():
    """A sweep with protocol.state_model.input_scale=state (versions 1-6's inputs) in the runs_dir: its cells say
    "[input_scale=state]" (a user's trial: the table showed whichever sweep was newest, silently), and a count read
    with one setting against a count read with the other gives no fall."""
    from simeval.measures.dynamics_diversity.table4_heldout import _state, _state_columns, state_fall

    old = {**_state_reading(0.5, 2.0, 0.1), "version": 7, "reads": "objects", "target_scale": "change",
           "input_scale": "state", "summary": {"model": 0.5, "skill_vs_last_state": 0.5,
                                               "skill_vs_constant_velocity": 0.5}}
    now = {**old, "input_scale": "change", "per_episode": _state_reading(0.2, 2.0, 0.1, seed=1)["per_episode"]}
    row: dict = {}
    _state_columns(row, 10, old)
    _state_columns(row, 40, now)
    assert _state(row, 10) == "objects [input_scale=state]: 0.5 (0.50 / 0.50)"
    assert _state(row, 40) == "objects: 0.5 (0.50 / 0.50)" and "state_inputs_40" not in row
    from simeval.measures.dynamics_diversity.table4_heldout import _state_settings_key
    assert _state_settings_key(row, [10, 40]) == " [state at 10: input_scale=state]"  # the figure's key says so too
    assert _state_settings_key({**row, "state_inputs_20": "input_scale=state"}, [10, 20, 40]) == \
        " [state at 10/20: input_scale=state]"
    assert _state_settings_key({}, [10, 40]) == ""
    assert state_fall(old, now, 10, 40)["state_fall_verdict"] == (
        "no reading: its counts were read by different versions of the state reading (10: version 7, objects, "
        "input_scale=state, 40: version 7, objects)")
    assert state_fall(old, {**now, "input_scale": "state"}, 10, 40)["state_fall_verdict"] == "falls"
    from simeval.measures.dynamics_diversity.table4_heldout import _fall_text
    from simeval.measures.dynamics_diversity.gate import OPPOSITE
    assert _fall_text(OPPOSITE + " (...)", "") == ("no reading (the fall and a baseline's own change point opposite "
                                                  "ways)")


def test_the_state_reading_alone_is_the_reading_a_run_with_pixels_gives_and_trains_no_world_model(monkeypatch):
    """protocol.pixels=false: the same training and evaluated episodes, the same state reading to the last digit as
    the run that also trains the world model, and no world model built nor frame read."""
    from simeval.measures.dynamics_diversity.state_reading import StateModelConfig

    source = RecordingSource(make_physics_group("varied", 2, 12, 20, 16))
    state_model = StateModelConfig(max_steps=200, eval_every=50, patience=2, seeds=(0, 1))

    def evaluate(pixels: bool) -> dict:
        training = dd.Training(WorldModelConfig.from_dict(TINY["model"]),
                               TrainConfig.from_dict({**TINY["train"], "seed": 0}), WindowSpec(**TINY["window"]),
                               steps=12)
        evaluation = dd.Evaluation(protocol="heldout", episodes=(8, 12), context=3, horizon=5,
                                   state_model=state_model, pixels=pixels)
        return dd.fit_and_evaluate(source, 4, training, evaluation, dd.Execution(progress=False))

    both = evaluate(True)
    source.reads.clear()

    def no_world_model(*args, **kwargs):
        raise AssertionError("a state-only run built a world model")

    monkeypatch.setattr(dd, "WorldModel", no_world_model)
    monkeypatch.setattr(ArraySource, "read", lambda *a, **k: pytest.fail("a state-only run read frames"))
    alone = evaluate(False)
    assert alone["prediction"] is None and alone["gate"] is None and alone["train"] is None
    # what each reading is, first in the values (result.json), before any number
    assert list(alone)[0] == "readings" and alone["readings"] == {
        "pixels": "not read (protocol.pixels=false)", "state": "whole state: " + alone["state"]["gate"]["verdict"]}
    assert both["readings"] == {"pixels": both["gate"]["verdict"],
                                "state": "whole state: " + both["state"]["gate"]["verdict"]}
    assert alone["protocol"] == {"name": "heldout", "pixels": False, "trained_on": [1, 4], "evaluated_on": [9, 12]}
    assert {e for _, e in source.reads} == set(range(24)) - {4, 5, 6, 7, 16, 17, 18, 19}  # ranks 1-4 and 9-12
    drop = ("seconds",)
    assert {k: v for k, v in alone["state"].items() if k not in drop} == \
        {k: v for k, v in both["state"].items() if k not in drop}
    assert dd.summary_line(alone) == f"held-out episodes [9, 12]: state reading: {alone['state']['line']}"
    assert set(dd.headline(alone)["heldout"]) >= {"state/gate_passes", "state/model"}
    with pytest.raises(UserError, match="protocol.pixels=false with protocol.state_model=null"):
        dd.fit_and_evaluate(source, 4, dd.Training(WorldModelConfig.from_dict(TINY["model"]),
                                                   TrainConfig.from_dict(TINY["train"]), WindowSpec(**TINY["window"])),
                            dd.Evaluation(protocol="heldout", episodes=(8, 12), pixels=False),
                            dd.Execution(progress=False))


def _state_only_record(seed: int, episodes: int, n_heldout: int) -> dict:
    state = {"gate": {"passes": True, "verdict": "reads"}, "line": "reads",
             "summary": {"model": 0.01 * (50 - episodes) / 40, "last_state": 0.2, "mean_state": 1.0,
                         "constant_velocity": 0.05, "skill_vs_last_state": 0.9, "skill_vs_mean_state": 0.99,
                         "skill_vs_constant_velocity": 0.5},
             "per_episode": [{"task": f"t{i % 2}", "index": i, "frames": 20, "model": [0.2 - 0.001 * episodes] * 3,
                              "last_state": 4.0, "mean_state": 20.0, "constant_velocity": 1.0}
                             for i in range(n_heldout)], "seeds": [0, 1, 2]}
    return {"metric": "dynamics_diversity", "status": "ok", "created": str(seed),
            "identity": {"pipeline": "bbsea", "task_group": "drawer", "preset": "cpu", "steps": 1000,
                         "episodes": episodes, "seed": seed, "protocol": "heldout"},
            "values": {"protocol": {"name": "heldout", "pixels": False}, "prediction": None, "gate": None,
                       "state": state}}


def test_rows_of_the_state_reading_alone_replace_only_a_kept_rows_state_columns_of_the_same_episodes(tmp_path):
    """A sweep with protocol.pixels=false beside the committed table: the kept row keeps its pixel columns and
    takes the fresh state columns (and says so), where both scored as many held-out episodes; otherwise
    the fresh row stands alone and its pixel cells say they were not read. Its table and figure are written."""
    from simeval.measures.dynamics_diversity.table4_heldout import build, display, has_pixels, merge, plot, read_rows

    kept = read_rows(ROOT / "outputs" / "tables" / "table4_heldout.csv")
    old = next(r for r in kept if (r["pipeline"], r["group"]) == ("bbsea", "drawer"))
    recs = [_state_only_record(0, k, old["heldout_episodes_10"]) for k in (10, 20, 40)]  # one run per count
    fresh = build(recs, n_boot=100)
    assert len(fresh) == 1 and not any(c.startswith(("gate_", "one_step")) for c in fresh[0])
    assert fresh[0]["runs_10"] == 3  # the state model's seeds
    assert fresh[0]["state_model_10"] == pytest.approx(0.01) and fresh[0]["state_fall_verdict"] == "falls"
    merged = {(r["pipeline"], r["group"]): r for r in merge(kept, fresh)}
    row = merged[("bbsea", "drawer")]
    assert {c: v for c, v in row.items() if not c.startswith("state_")} == \
        {c: v for c, v in old.items() if not c.startswith("state_")}
    assert row["state_model_40"] == fresh[0]["state_model_40"] and row["state_drop"] == fresh[0]["state_drop"]
    assert row["state_runs"].startswith("runs of the state reading only (protocol.pixels=false), beside the kept")
    # the kept row fails the pixel gate at every count: no model error is shown, its skills are
    gated_cells = display([row])[1][0]
    assert gated_cells[5].startswith("no reading") and gated_cells[6] == gated_cells[10] == gated_cells[12] == \
        gated_cells[14] == "no reading"
    assert gated_cells[11].startswith("-")
    assert gated_cells[15].startswith("whole state (v4): 0.0")  # the state cell says what it read
    assert len(merged) == len(kept)
    # another number of held-out episodes: the kept pixel reading is of other episodes, so it is not borrowed
    other = build([_state_only_record(0, k, 40) for k in (10, 20, 40)], n_boot=100)
    alone = {(r["pipeline"], r["group"]): r for r in merge(kept, other)}[("bbsea", "drawer")]
    _, body = display([alone])
    assert body[0][5] == "not read (protocol.pixels=false)" and body[0][6] == "—" and body[0][9] == "—"
    assert body[0][15].startswith("whole state (v4): 0.01 (0.90 / 0.50)")  # a record without `reads`
    assert body[0][2] == "states only" and body[0][16].startswith("falls: 0.0")  # no world model; the verdict said
    # a sweep with pixels beside the state-only one: its runs make the row (pixel and state columns alike)
    source = make_physics_group("varied", 2, 12, 20, 16)
    full = {"metric": "dynamics_diversity", "status": "ok", "created": "9",
            "identity": {**recs[0]["identity"], "episodes": 4}, "values": run(source, k=4)}
    state_only = {**recs[0], "identity": {**recs[0]["identity"], "episodes": 4}}
    both = build([state_only, full], n_boot=50)
    assert len(both) == 1 and has_pixels(both[0]) and "state_runs" not in both[0]
    # ... unless the states-only run read the state with a newer version of the reading: its state columns then
    own = {**state_only["values"]["state"], "version": 4, "summary": {**state_only["values"]["state"]["summary"],
                                                                      "model": 0.123}}
    full_v4 = {**full, "values": {**full["values"], "state": own}}
    newer = {**state_only, "values": {**state_only["values"], "state": {**state_only["values"]["state"],
                                                                        "version": 5, "reads": "objects"}}}
    [mixed] = build([newer, full_v4], n_boot=50)
    assert has_pixels(mixed) and mixed["state_model_4"] == newer["values"]["state"]["summary"]["model"]
    assert mixed["state_reads_4"] == "objects" and mixed["state_runs"].startswith("runs of the state reading only")
    assert {c: v for c, v in mixed.items() if not c.startswith("state_")} == \
        {c: v for c, v in both[0].items() if not c.startswith("state_")}
    [same] = build([{**newer, "values": {**newer["values"], "state": {**newer["values"]["state"], "version": 4}}},
                    full_v4], n_boot=50)  # not newer: the pixel runs' own
    assert same["state_model_4"] == 0.123 and "state_runs" not in same
    # the same version read after the pixel runs (the episodes collected again with more state): the newer reading
    later = {**newer, "created": "99", "values": {**newer["values"], "state": {**newer["values"]["state"],
                                                                               "version": 4}}}
    [again] = build([later, full_v4], n_boot=50)
    assert again["state_model_4"] == newer["values"]["state"]["summary"]["model"] != 0.123
    assert again["state_runs"].startswith("runs of the state reading only") and "read after them" in again["state_runs"]
    # an older version never replaces the pixel runs' own, however late it was read
    [old_late] = build([{**later, "values": {**later["values"], "state": {**later["values"]["state"], "version": 3}}},
                        full_v4], n_boot=50)
    assert old_late["state_model_4"] == 0.123
    assert plot([alone, merged[("bbsea", "table")]], tmp_path / "f.png").stat().st_size > 10_000


def test_the_command_line_reads_the_states_alone_and_says_so(tmp_path):
    """`protocol.pixels=false` from the command line: one line naming the states-only protocol, a result.json with
    the state reading and no pixel one, and no checkpoint written."""
    import json

    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    write_group(tmp_path / "store", "diverse", n_tasks=2, episodes=6, n_actions=14, size=16, pipeline="gensim")
    r = _diversity("pipeline=gensim", "task_group=diverse", f"store={tmp_path}/store", "eval_episodes=[5,6]",
                   "episodes=4", "protocol.pixels=false", "protocol.state_model.max_steps=100", "progress=false",
                   "threads=1", f"checkpoint_dir={tmp_path}/ck", f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "gensim/diverse episodes=4 [protocol=heldout, states only]: held-out episodes [5, 6]: state reading: " \
        in r.stdout + r.stderr
    rec = json.loads((tmp_path / "run" / "result.json").read_text())
    assert rec["values"]["prediction"] is None and rec["values"]["state"]["dims"] > 0
    assert rec["identity"]["settings"]["protocol"]["pixels"] is False
    assert not any((tmp_path / "ck").glob("*.pt"))


def test_a_store_recorded_without_frames_serves_the_state_reading_and_refuses_the_pixel_one(tmp_path):
    """Episodes collected with `record.cameras=[]` (a state-only collection: GenSim's own code renders nothing then):
    the states-only run reads them and gives the state reading of the same episodes with frames to the last digit;
    a run with pixels on them is one line naming the file and what to do, exit 2."""
    import json
    from dataclasses import replace

    from simeval.episodes.store import EpisodeStore, read_episode
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    paths = write_group(tmp_path / "framed", "diverse", n_tasks=2, episodes=6, n_actions=14, size=16,
                        pipeline="gensim")
    frameless = EpisodeStore(tmp_path / "frameless")
    for p in paths:
        frameless.write(replace(read_episode(p), rgb={}))
    common = ("pipeline=gensim", "task_group=diverse", "eval_episodes=[5,6]", "episodes=4",
              "protocol.state_model.max_steps=100", "progress=false", "threads=1", "checkpoint_dir=null")
    readings = {}
    for name in ("framed", "frameless"):
        r = _diversity(*common, f"store={tmp_path / name}", "protocol.pixels=false",
                       f"hydra.run.dir={tmp_path / ('run_' + name)}", cwd=tmp_path)
        assert r.returncode == 0, r.stderr[-2000:]
        readings[name] = json.loads((tmp_path / f"run_{name}" / "result.json").read_text())["values"]["state"]
    assert readings["frameless"]["summary"] == readings["framed"]["summary"]
    assert readings["frameless"]["per_episode"] == readings["framed"]["per_episode"]
    r = _diversity(*common, f"store={tmp_path / 'frameless'}", f"hydra.run.dir={tmp_path / 'run_pixels'}",
                   cwd=tmp_path)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert lines[-1].startswith(f"error: {tmp_path / 'frameless'}") and \
        "recorded without frames (record.cameras=[]), and the pixel reading needs camera 'front': read the state " \
        "alone (protocol.pixels=false)" in lines[-1]


def test_state_fall_cells_keep_two_significant_digits_and_the_panel_says_what_each_row_read():
    """A state error's fall is 1e-5 in one group's units and 1 in another's: its cell keeps 2 significant digits of
    the interval's larger end (fixed decimals showed BBSEA drawer's objects as 0.0000 [-0.0000, 0.0000]); the state
    panel's title names what its rows read."""
    from simeval.measures.dynamics_diversity.table4_heldout import _sig, _state_panel_title

    assert _sig({"v": 1.3e-5, "v_lo": 4e-6, "v_hi": 2.2e-5}, "v") == "0.000013 [0.000004, 0.000022]"
    assert _sig({"v": 1.33, "v_lo": 0.7, "v_hi": 1.92}, "v") == "1.3 [0.7, 1.9]"
    assert _sig({"v": None}, "v") == "—"
    row = lambda p, reads: {"pipeline": p, "group": "g", "counts": "10/40",  # noqa: E731
                            **({"state_reads_10": reads} if reads else {})}
    assert _state_panel_title([row("bbsea", "objects")]).startswith("state reading: objects' poses\n")
    assert _state_panel_title([row("bbsea", "objects"), row("metaworld", "state")]).startswith(
        "state reading: objects' poses; whole state: metaworld/g\n")
    assert _state_panel_title([row("bbsea", None)]).startswith("state reading: whole state (v4)\n")


def test_a_state_reading_is_kept_by_its_inputs_so_a_rerun_skips_it_and_other_states_read_again(tmp_path, caplog):
    """With a checkpoint_dir the state reading is kept as state_reading-<key>.json, keyed by the states read by
    value: the same run again (a sweep rerun after a kill, or another seed of a sweep with pixels) returns it without
    training; the same episodes with one value changed, or one more value recorded, read again; a cut-short file
    is read again and rewritten."""
    import dataclasses
    import json
    import logging

    from simeval.measures.dynamics_diversity.state_reading import StateModelConfig

    source = make_physics_group("varied", 2, 12, 20, 16)
    training = dd.Training(WorldModelConfig.from_dict(TINY["model"]), TrainConfig.from_dict(TINY["train"]),
                           WindowSpec(**TINY["window"]), steps=12)
    evaluation = dd.Evaluation(protocol="heldout", episodes=(8, 12), pixels=False,
                               state_model=StateModelConfig(max_steps=40, eval_every=20, seeds=(0,)))

    def read(src, name="ck"):
        return dd.fit_and_evaluate(src, 4, training, evaluation,
                                   dd.Execution(progress=False, checkpoint_dir=tmp_path / name))["state"]

    def plain(state):
        return json.loads(json.dumps({k: v for k, v in state.items() if k not in ("cache", "seconds")},
                                     default=lambda v: v.tolist()))

    first = read(source)
    [kept] = (tmp_path / "ck").glob("state_reading-*.json")
    assert "cache" not in first
    assert [p.name for p in (tmp_path / "ck").iterdir()] == [kept.name]  # its training's saves gone once kept
    with caplog.at_level(logging.INFO, logger=dd.__name__):
        again = read(source)
    assert again["cache"] == str(kept) and plain(again) == plain(first)
    assert "state reading: read before, from" in caplog.text
    fresh = read(source, "other")  # read anew elsewhere: the kept reading is the one a rerun would give
    assert plain(fresh) == plain(first)

    changed = [dict(a) for a in source.arrays]
    changed[0]["state"] = changed[0]["state"].copy()
    changed[0]["state"][3, 0] += 1e-3
    read(ArraySource(source.infos, changed))
    one_more = [{**a, "state": np.concatenate([a["state"], a["state"][:, :1]], 1)}
                for a in source.arrays]  # the same episodes with one more value recorded (as a moving link)
    read(ArraySource(source.infos, one_more))
    evaluation = dataclasses.replace(evaluation, state_model=dataclasses.replace(evaluation.state_model, seeds=(1,)))
    read(source)  # other settings
    assert len(list((tmp_path / "ck").glob("state_reading-*.json"))) == 4
    evaluation = dataclasses.replace(evaluation, state_model=dataclasses.replace(evaluation.state_model, seeds=(0,)))

    kept.write_text(kept.read_text()[:100])  # cut short
    with caplog.at_level(logging.WARNING, logger=dd.__name__):
        mended = read(source)
    assert "unreadable" in caplog.text and "cache" not in mended and plain(mended) == plain(first)
    assert json.loads(kept.read_text())["summary"] == plain(first)["summary"]
    for damaged in ("{}", "[]", "null"):  # JSON, but not a state reading: read again too
        kept.write_text(damaged)
        assert "cache" not in read(source) and json.loads(kept.read_text())["summary"] == plain(first)["summary"]


def test_a_task_recorded_with_and_without_its_moving_links_reads_no_state_and_says_why(tmp_path):
    """A store collected before the suites recorded moving links and topped up after: one task's episodes hold one
    pose row (the body) or two (the body, then its lid). Padded into one layout the earlier lids would never move;
    the state reading says no reading, naming the task, an episode and the fix. One recording alone reads (the
    earlier layout throughout, or the later), and episodes without the suites' metadata (imported) are not judged."""
    from dataclasses import replace

    from simeval.episodes.dataset import StoreSource
    from simeval.episodes.store import EpisodeStore, read_episode
    from simeval.errors import EpisodesUnfit
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group
    from simeval.measures.dynamics_diversity.state_reading import StateModelConfig, read_states, robot_dims

    paths = write_group(tmp_path / "synthetic", "diverse", n_tasks=2, episodes=6, n_actions=14, size=16,
                        pipeline="robogen")
    rng = np.random.default_rng(0)

    def store(name, old_seeds, metadata=True):
        out, written = EpisodeStore(tmp_path / name), []
        for p in paths:
            ep = read_episode(p)
            n = len(ep.state)
            lid = np.cumsum(rng.normal(0, 0.01, (n, 1, 7)), 0)
            poses = np.concatenate([np.zeros((n, 1, 7)), lid], 1).astype(np.float32)
            old = ep.seed in old_seeds
            extra = {"objects": {"laptop": {"shape": "laptop", "bodies": 1, **({} if old else {"links": 1})}}}
            written.append(out.write(replace(ep, object_poses=poses[:, :1] if old else poses,
                                             extra=extra if metadata else {})))
        return StoreSource(written, camera=None)

    seeds = sorted({read_episode(p).seed for p in paths})
    def refuse(src):
        every = list(range(len(src.infos)))
        dd.refuse_poses_recorded_apart(src, read_states(src, every), robot_dims(src, every))

    mixed = store("mixed", set(seeds[:4]))
    with pytest.raises(EpisodesUnfit, match=r"^task \S+: 4 of its episodes were recorded without their moving "
                                            r"links' poses \(collected before 2026-12-06, e.g. .+episode_\d+\.h5\) "
                                            r"and 2 with them; so were 4 of task \S+'s 6; collect the group again "
                                            r"into an empty store"):
        refuse(mixed)
    for one in (store("before", set(seeds)), store("after", set()), store("imported", set(seeds[:4]), False)):
        refuse(one)  # one recording, or no metadata: reads
    ranks = dd.episode_ranks([i.task for i in mixed.infos], [i.seed for i in mixed.infos])
    state = dd._state_reading(mixed, dd.rank_mask(ranks, 0, 4), dd.rank_mask(ranks, 4, 6),
                              StateModelConfig(max_steps=20, eval_every=10, seeds=(0,)), None)
    assert state["line"].startswith("no reading: task ") and not state["gate"]["passes"]


def test_a_stores_pile_particles_are_found_from_its_objects_list_and_a_list_that_disagrees_is_named(tmp_path):
    """StoreSource finds a pile's pose rows from `extra.objects` (each object's bodies and moving links, in the
    order recorded); read_states reads every pose whole (the protocol) or, for the pile control, leaves the
    particles' quaternions unread; an objects list naming more rows than the episode recorded is then an error
    naming the file."""
    from dataclasses import replace

    from simeval.episodes.dataset import StoreSource, particle_rows
    from simeval.episodes.store import EpisodeStore, read_episode
    from simeval.errors import EpisodesUnfit
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group
    from simeval.measures.dynamics_diversity.state_reading import read_states

    objects = {"laptop": {"shape": "laptop", "bodies": 1, "links": 1}, "pile": {"shape": "pile", "bodies": 3},
               "zone": {"shape": "zone", "bodies": 1, "links": None}}
    assert particle_rows(objects) == (2, 3, 4) and particle_rows({"b": {"shape": "block", "bodies": 2}}) == ()
    path = write_group(tmp_path / "synthetic", "diverse", n_tasks=1, episodes=2, n_actions=14, size=16,
                       pipeline="gensim")[0]
    ep = read_episode(path)
    poses = np.tile(np.array([0.1, 0.2, 0.3, 0, 0, 0, 1.0], np.float32), (len(ep.state), 6, 1))
    store = EpisodeStore(tmp_path / "store")
    good = store.write(replace(ep, object_poses=poses, extra={"objects": objects}))
    src = StoreSource([good], camera=None)
    assert src.infos[0].extra["particles"] == (2, 3, 4)
    assert len(read_states(src, [0])[0]) == 2  # the protocol's reading: every pose whole, no mask
    s, _, present = read_states(src, [0], particles_by_position=True)[0]
    dr = ep.state.shape[1]
    np.testing.assert_array_equal(present[dr:].reshape(6, 7)[:, 3:].any(1), [1, 1, 0, 0, 0, 1])
    rows = s[:, dr:].reshape(len(s), 6, 7)
    assert present[dr:].reshape(6, 7)[:, :3].all() and not rows[:, 2:5, 3:].any() and (rows[:, 5, 6] == 1).all()
    bad = store.write(replace(ep, seed=ep.seed + 1, object_poses=poses[:, :4],
                              extra={"objects": {**objects, "pile": {"shape": "pile", "bodies": 5}}}))
    with pytest.raises(EpisodesUnfit, match=r"episode_\d+\.h5: its objects list a pile's particles at pose rows up to "
                                            r"6, but obs/object_poses holds 4 rows; collect it again"):
        read_states(StoreSource([bad], camera=None), [0], particles_by_position=True)
