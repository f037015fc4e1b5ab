"""lerobot 0.4.4's own LeRobotDataset, run as a script by tests/test_lerobot.py (with tests/stand_ins first on
PYTHONPATH, for the torchvision stand-in), so the tests compare simeval's reader and writer with lerobot's.

    python lerobot_io.py write ROOT SPEC.json   # LeRobotDataset.create / add_frame / save_episode / finalize; the
                                                # frames, states and actions it was given go to ROOT.given.npz
    python lerobot_io.py read ROOT OUT.npz      # LeRobotDataset(root=ROOT)[i] for every i, as arrays
    python lerobot_io.py time ROOT              # seconds to load the dataset and to read every item (JSON)
"""

import json
import sys

import numpy as np


def frames_of(spec: dict, episode: int, camera: int) -> np.ndarray:
    """(T, H, W, 3) uint8: a bright square moving over a gradient, different per episode and camera."""
    t, h, w = spec["frames"], spec["height"], spec["width"]
    img = np.zeros((t, h, w, 3), np.uint8)
    img[..., 0] = np.linspace(0, 200, w, dtype=np.uint8)[None, None, :]
    img[..., 1] = (40 * camera + 10 * episode) % 256
    for i in range(t):
        y, x = (2 * i + episode) % (h - 6), (3 * i + 5 * camera) % (w - 6)
        img[i, y : y + 6, x : x + 6] = 255
    return img


def write(root: str, spec_path: str) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    spec = json.loads(open(spec_path).read())
    rng = np.random.default_rng(spec.get("seed", 0))
    cams = spec["cameras"]  # {name: "video" | "image"}
    features = {f"observation.images.{c}": {"dtype": kind, "shape": (spec["height"], spec["width"], 3),
                                            "names": ["height", "width", "channels"]} for c, kind in cams.items()}
    features["observation.state"] = {"dtype": "float32", "shape": (spec["state"],),
                                     "names": [f"joint{i}" for i in range(spec["state"])]}
    features["action"] = {"dtype": "float32", "shape": (spec["action"],),
                          "names": [f"a{i}" for i in range(spec["action"])]}
    if spec.get("success"):
        features["next.success"] = {"dtype": "bool", "shape": (1,), "names": None}
    if spec.get("reward"):
        features["next.reward"] = {"dtype": "float32", "shape": (1,), "names": None}
    ds = LeRobotDataset.create("local/simeval_test", fps=spec["fps"], features=features, root=root,
                               robot_type=spec.get("robot_type", "test_arm"),
                               use_videos=any(k == "video" for k in cams.values()), image_writer_threads=0)
    given = {}
    for e in range(spec["episodes"]):
        state = rng.normal(size=(spec["frames"], spec["state"])).astype(np.float32)
        action = rng.normal(size=(spec["frames"], spec["action"])).astype(np.float32)
        images = {c: frames_of(spec, e, k) for k, c in enumerate(cams)}
        for t in range(spec["frames"]):
            frame = {f"observation.images.{c}": images[c][t] for c in cams}
            frame.update({"observation.state": state[t], "action": action[t],
                          "task": spec["tasks"][e % len(spec["tasks"])]})
            if spec.get("success"):
                frame["next.success"] = np.array([t == spec["frames"] - 1 and e % 2 == 0])
            if spec.get("reward"):
                frame["next.reward"] = np.array([float(t == spec["frames"] - 1 and e % 2 == 0)], np.float32)
            ds.add_frame(frame)
        ds.save_episode()
        given.update({f"state_{e}": state, f"action_{e}": action,
                      **{f"rgb_{c}_{e}": images[c] for c in cams}})
    ds.finalize()
    np.savez(root.rstrip("/") + ".given.npz", **given)


def read(root: str, out: str) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset("local/simeval_test", root=root, video_backend="torchcodec")
    items = [ds[i] for i in range(len(ds))]
    arrays = {"episode_index": np.array([int(x["episode_index"]) for x in items]),
              "frame_index": np.array([int(x["frame_index"]) for x in items]),
              "tasks": np.array([x["task"] for x in items]),
              "fps": np.array(ds.fps), "num_episodes": np.array(ds.num_episodes)}
    for key in items[0]:
        v = items[0][key]
        if hasattr(v, "numpy") and key not in arrays:
            stacked = np.stack([x[key].numpy() for x in items])
            if key.startswith("observation.images."):  # lerobot gives (3, H, W) floats in [0, 1]
                stacked = np.round(stacked.transpose(0, 2, 3, 1) * 255).astype(np.uint8)
            arrays[key] = stacked
    np.savez(out, **arrays)


def time_reading(root: str) -> None:
    import time

    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    t0 = time.perf_counter()
    ds = LeRobotDataset("local/simeval_test", root=root, video_backend="torchcodec")
    t1 = time.perf_counter()
    for i in range(len(ds)):
        ds[i]
    t2 = time.perf_counter()
    print(json.dumps({"frames": len(ds), "load_s": t1 - t0, "read_s": t2 - t1}))


if __name__ == "__main__":
    {"write": write, "read": read, "time": time_reading}[sys.argv[1]](*sys.argv[2:])
