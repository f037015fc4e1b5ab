"""Open-loop prediction videos of the world model (simeval.models.world_model.open_loop_video,
simeval.measures.dynamics_diversity.run.prediction_videos), the mp4 writer (simeval.media) and the loggers' log_video
without W&B (tests/test_wandb_videos.py runs the entrypoints with logger=wandb)."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch

from simeval.episodes.dataset import ArraySource, WindowDataset, WindowSpec
from simeval.errors import UserError
from simeval.measures.dynamics_diversity.controls.synthetic import make_group
from simeval.models.world_model import IMAGINED_GAP_RGB, WorldModel, WorldModelConfig, open_loop_video

torch.set_num_threads(1)
SIZE, L, CONTEXT, GAP = 16, 8, 3, 2


def tiny_model() -> WorldModel:
    torch.manual_seed(0)
    cfg = WorldModelConfig(image_size=SIZE, deter=16, hidden=16, stoch=2, classes=4, cnn_depth=4, minres=4,
                           mlp_layers=1, mlp_units=8)
    return WorldModel(cfg, state_dim=4, action_dim=2)


def dataset(source=None, pad_end=False) -> WindowDataset:
    src = source or make_group("diverse", 2, 2, 10, SIZE)
    return WindowDataset(src, WindowSpec(length=L, stride=L, pad_end=pad_end), image_size=SIZE)


def panels(video: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return video[:, :, :SIZE], video[:, :, SIZE + GAP:2 * SIZE + GAP], video[:, :, 2 * SIZE + 2 * GAP:]


def test_panels_are_truth_reconstruction_and_imagination_from_actions_alone():
    model, ds = tiny_model(), dataset()
    window = ds[(0, 0)]
    video = open_loop_video(model, window, CONTEXT, seed=3, gap=GAP)
    assert video.dtype == np.uint8 and video.shape == (L, SIZE, 3 * SIZE + 2 * GAP, 3)
    truth, recon, imagined = panels(video)
    np.testing.assert_array_equal(truth, window["image"])
    # separators: white while the open-loop panel shows observed frames, red from the first imagined frame on
    sep = video[:, 0, SIZE]
    assert (sep[:CONTEXT] == 255).all() and (sep[CONTEXT:] == IMAGINED_GAP_RGB).all()
    assert (video == open_loop_video(model, window, CONTEXT, seed=3, gap=GAP)).all()  # seeded

    # a frame after the context reaches the truth and reconstruction panels, never the imagined ones
    later = {**window, "image": window["image"].copy()}
    later["image"][CONTEXT + 1:] = 255 - later["image"][CONTEXT + 1:]
    t2, r2, i2 = panels(open_loop_video(model, later, CONTEXT, seed=3, gap=GAP))
    assert (t2[CONTEXT + 1:] != truth[CONTEXT + 1:]).any() and (r2[CONTEXT + 1:] != recon[CONTEXT + 1:]).any()
    np.testing.assert_array_equal(i2, imagined)
    # an observed frame does reach the imagination, and so does an action taken after the context
    early = {**window, "image": window["image"].copy()}
    early["image"][0] = 255 - early["image"][0]
    assert (panels(open_loop_video(model, early, CONTEXT, seed=3, gap=GAP))[2][CONTEXT:] != imagined[CONTEXT:]).any()
    acted = {**window, "prev_action": window["prev_action"].copy()}
    acted["prev_action"][CONTEXT + 2:] += 3.0
    i3 = panels(open_loop_video(model, acted, CONTEXT, seed=3, gap=GAP))[2]
    np.testing.assert_array_equal(i3[:CONTEXT + 2], imagined[:CONTEXT + 2])
    assert (i3[CONTEXT + 2:] != imagined[CONTEXT + 2:]).any()


def test_imagined_frames_are_the_ones_the_open_loop_error_scores():
    """open_loop_images with a seed, scored like the metric, gives open_loop_errors' number for that seed; the video
    shows those frames (clamped to [0, 1], rounded to uint8)."""
    model, ds = tiny_model(), dataset()
    window = ds[(1, 0)]
    batch = {k: torch.as_tensor(v)[None] for k, v in window.items()}
    errors = model.open_loop_errors(batch, CONTEXT, generator=torch.Generator().manual_seed(7))["image_se"][0]
    frames = model.open_loop_images(batch, CONTEXT, generator=torch.Generator().manual_seed(7))[0]
    target = torch.as_tensor(window["image"]).float() / 255
    torch.testing.assert_close((frames[CONTEXT:] - target[CONTEXT:]).pow(2).sum((1, 2, 3)), errors)
    shown = panels(open_loop_video(model, window, CONTEXT, seed=7, gap=GAP))[2]
    np.testing.assert_allclose(shown / 255, frames.clamp(0, 1).numpy(), atol=0.5 / 255 + 1e-6)
    other = panels(open_loop_video(model, window, CONTEXT, seed=8, gap=GAP))[2]
    assert (other[CONTEXT:] != shown[CONTEXT:]).any()  # another seed, other samples


def test_padded_rows_are_left_out_and_a_bad_context_is_a_user_error():
    model = tiny_model()
    ds = dataset(pad_end=True)  # 11 rows per episode: windows at 0 and 8, the second with 3 real rows
    video = open_loop_video(model, ds[(0, 8)], 1, gap=GAP)
    assert video.shape[0] == 3
    np.testing.assert_array_equal(panels(video)[0], ds.source.arrays[0]["image"][8:11])
    with pytest.raises(UserError, match=r"eval.context=8: expected 1 <= context < window length \(8\)"):
        open_loop_video(model, ds[(0, 0)], L)


def test_prediction_videos_take_each_tasks_lowest_seed_episode_from_its_start():
    from simeval.measures.dynamics_diversity.run import prediction_videos

    src = make_group("diverse", 3, 3, 10, SIZE)
    order = [2, 0, 1, 5, 4, 3, 8, 6, 7]  # episodes stored out of seed order
    shuffled = ArraySource([src.infos[i] for i in order], [src.arrays[i] for i in order])
    ds = dataset(shuffled)
    ds.episodes[[i for i, k in enumerate(order) if k == 3]] = False  # task 1's seed-0 episode is not evaluated
    videos = prediction_videos(tiny_model(), ds, CONTEXT, n_tasks=2)
    assert list(videos) == ["diverse-0-move", "diverse-1-turn"]
    np.testing.assert_array_equal(panels(videos["diverse-0-move"])[0], src.arrays[0]["image"][:L])  # seed 0
    np.testing.assert_array_equal(panels(videos["diverse-1-turn"])[0], src.arrays[4]["image"][:L])  # seed 1


def test_write_video_round_trips_frames_and_pads_odd_sizes(tmp_path):
    import imageio.v2 as imageio

    from simeval.media import write_video

    rng = np.random.default_rng(0)
    frames = np.repeat(np.repeat(rng.integers(0, 256, (5, 5, 7, 3), dtype=np.uint8), 4, 1), 4, 2)[:, :-1, :-1]
    path = write_video(frames, tmp_path / "v" / "clip.mp4", fps=5)
    back = np.stack([f for f in imageio.get_reader(path)])
    assert back.shape == (5, 20, 28, 3)  # 19 x 27 padded to even sizes for yuv420p
    assert np.abs(back[:, :19, :27].astype(float) - frames).mean() < 12  # lossy, but the same pictures
    assert not list(tmp_path.glob("v/.*"))  # no temp file left
    with pytest.raises(ValueError, match="uint8"):
        write_video(frames.astype(np.float32), tmp_path / "bad.mp4")


def test_csv_logger_lists_videos_and_the_null_logger_writes_nothing(tmp_path):
    from simeval.loggers import CsvLogger, NullLogger

    frames = np.zeros((4, 8, 8, 3), np.uint8)
    frames[:, :, :4] = 200
    with CsvLogger(run_dir=str(tmp_path / "run")) as logger:
        logger.log_video("open_loop/task-a", frames, fps=5, caption="task-a: truth | recon | open loop")
        existing = tmp_path / "given.mp4"
        existing.write_bytes(b"not decoded")
        logger.log_video("rollout/best", str(existing), caption="best")
    rows = list(csv.DictReader((tmp_path / "run" / "videos.csv").open()))
    assert [(r["name"], r["caption"]) for r in rows] == [("open_loop/task-a", "task-a: truth | recon | open loop"),
                                                          ("rollout/best", "best")]
    assert rows[0]["path"] == str(tmp_path / "run" / "videos" / "open_loop_task-a.mp4")
    assert rows[1]["path"] == str(existing)
    import imageio.v2 as imageio

    assert len([f for f in imageio.get_reader(rows[0]["path"])]) == 4
    with NullLogger() as logger:
        logger.log_video("x", frames)
    with pytest.raises(FileNotFoundError, match="no file"):
        CsvLogger(run_dir=str(tmp_path / "r2")).log_video("x", str(tmp_path / "missing.mp4"))
