"""LeRobotDataset import and export (simeval.pipelines.lerobot_format) against lerobot 0.4.4's own writer and
reader (`make lerobot-env`; run in a subprocess by tests/stand_ins/lerobot_io.py): actions and states bit for bit,
PNG frames bit for bit, AV1 frames within the codec's tolerance of what was written and of lerobot's own decoding;
the v2.1 layout against lerobot's own v2.1 -> v3.0 converter; bad input one line with exit 2; kill -9 mid-import."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from helpers import one_line_error
from simeval.episodes.store import EpisodeStore, read_episode
from simeval.pipelines.import_parts import task_name

ROOT = Path(__file__).resolve().parents[1]
STAND_INS = ROOT / "tests" / "stand_ins"
TASKS = ["pick the red cube", "push the green block into the far left corner of the table, then release it and "
                              "move the arm back to its rest pose"]
SPEC = {"episodes": 4, "frames": 14, "height": 32, "width": 48, "fps": 15, "cameras": {"front": "video",
        "wrist": "image"}, "state": 5, "action": 3, "success": True, "tasks": TASKS, "seed": 3}
# AV1 at lerobot's crf 30 in yuv420p on these 32x48 frames: what any decoder gives back of the written frames
MIN_PSNR_DB = 30.0
# two decoders of one stream (PyAV here, torchcodec in lerobot) differ only in rounding of the colour conversion
MAX_MEAN_ABS_BETWEEN_DECODERS = 1.0

pytestmark = pytest.mark.skipif(os.environ.get("CI") != "true" and not (ROOT / ".venv" / ".lerobot-installed").exists()
                                and __import__("importlib").util.find_spec("lerobot") is None,
                                reason="lerobot is not installed (make lerobot-env)")


def _lerobot(*args: str) -> None:
    env = {**os.environ, "PYTHONPATH": str(STAND_INS), "HF_HUB_OFFLINE": "1", "SVT_LOG": "1"}
    res = subprocess.run([sys.executable, str(STAND_INS / "lerobot_io.py"), *args], capture_output=True, text=True,
                         env=env, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(float) - b.astype(float)) ** 2)
    return float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)


@pytest.fixture(scope="module")
def lerobot_written(tmp_path_factory) -> tuple[Path, dict]:
    """A dataset written by lerobot's LeRobotDataset.create / add_frame / save_episode / finalize, and what it was
    given."""
    base = tmp_path_factory.mktemp("lerobot")
    (base / "spec.json").write_text(json.dumps(SPEC))
    _lerobot("write", str(base / "tabletop"), str(base / "spec.json"))
    return base / "tabletop", dict(np.load(base / "tabletop.given.npz"))


def _import(tmp_path: Path, src: Path, *args: str, store: str = "store", **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "src" / "import_data.py"), "format=lerobot", f"src={src}",
                           f"store={tmp_path / store}", f"hydra.run.dir={tmp_path / 'run'}", *args], cwd=ROOT,
                          capture_output=True, text=True, **kw)


def _episodes(store: Path, pipeline: str) -> list:
    return sorted((read_episode(p) for p in EpisodeStore(store).paths(pipeline)), key=lambda e: e.seed)


def test_a_dataset_lerobot_wrote_imports_bit_for_bit_and_frames_within_the_codec(lerobot_written, tmp_path):
    root, given = lerobot_written
    res = _import(tmp_path, root)
    assert res.returncode == 0, res.stderr[-2000:]
    eps = _episodes(tmp_path / "store", "tabletop")
    assert [e.seed for e in eps] == list(range(SPEC["episodes"]))
    _lerobot("read", str(root), str(tmp_path / "lerobot_read.npz"))
    theirs = np.load(tmp_path / "lerobot_read.npz")
    for e, ep in enumerate(eps):
        text = TASKS[e % 2]
        assert ep.description == text and ep.task == task_name(text) and ep.pipeline == "tabletop"
        np.testing.assert_array_equal(ep.action, given[f"action_{e}"])  # bit for bit
        np.testing.assert_array_equal(ep.state, given[f"state_{e}"])
        np.testing.assert_array_equal(ep.rgb["wrist"], given[f"rgb_wrist_{e}"])  # PNG: lossless
        assert _psnr(ep.rgb["front"], given[f"rgb_front_{e}"]) >= MIN_PSNR_DB
        rows = theirs["episode_index"] == e
        lerobot_frames = theirs["observation.images.front"][rows]
        assert np.abs(ep.rgb["front"].astype(int) - lerobot_frames).mean() <= MAX_MEAN_ABS_BETWEEN_DECODERS
        # frame for frame: a frame one step off would differ by far more than the codec's error
        assert _psnr(ep.rgb["front"][1:], given[f"rgb_front_{e}"][:-1]) < MIN_PSNR_DB - 5
        np.testing.assert_array_equal(ep.action, theirs["action"][rows])
        assert ep.success == (e % 2 == 0) and ep.success_known
        assert ep.control_hz == SPEC["fps"] and ep.action_space["dims"] == ["a0", "a1", "a2"]
        assert ep.state_names == [f"joint{i}" for i in range(5)] and ep.action_space["kind"] == "lerobot:test_arm"
        assert ep.progress is None and ep.is_first[0] and ep.is_terminal[-1] and ep.is_terminal.sum() == 1
    values = json.loads((tmp_path / "run" / "result.json").read_text())["values"]
    assert values["written"] == 4 and values["tasks"][task_name(TASKS[0])]["success"] == 2
    again = _import(tmp_path, root)  # idempotent: a second import writes nothing
    assert again.returncode == 0 and json.loads((tmp_path / "run" / "result.json").read_text())["values"][
        "skipped"] == 4


def test_an_export_loads_in_lerobots_own_dataset_with_the_stores_values(lerobot_written, tmp_path):
    root, _ = lerobot_written
    assert _import(tmp_path, root, "name=mine").returncode == 0
    out = tmp_path / "exported"
    res = subprocess.run([sys.executable, str(ROOT / "src" / "export_data.py"), "episodes.pipeline=mine",
                          f"episodes.store={tmp_path / 'store'}", f"out={out}", f"hydra.run.dir={tmp_path / 'ex'}"],
                         cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-2000:]
    _lerobot("read", str(out), str(tmp_path / "read.npz"))
    theirs = np.load(tmp_path / "read.npz")
    eps = _episodes(tmp_path / "store", "mine")
    assert int(theirs["num_episodes"]) == len(eps) and int(theirs["fps"]) == SPEC["fps"]
    for e, ep in enumerate(eps):
        rows = theirs["episode_index"] == e
        np.testing.assert_array_equal(theirs["frame_index"][rows], np.arange(ep.n_steps))
        np.testing.assert_array_equal(theirs["action"][rows], ep.action)
        np.testing.assert_array_equal(theirs["observation.state"][rows], ep.state)
        for cam in ("front", "wrist"):
            assert _psnr(theirs[f"observation.images.{cam}"][rows], ep.rgb[cam]) >= MIN_PSNR_DB
        assert set(theirs["tasks"][rows]) == {ep.description}
        assert theirs["next.success"][rows].tolist() == [False] * (ep.n_steps - 1) + [ep.success]
    # and back: the export imports into the store as the episodes it came from
    assert _import(tmp_path, out, "name=back", store="store2").returncode == 0
    for ep, back in zip(eps, _episodes(tmp_path / "store2", "back")):
        np.testing.assert_array_equal(back.action, ep.action)
        np.testing.assert_array_equal(back.state, ep.state)
        assert back.description == ep.description and back.success == ep.success
        assert _psnr(back.rgb["wrist"], ep.rgb["wrist"]) >= MIN_PSNR_DB


def test_a_round_trip_keeps_the_stores_tasks_and_groups_where_the_instructions_vary(tmp_path):
    """A LeRobot task is an instruction: a pipeline whose instructions vary per episode (a colour, a direction)
    came back from its own export as a task per instruction, each with an episode or two, and in group "all".
    The export writes simeval's task and group beside (columns lerobot's own reader reads past)."""
    import dataclasses

    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    write_group(tmp_path / "src", "diverse", n_tasks=2, episodes=3, n_actions=6, size=32, pipeline="syn")
    store, words = EpisodeStore(tmp_path / "store"), ("left", "right", "up")
    mine = [dataclasses.replace(ep, description=f"push the disk {words[ep.seed]}")
            for ep in _episodes(tmp_path / "src", "syn")]
    for ep in mine:
        store.write(ep)
    out = tmp_path / "exported"
    res = subprocess.run([sys.executable, str(ROOT / "src" / "export_data.py"), "episodes.pipeline=syn",
                          f"episodes.store={tmp_path / 'store'}", f"out={out}", "fps=10",
                          f"hydra.run.dir={tmp_path / 'ex'}"], cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-2000:]
    _lerobot("read", str(out), str(tmp_path / "read.npz"))  # lerobot's own reader loads it, extra columns and all
    theirs = np.load(tmp_path / "read.npz")
    assert int(theirs["num_episodes"]) == 6 and set(theirs["tasks"]) == {ep.description for ep in mine}
    assert _import(tmp_path, out, "name=back", store="store2").returncode == 0
    back = _episodes(tmp_path / "store2", "back")
    assert sorted((e.task, e.group, e.description) for e in back) == sorted(
        (e.task, e.group, e.description) for e in mine)
    assert len({e.task for e in back}) == 2 and {e.group for e in back} == {"diverse"}


def _write_v21(dst: Path, given: dict) -> None:
    """The v2.1 layout (one parquet and one mp4 per episode, meta/*.jsonl) as lerobot 0.4.4's converter reads it."""
    import av
    import pyarrow as pa
    import pyarrow.parquet as pq

    (dst / "meta").mkdir(parents=True)
    fps, n = SPEC["fps"], SPEC["frames"]
    features = {"observation.images.front": {"dtype": "video", "shape": [32, 48, 3],
                                             "names": ["height", "width", "channels"],
                                             "info": {"video.fps": fps, "video.codec": "h264"}},
                "observation.state": {"dtype": "float32", "shape": [5], "names": [f"joint{i}" for i in range(5)]},
                "action": {"dtype": "float32", "shape": [3], "names": ["a0", "a1", "a2"]},
                **{k: {"dtype": "int64", "shape": [1], "names": None} for k in ("frame_index", "episode_index",
                                                                                "index", "task_index")},
                "timestamp": {"dtype": "float32", "shape": [1], "names": None}}
    info = {"codebase_version": "v2.1", "robot_type": "test_arm", "total_episodes": SPEC["episodes"],
            "total_frames": n * SPEC["episodes"], "total_tasks": 2, "total_videos": SPEC["episodes"],
            "total_chunks": 1, "chunks_size": 1000, "fps": fps, "splits": {"train": f"0:{SPEC['episodes']}"},
            "data_path": "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet",
            "video_path": "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4",
            "features": features}
    (dst / "meta" / "info.json").write_text(json.dumps(info))
    (dst / "meta" / "tasks.jsonl").write_text("".join(json.dumps({"task_index": i, "task": t}) + "\n"
                                                      for i, t in enumerate(TASKS)))
    episodes, stats = [], []
    for e in range(SPEC["episodes"]):
        episodes.append({"episode_index": e, "tasks": [TASKS[e % 2]], "length": n})
        vec = {k: {"min": [0.0], "max": [1.0], "mean": [0.5], "std": [0.1], "count": [n]}
               for k in ("observation.state", "action", "timestamp", "frame_index", "episode_index", "index",
                         "task_index")}
        vec["observation.images.front"] = {s: [[[0.5]]] * 3 for s in ("min", "max", "mean", "std")}
        vec["observation.images.front"]["count"] = [n]
        stats.append({"episode_index": e, "stats": vec})
        vectors = {key: pa.FixedSizeListArray.from_arrays(pa.array(given[f"{name}_{e}"].ravel()), width)
                   for key, name, width in (("observation.state", "state", 5), ("action", "action", 3))}
        table = pa.table({**vectors,
                          "timestamp": pa.array((np.arange(n) / fps).astype(np.float32)),
                          "frame_index": pa.array(np.arange(n)), "episode_index": pa.array(np.full(n, e)),
                          "index": pa.array(np.arange(e * n, (e + 1) * n)), "task_index": pa.array(np.full(n, e % 2))})
        (dst / "data" / "chunk-000").mkdir(parents=True, exist_ok=True)
        pq.write_table(table, dst / "data" / "chunk-000" / f"episode_{e:06d}.parquet")
        video = dst / "videos" / "chunk-000" / "observation.images.front" / f"episode_{e:06d}.mp4"
        video.parent.mkdir(parents=True, exist_ok=True)
        with av.open(str(video), "w") as c:
            s = c.add_stream("libx264" if "libx264" in av.codecs_available else "mpeg4", fps,
                             options={"crf": "10"} if "libx264" in av.codecs_available else {})
            s.width, s.height, s.pix_fmt = 48, 32, "yuv420p"
            for f in given[f"rgb_front_{e}"]:
                c.mux(s.encode(av.VideoFrame.from_ndarray(f, format="rgb24")))
            c.mux(s.encode())
    (dst / "meta" / "episodes.jsonl").write_text("".join(json.dumps(x) + "\n" for x in episodes))
    (dst / "meta" / "episodes_stats.jsonl").write_text("".join(json.dumps(x) + "\n" for x in stats))


CONVERT = ("import sys; from lerobot.datasets.v30.convert_dataset_v21_to_v30 import convert_dataset; "
           "convert_dataset(sys.argv[1], root=sys.argv[2], push_to_hub=False, force_conversion=True)")


def test_the_v21_layout_imports_as_lerobots_own_conversion_of_it_to_v30(lerobot_written, tmp_path):
    _, given = lerobot_written
    _write_v21(tmp_path / "lerobot" / "old", given)
    res = _import(tmp_path, tmp_path / "lerobot" / "old", "name=old")
    assert res.returncode == 0, res.stderr[-2000:]
    old = _episodes(tmp_path / "store", "old")
    assert [e.seed for e in old] == list(range(SPEC["episodes"]))
    for e, ep in enumerate(old):
        np.testing.assert_array_equal(ep.action, given[f"action_{e}"])
        np.testing.assert_array_equal(ep.state, given[f"state_{e}"])
        assert _psnr(ep.rgb["front"], given[f"rgb_front_{e}"]) >= MIN_PSNR_DB
        assert ep.description == TASKS[e % 2] and not ep.success_known  # no next.success, no reward: unknown
    # lerobot's converter (v2.1 -> v3.0, in place: the v2.1 folder moves to old_old) reads the layout written above;
    # its v3.0 output imports as the same episodes
    env = {**os.environ, "PYTHONPATH": str(STAND_INS), "HF_HUB_OFFLINE": "1"}
    res = subprocess.run([sys.executable, "-c", CONVERT, "old", str(tmp_path / "lerobot")], capture_output=True,
                         text=True, env=env, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    assert json.loads((tmp_path / "lerobot" / "old" / "meta" / "info.json").read_text())["codebase_version"] == "v3.0"
    res = _import(tmp_path, tmp_path / "lerobot" / "old", "name=converted")
    assert res.returncode == 0, res.stderr[-2000:]
    for ep, conv in zip(old, _episodes(tmp_path / "store", "converted"), strict=True):
        np.testing.assert_array_equal(conv.action, ep.action)
        np.testing.assert_array_equal(conv.state, ep.state)
        assert conv.description == ep.description and conv.seed == ep.seed
        assert np.abs(conv.rgb["front"].astype(int) - ep.rgb["front"]).mean() <= MAX_MEAN_ABS_BETWEEN_DECODERS


def _copy(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst)
    return dst


def _edit_info(root: Path, change) -> None:
    path = root / "meta" / "info.json"
    info = json.loads(path.read_text())
    change(info)
    path.write_text(json.dumps(info))


def test_bad_datasets_are_one_line_naming_the_file_or_feature(lerobot_written, tmp_path):
    root, _ = lerobot_written
    (tmp_path / "empty").mkdir()
    one_line_error(_import(tmp_path, tmp_path / "empty"), f"src={tmp_path / 'empty'}: ", "no meta/info.json",
                    "not a LeRobotDataset folder")
    old = _copy(root, tmp_path / "old")
    _edit_info(old, lambda i: i.update(codebase_version="v1.6"))
    one_line_error(_import(tmp_path, old), f"{old / 'meta' / 'info.json'}: codebase_version 'v1.6'",
                    "v2.1, v3.0")
    depth = _copy(root, tmp_path / "depth")
    _edit_info(depth, lambda i: [i["features"][k]["info"].update({"video.is_depth_map": True}) for k in
                                 ["observation.images.front"]] and i["features"].pop("observation.images.wrist"))
    one_line_error(_import(tmp_path, depth), "features: no RGB camera (observation.images.front: depth maps")
    cut = _copy(root, tmp_path / "cut_parquet")
    data = cut / "data" / "chunk-000" / "file-000.parquet"
    data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])
    one_line_error(_import(tmp_path, cut), f"{data}: not a readable parquet file")
    cut = _copy(root, tmp_path / "cut_mp4")
    video = cut / "videos" / "observation.images.front" / "chunk-000" / "file-000.mp4"
    video.write_bytes(video.read_bytes()[: video.stat().st_size // 2])
    one_line_error(_import(tmp_path, cut, store="store_cut"), f"{video}: ")
    # a second dataset under a name the store holds from the first is refused, not mixed into it
    other = _copy(root, tmp_path / "tabletop_v2" / "tabletop")
    assert _import(tmp_path, root, store="store_names").returncode == 0
    one_line_error(_import(tmp_path, other, store="store_names"), "name=tabletop: the store",
                   f"imported from {root.resolve()}", "give another name=")
    one_line_error(_import(tmp_path, root, "name=../evil"), "name=../evil: letters, digits")
    one_line_error(_import(tmp_path, cut, store="store_cut"), "episodes written", "the same command resumes")
    gone = _copy(root, tmp_path / "no_camera_file")
    missing = gone / "videos" / "observation.images.front" / "chunk-000" / "file-000.mp4"
    missing.unlink()
    one_line_error(_import(tmp_path, gone, store="store_gone"), f"{missing}: missing")


def test_a_killed_import_resumes_to_the_store_an_uninterrupted_one_writes(tmp_path):
    import hashlib

    spec = {**SPEC, "episodes": 24, "frames": 30, "height": 64, "width": 64, "cameras": {"front": "video"}}
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    _lerobot("write", str(tmp_path / "big"), str(tmp_path / "spec.json"))
    whole = _import(tmp_path, tmp_path / "big", store="whole")
    assert whole.returncode == 0, whole.stderr[-2000:]
    args = [sys.executable, str(ROOT / "src" / "import_data.py"), "format=lerobot", f"src={tmp_path / 'big'}",
            f"store={tmp_path / 'killed'}", f"hydra.run.dir={tmp_path / 'run_killed'}"]
    proc = subprocess.Popen(args, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while time.time() < deadline and len(list((tmp_path / "killed").glob("*/*/episode_*.h5"))) < 3:
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    done = len(list((tmp_path / "killed").glob("*/*/episode_*.h5")))
    assert 3 <= done < spec["episodes"], f"{done} episodes when killed: make the dataset larger"
    res = subprocess.run(args, cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-2000:]
    assert json.loads((tmp_path / "run_killed" / "result.json").read_text())["values"]["skipped"] >= done

    def digests(store: Path) -> dict:
        return {str(p.relative_to(store)): hashlib.md5(p.read_bytes()).hexdigest()
                for p in sorted(store.glob("*/*/episode_*.h5"))}

    assert digests(tmp_path / "killed") == digests(tmp_path / "whole") and len(digests(tmp_path / "whole")) == 24


def test_export_mistakes_are_one_line(lerobot_written, tmp_path):
    root, _ = lerobot_written
    assert _import(tmp_path, root, "name=mine").returncode == 0

    def export(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, str(ROOT / "src" / "export_data.py"),
                               f"episodes.store={tmp_path / 'store'}", f"hydra.run.dir={tmp_path / 'ex'}", *args],
                              cwd=ROOT, capture_output=True, text=True)

    one_line_error(export(f"out={tmp_path / 'x'}"), "episodes.pipeline is not set")
    one_line_error(export("episodes.pipeline=yours", f"out={tmp_path / 'x'}"), "episodes.pipeline=yours",
                   "(it holds mine)")
    one_line_error(export("episodes.pipeline=mine", f"out={tmp_path / 'x'}", "episodes.group=drawer"),
                   "episodes.group=drawer: pipeline mine has no such group (it has all)")
    one_line_error(export("episodes.pipeline=mine"), "out is not set")
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "notes.txt").write_text("mine")
    one_line_error(export("episodes.pipeline=mine", f"out={tmp_path / 'taken'}"), "exists and is not empty",
                   "overwrite=true")
    one_line_error(export("episodes.pipeline=mine", f"out={tmp_path / 'y'}", "format=rlds"),
                   "format='rlds': expected lerobot")
    one_line_error(export("episodes.pipeline=mine", f"out={tmp_path / 'taken' / 'notes.txt'}"), "is a file")
    for fps in ("abc", "-3", "0"):
        one_line_error(export("episodes.pipeline=mine", f"out={tmp_path / 'z'}", f"fps={fps}"), "fps=")
    assert (tmp_path / "taken" / "notes.txt").read_text() == "mine"
    # frames too narrow for the encoder: it died of SIGFPE (exit -8, nothing printed), now one line
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    write_group(tmp_path / "store", "diverse", n_tasks=1, episodes=1, n_actions=4, size=16, pipeline="small")
    one_line_error(export("episodes.pipeline=small", f"out={tmp_path / 'small'}", "fps=10"), "frames of 16x16",
                   "needs at least 4 rows and 26 columns")
    assert not (tmp_path / "small").exists()
