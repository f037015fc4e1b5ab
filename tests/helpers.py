"""Helpers several test files share (task bundles, a quality run against a server, a policy config, W&B run files,
Ravens demos); fixtures live in conftest.py. Test files import from here, never from each other."""

from __future__ import annotations

import os
import pickle
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

from simeval.episodes.episode import Episode
from simeval.judges.providers import Image
from simeval.models.diffusion_policy import PolicyConfig

ROOT = Path(__file__).resolve().parents[1]
FAKE_KEY = "sk-test-0123456789abcdefghijklmnop"  # the key quality runs against a test server get
SECRET = "sk-test-SECRET123"  # the key W&B runs get: it must appear in none of their files


def _png(seed: int, size: int = 16) -> bytes:
    return Image.from_array(np.random.default_rng(seed).integers(0, 255, (size, size, 3))).png


def make_bundles(root: Path, n: int = 3, corrupt: str | None = None, video: str | None = None) -> Path:
    for t in range(n):
        d = root / f"task{t}"
        (d / "scene").mkdir(parents=True)
        (d / "frames").mkdir()
        (d / "task.yaml").write_text(yaml.safe_dump({"description": f"stack block {t} on the pallet",
                                                     "pipeline": "gensim", "ground_truth": {"progress": min(t / 2, 1.0)}}))
        for v in range(4):
            (d / "scene" / f"view{v}.png").write_bytes(_png(100 * t + v))
        for f in range(12):
            (d / "frames" / f"{f:04d}.png").write_bytes(_png(1000 * t + f))
    if corrupt:
        (root / corrupt / "scene" / "view0.png").write_bytes(b"not a png")
    if video:
        import imageio.v3 as iio

        d = root / video
        for f in (d / "frames").glob("*.png"):
            f.unlink()
        (d / "frames").rmdir()
        iio.imwrite(d / "trajectory.mp4", np.random.default_rng(0).integers(0, 255, (20, 32, 32, 3), dtype=np.uint8),
                    fps=10, codec="libx264")
    return root


def _bundles(root: Path) -> Path:
    d = root / "task0"
    (d / "scene").mkdir(parents=True)
    (d / "frames").mkdir()
    (d / "task.yaml").write_text(yaml.safe_dump({"description": "stack the block", "pipeline": "gensim"}))
    png = Image.from_array(np.zeros((8, 8, 3))).png
    (d / "scene" / "v0.png").write_bytes(png)
    for f in range(2):
        (d / "frames" / f"{f}.png").write_bytes(png)
    return root


def run_quality(tmp: Path, *args: str, flags: tuple = ()) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "src" / "quality.py"), *flags,
                           f"bundles_dir={_bundles(tmp / 'b')}",
                           f"cache_dir={tmp / 'cache'}", f"hydra.run.dir={tmp / 'run'}", "repeats=1", *args],
                          cwd=ROOT, env={**os.environ, "OPENAI_API_KEY": FAKE_KEY},
                          capture_output=True, text=True, timeout=300)


def _error_line(res: subprocess.CompletedProcess) -> str:
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr[-3000:]
    lines = [x for x in res.stderr.splitlines() if x.startswith("error: ")]
    assert len(lines) == 1, res.stderr[-3000:]
    return lines[0]


def policy_config() -> PolicyConfig:
    model = yaml.safe_load((ROOT / "conf" / "policy" / "tiny.yaml").read_text())["model"]
    return PolicyConfig.from_mapping({**model, "action_space": "joint"})


def square_episode(T: int = 16) -> Episode:
    """A square crossing a 32x32 frame while the action traces a circle: something for a policy to fit."""
    rgb = np.zeros((T, 32, 32, 3), np.uint8)
    for t in range(T):
        rgb[t, 10:18, 2 + t : 8 + t] = (255, 200, 50)
    ph = np.linspace(0, 1, T, dtype=np.float32)
    return Episode(pipeline="p", task="t", description="", group="g", seed=0, rgb={"top": rgb},
                   state=np.stack([ph, ph**2], 1), action=np.stack([np.sin(6 * ph), np.cos(6 * ph)], 1),
                   reward=np.zeros(T, np.float32), is_first=np.arange(T) == 0, is_terminal=np.arange(T) == T - 1)


def wandb_records(path: Path) -> list:
    """Every protobuf Record of an offline run file. The format is W&B's LevelDB-style log (a 7-byte `:W&B` header,
    then 32 KiB blocks of chunks with a 7-byte header: crc32, length, type FULL/FIRST/MIDDLE/LAST); wandb 0.31
    ships no Python reader for it any more."""
    from wandb.proto import wandb_internal_pb2 as pb

    data = path.read_bytes()
    assert data[:4] == b":W&B"
    pos, block, chunks, pending = 7, 32768, [], b""
    while pos + 7 <= len(data):
        if block - pos % block < 7:  # a block's tail too short for a header is padding
            pos += block - pos % block
            continue
        _crc, length, kind = struct.unpack("<IHB", data[pos:pos + 7])
        if kind == 0:  # zero-filled padding up to the next block
            pos += block - pos % block
            continue
        chunk, pos = data[pos + 7:pos + 7 + length], pos + 7 + length
        if kind == 1:
            chunks.append(chunk)
        elif kind == 2:
            pending = chunk
        elif kind == 3:
            pending += chunk
        elif kind == 4:
            chunks.append(pending + chunk)
    records = []
    for c in chunks:
        r = pb.Record()
        r.ParseFromString(c)
        records.append(r)
    return records


def _run(script: str, *args: str, env: dict, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "src" / script), *args, "logger=wandb"], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


def _no_secret_anywhere(root: Path) -> None:
    files = [p for p in root.rglob("*") if p.is_file()]
    assert any(p.suffix == ".wandb" for p in files)
    leaked = [str(p) for p in files if SECRET.encode() in p.read_bytes()]
    assert not leaked, leaked


def _write_ravens(root: Path, task="stack-block-pyramid", mode="train", episodes=2, t=3):
    d = root / f"{task}-{mode}"
    rng = np.random.default_rng(0)
    for e in range(episodes):
        seed = 100 + e
        name = f"{e:06d}-{seed}.pkl"
        color = rng.integers(0, 255, (t + 1, 3, 24, 32, 3), dtype=np.uint8)
        action = [{"pose0": ((0.1, 0.2, 0.0), (0, 0, 0, 1)), "pose1": ((0.3, 0.4, 0.05), (0, 0, 0.7, 0.7))}] * t + [None]
        reward = [0.0] + [1.0 / t] * t
        info = [{"lang_goal": "stack the blocks into a pyramid"}] * (t + 1)
        for key, value in (("color", color), ("depth", np.zeros((t + 1, 3, 24, 32), np.float32)), ("action", action),
                           ("reward", reward), ("info", info)):
            (d / key).mkdir(parents=True, exist_ok=True)
            with (d / key / name).open("wb") as f:
                pickle.dump(value, f)
    return d


def load_script(path: Path, name: str | None = None):
    """A script (a file run by another interpreter, e.g. GenSim's worker) loaded as a module from its file, without
    putting its folder on sys.path; registered in sys.modules under `name` (default: its stem) while it loads, as a
    module's dataclasses need, and removed again after."""
    import importlib.util

    name = name or path.stem
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    finally:
        sys.modules.pop(name, None)
    return module


GROUP = "piles"  # the smallest group of the GenSim-style suite (3 tasks): synthetic_store's


def synthetic_store(root, per_task: int = 3, T: int = 30) -> Path:
    """Episodes of GROUP's tasks with random frames and smooth joint actions, for src/generalization.py and
    `src/generalization_tools.py offline`: enough to train and to check the plumbing (not to learn a task)."""
    from simeval.episodes.store import EpisodeStore
    from simeval.sim.action_spaces import joint_action_space
    from simeval.sim.tasks.spec import suite_dir, load_suite, select_specs

    store = EpisodeStore(root)
    for spec in select_specs(load_suite(suite_dir("gensim")), None, GROUP):
        for seed in range(per_task):
            r = np.random.default_rng(seed)
            store.write(Episode(
                pipeline="gensim", task=spec.name, description="d", group=spec.group, seed=seed,
                rgb={"top": r.integers(0, 255, (T, 32, 32, 3), dtype=np.uint8)},
                state=r.normal(size=(T, 12)).astype(np.float32),
                action=np.cumsum(r.normal(size=(T, 7)), 0).astype(np.float32), reward=np.zeros(T, np.float32),
                is_first=np.arange(T) == 0, is_terminal=np.arange(T) == T - 1, progress=np.zeros(T, np.float32),
                action_space=joint_action_space(30.0)))  # every stored episode declares its action space
    return root


class ConstantImageModel:
    """A stand-in world model whose every decoded frame is one constant image `frame` (H, W, 3) in [0, 1] (the
    prior, the posterior and the imagination all decode to it), for what simeval.measures.dynamics_diversity.prediction
    scores."""

    def __init__(self, frame) -> None:
        self.frame = frame
        self.rssm = self

    @staticmethod
    def _images(batch):
        return batch["image"].float() / 255

    def embed(self, image, state):
        return image

    def observe(self, embed, prev_action, is_first, generator=None):
        return embed, embed

    @staticmethod
    def features(state):
        return state

    def image_decoder(self, features):
        return self.frame.expand_as(features)


def one_line_error(res: subprocess.CompletedProcess, *expected: str) -> None:
    """An entrypoint's user error: exit status 2 and one line `error: ...` holding each of `expected` (progress
    bars before it, which show how far the run got, are not counted)."""
    import re

    assert res.returncode == 2, res.stderr[-2000:]
    # a bar's rate ends "episode/s]", or "s/episode]" where an item takes over a second (a loaded machine)
    lines = [x for x in res.stderr.strip().splitlines() if not re.search(r"(?:(it|episode)/s|s/(it|episode))\]$", x)]
    assert "Traceback" not in res.stderr and len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    for text in expected:
        assert text in lines[0], lines[0]
