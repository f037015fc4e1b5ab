"""GenSim's own task as a Gymnasium environment with GenSim's pick/place action (the abstraction the authors' policy
used): one step = one 14-d pick/place pose pair through GenSim's `env.step`, observed as simeval's environments
are (`obs["rgb"][camera]` at `image_size`, `obs["state"]` 14-d; `info["success"]` = GenSim's total reward >= 0.99,
`info["progress"]` = the total reward), so simeval's policies and rollouts take it like `simeval.sim.make_env`.

GenSim runs in a worker process (worker.py --serve: one Environment for the env's life, episodes started as
cliport/demos.py starts them); commands and replies travel over its stdin and stdout. `oracle_action()` is GenSim's
own oracle's next action from the same state (for tests and for scripted baselines)."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import ClassVar

import gymnasium as gym
import numpy as np

from simeval.pipelines.gensim_own.native import (
    CAMERAS,
    WORKER,
    EpisodeFailed,
    GensimSettings,
    worker_environment,
    worker_request,
)
from simeval.sim.action_spaces import POSE_HIGH, POSE_LOW

log = logging.getLogger(__name__)


class GensimEnv(gym.Env):
    metadata: ClassVar[dict] = {"render_modes": []}

    def __init__(self, task: str, settings: GensimSettings, image_size: Sequence[int] = (64, 64),
                 cameras: Sequence[str] = CAMERAS, max_steps: int | None = None) -> None:
        self.task, self.settings, self.cameras = task, settings, tuple(cameras)
        self.image_size = (int(image_size[0]), int(image_size[1]))
        self.max_steps = max_steps  # a cap below GenSim's task.max_steps (which always holds, as in demos.py)
        h, w = self.image_size
        self.observation_space = gym.spaces.Dict({
            "rgb": gym.spaces.Dict({c: gym.spaces.Box(0, 255, (h, w, 3), np.uint8) for c in self.cameras}),
            "state": gym.spaces.Box(-np.inf, np.inf, (14,), np.float32)})
        self.action_space = gym.spaces.Box(POSE_LOW, POSE_HIGH, dtype=np.float32)
        self._proc = None
        self._seed = 0
        self._steps = 0

    # --- the worker ------------------------------------------------------------------------------------------
    def _start(self) -> None:
        from multiprocessing.connection import Connection

        self._scratch = tempfile.mkdtemp(prefix="simeval-gensim-env-")
        req = worker_request(self.settings, self.task, self.image_size, self.cameras)
        path = Path(self._scratch) / "request.json"
        path.write_text(json.dumps(req))
        self._stderr = open(Path(self._scratch) / "stderr.txt", "w+")  # noqa: SIM115  (closed in close())
        self._proc = subprocess.Popen([self.settings.python or sys.executable, str(WORKER), "--serve", str(path)],
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr,
                                      env=worker_environment())
        self._send = Connection(os.dup(self._proc.stdin.fileno()), readable=False)
        self._recv = Connection(os.dup(self._proc.stdout.fileno()), writable=False)

    def _call(self, *command, timeout: float | None = None):
        if self._proc is None:
            self._start()
        try:
            self._send.send(command)
            if timeout is not None and not self._recv.poll(timeout):
                self._stop_worker()
                raise EpisodeFailed(self.task, self._seed, f"one step ran past {timeout:g} s "
                                    "(pipeline.native.step_timeout_s): GenSim's primitive did not return, its worker "
                                    "was stopped")
            reply = self._recv.recv()
        except (EOFError, BrokenPipeError, OSError):
            self._proc.wait(timeout=30)
            self._stderr.seek(0)
            last = (self._stderr.read().strip().splitlines() or [""])[-1]
            try:
                said = json.loads(last)
            except json.JSONDecodeError:
                said = {"error": f"the GenSim worker exited with status {self._proc.returncode}: {last}"}
            self.close()
            raise EpisodeFailed(self.task, self._seed, said.get("error", "?"), said.get("where", ""),
                                unusable=True) from None
        if reply[0] == "error":
            raise EpisodeFailed(self.task, self._seed, reply[1], reply[2])
        return reply[1:]

    # --- gymnasium -------------------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._seed = int(seed) if seed is not None else self._seed + 1
        self._steps = 0
        obs, info = self._call("reset", self._seed)
        self._last_obs, self._last_info = self._obs(obs), {"progress": 0.0, **info}
        return self._last_obs, info

    def step(self, action):
        action = np.clip(np.asarray(action, np.float32).reshape(14), POSE_LOW, POSE_HIGH)
        self._steps += 1
        try:
            obs, reward, done, info = self._call("step", action.tolist(), timeout=self.settings.step_timeout_s)
        except EpisodeFailed as e:
            # GenSim raised, hung or died inside one primitive: the rollout ends there, failed (as GenSim ends one
            # whose primitive times out), with the error in info; the next reset starts a fresh worker if needed
            log.warning("%s seed %d, step %d: %s%s", self.task, self._seed, self._steps, e.error,
                        f" ({e.where})" if e.where else "")
            info = {**self._last_info, "success": False, "error": e.error}
            return self._last_obs, 0.0, True, False, info
        terminated = bool(info["success"] or done)
        limits = [m for m in (self.max_steps, info.get("max_steps")) if m is not None]  # GenSim's cap holds too
        truncated = bool(not terminated and limits and self._steps >= min(limits))
        self._last_obs, self._last_info = self._obs(obs), info
        return self._last_obs, reward, terminated, truncated, info

    def oracle_action(self) -> np.ndarray | None:
        """GenSim's oracle's next pick/place from the current state (None: it has nothing left to do)."""
        (action,) = self._call("oracle")
        return None if action is None else np.asarray(action, np.float32)

    def _stop_worker(self) -> None:
        self._proc.kill()
        self._proc.wait()
        self.close()

    def close(self) -> None:
        if self._proc is not None:
            try:
                if self._proc.poll() is None:
                    self._send.send(("close",))
                self._proc.wait(timeout=30)
            except (OSError, subprocess.TimeoutExpired):
                self._proc.kill()
            for conn in (self._send, self._recv):
                conn.close()
            for pipe in (self._proc.stdin, self._proc.stdout):
                pipe.close()
            self._stderr.close()
            self._proc = None
            import shutil

            shutil.rmtree(self._scratch, ignore_errors=True)

    def _obs(self, obs: dict) -> dict:
        return {"rgb": {c: obs["rgb"][c] for c in self.cameras}, "state": obs["state"]}
