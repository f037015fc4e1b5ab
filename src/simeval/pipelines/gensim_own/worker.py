"""Record one episode of a GenSim task with GenSim's own code: its task class, its `Environment` and its oracle agent
(`task.oracle(env)`), run as the authors ran them (cliport/demos.py: seeds `np.random.seed`, `random.seed`; the
oracle's pick/place poses through `env.step`), with the PyBullet loop at `hz` and one frame every `frame_every`
physics steps.

Run as a separate process (simeval.pipelines.gensim_own.native starts it): GenSim drives PyBullet's one global client,
imports its whole learning stack at package level and prints freely; none of that reaches simeval's process. This
file needs only numpy and GenSim's own imports, so any interpreter that can run GenSim can run it:

    python worker.py REQUEST.json          # writes REQUEST's `out` (.npz) and `out` + .json, or exits non-zero
    python worker.py --serve REQUEST.json  # closed loop: commands on stdin, replies on stdout (see `serve`)

Exit status: 0 recorded; 3 GenSim's code raised (one JSON line on stderr: {"error": ..., "where": ...}); 4 the
checkout or GenSim's imports are unusable (same JSON line). Nothing in the checkout is written: no bytecode files.

Two things are done to load GenSim without changing it, and each is visible in the episode's `extra`:
- `cliport` is loaded as a bare package: its `__init__.py` imports agents and models (pytorch_lightning, timm,
  transformers), which recording never uses; every module recording does use is imported for real.
- `torchvision` is given a stand-in module only when none is installed: `cliport/utils/utils.py` imports it at
  module level and uses it nowhere (one reference, in a comment). Any attribute of the stand-in raises
  ImportError, so a real use cannot pass silently.

Convention of the recorded rows (the store's: row 0 is the reset observation, action t leads to row t + 1): a row
every `frame_every` physics steps after `env.reset()`, during the joint moves and the settling after each
primitive alike. Action t is the UR5's joint position target commanded last in those physics steps (GenSim's
`movej` commands a new target every physics step, 0.01 rad further towards the goal, so 1 in `frame_every` of
them is stored: an exact replay from the stored actions is impossible, see the README) and the suction state at
row t + 1. A partial block of fewer than `frame_every` physics steps at the end is not stored. A row holds the UR5's
joints and suction (state), the poses of the task's rigid bodies (object_poses: position and xyzw quaternion, in the
order the task added them) and one frame per requested camera; with no camera requested (`record.cameras=[]`)
nothing is rendered but GenSim's own observations, and the rows are the same to the bit (the renderer does not step
the physics): a state-only collection, ~3x faster."""

from __future__ import annotations

import importlib.util
import json
import os
import random
import sys
import time
import traceback
import types

EXIT_TASK_RAISED, EXIT_UNUSABLE = 3, 4


class _StandIn(types.ModuleType):
    """What `import torchvision` gives when torchvision is not installed; every attribute use fails loudly."""

    def __getattr__(self, name: str):
        if name.startswith("__") and name.endswith("__"):
            raise AttributeError(name)
        raise ImportError(f"torchvision.{name}: torchvision is not installed, only a stand-in for GenSim's unused "
                          "module-level import; install a torchvision built for this torch to use it")


def load_gensim(root: str) -> dict:
    """Import GenSim's task registry and Environment from `root`; returns what was stood in for."""
    sys.dont_write_bytecode = True  # importing must not write __pycache__ into the user's checkout
    package = os.path.join(root, "cliport")
    if not os.path.isfile(os.path.join(package, "environments", "environment.py")):
        raise FileNotFoundError(f"{root} is not a GenSim checkout: cliport/environments/environment.py not found")
    stood_in = []
    if "cliport" not in sys.modules:
        bare = types.ModuleType("cliport")
        bare.__path__ = [package]
        sys.modules["cliport"] = bare
        stood_in.append("cliport/__init__.py (agents, models)")
    if importlib.util.find_spec("torchvision") is None:
        sys.modules["torchvision"] = _StandIn("torchvision")
        stood_in.append("torchvision")
    from cliport import tasks  # noqa: F401  (registry: template and generated tasks)
    from cliport.environments import environment  # noqa: F401
    return {"stood_in": stood_in}


class _TargetSpy:
    """Stands in for the `pybullet` module inside GenSim's environment module only: every call goes to pybullet,
    and the joint targets GenSim commands to the arm are remembered (PyBullet cannot report a motor's target)."""

    def __init__(self, pybullet, arm_of):
        self._p, self._arm_of, self.target = pybullet, arm_of, None

    def __getattr__(self, name):
        return getattr(self._p, name)

    def setJointMotorControlArray(self, *args, **kwargs):
        body = kwargs.get("bodyIndex", args[0] if args else None)
        if body == self._arm_of() and "targetPositions" in kwargs:
            self.target = [float(x) for x in kwargs["targetPositions"]]
        return self._p.setJointMotorControlArray(*args, **kwargs)


class _SimulatedClock:
    """Stands in for the `time` module inside GenSim's environment module only (clock="simulated"): `time()` is the
    physics steps taken so far over `hz`. GenSim's joint moves and its settling loop stop after 5 s of wall-clock
    time; on a loaded machine (or while frames are rendered inside the loop) that cut moves short and failed
    episodes that succeed on an idle one. On this clock the same limits are 5 s of simulated time (1200 steps at
    240 Hz), so an episode is the same on any machine under any load."""

    def __init__(self, hz: int) -> None:
        self.hz, self.steps = hz, 0

    def time(self) -> float:
        return self.steps / self.hz

    def __getattr__(self, name):
        return getattr(time, name)


def _camera(config: dict, size: tuple[int, int]) -> dict:
    """GenSim's camera config rendered at `size` with its field of view kept: GenSim's render_camera derives the
    field of view from the image height and a focal length in pixels, so the focal length scales with the height."""
    h0 = config["image_size"][0]
    fx, _, cx, _, fy, cy, *rest = config["intrinsics"]
    s = size[0] / h0
    return dict(config, image_size=tuple(size), intrinsics=(fx * s, 0, cx * s, 0, fy * s, cy * s, *rest))


def draw_unseen_colors() -> None:
    """GenSim's utils.get_colors_names returns its TRAIN_COLORS whatever the mode; replaced in this process by the
    rule its two colour sets were made for (TRAIN_COLORS in train mode, EVAL_COLORS in val and test), so a task that
    passes its mode to utils.get_colors draws unseen colours outside train mode. The checkout's file is untouched."""
    from cliport.utils import utils

    def get_colors_names(mode):
        return utils.TRAIN_COLORS if mode == "train" else utils.EVAL_COLORS

    utils.get_colors_names = get_colors_names


class Session:
    """One GenSim task in one Environment, hooked for recording: `reset(seed)` as cliport/demos.py starts an
    episode, `primitive(action)` runs one pick/place through `env.step`, `observe()` renders the cameras at the
    requested size. While `recording`, a row (action, then observation) is kept every `frame_every` physics steps."""

    def __init__(self, req: dict) -> None:
        import pybullet
        from cliport import tasks
        from cliport.environments import environment
        from cliport.tasks import cameras as gensim_cameras

        if req["task"] not in tasks.names:
            raise KeyError(f"GenSim has no task {req['task']!r} in its registry (cliport/tasks/__init__.py `names` "
                           "and cliport/generated_tasks)")
        self.req, self.p = req, pybullet
        views = {"front": gensim_cameras.RealSenseD415.CONFIG[0], "top": gensim_cameras.Oracle.CONFIG[0]}
        self.cams = {c: _camera(views[c], tuple(req["image_size"])) for c in req["cameras"]}
        self.task = tasks.names[req["task"]]()
        self.task.mode = req.get("mode", "train")
        if req.get("unseen_colors"):
            draw_unseen_colors()
        assets = os.path.join(req["root"], "cliport", "environments", "assets")
        self.env = env = environment.Environment(assets, disp=False, hz=int(req["hz"]),
                                                 record_cfg={"save_video": False, "blender_render": False})
        self.spy = _TargetSpy(pybullet, lambda: getattr(env, "ur5", None))
        environment.p = self.spy
        self.clock = _SimulatedClock(int(req["hz"]))
        if req.get("clock", "simulated") == "simulated":
            environment.time = self.clock
        self.movej_timeouts, self.recording, self.physics_steps = 0, False, 0
        self.rows: dict[str, list] = {}
        original_movej, original_step = env.movej, env.step_simulation

        def movej(*args, **kwargs):
            timed_out = original_movej(*args, **kwargs)
            self.movej_timeouts += bool(timed_out)
            return timed_out

        def stepped() -> None:
            original_step()
            self.clock.steps += 1
            if self.recording:
                self.physics_steps += 1
                if self.physics_steps % int(req["frame_every"]) == 0:
                    self._keep_action()
                    self._keep(self.observe())

        env.movej, env.step_simulation = movej, stepped

    def reset(self, seed: int):
        import numpy as np

        np.random.seed(seed)  # as cliport/demos.py seeds an episode, just before env.reset
        random.seed(seed)
        self.env.seed(seed)
        self.env.set_task(self.task)
        obs = self.env.reset()
        self.agent = self.task.oracle(self.env)
        self.total_reward, self.done, self.primitives, self.physics_steps = 0.0, False, 0, 0
        self.movej_timeouts = 0
        self.rows = {"state": [], "object_poses": [], "action": [], "progress": [],
                     **{f"{k}/{c}": [] for c in self.cams for k in ("rgb", "robot_mask")}}
        return obs, self.env.info

    def observe(self) -> dict:
        import numpy as np

        env, p = self.env, self.p
        q = [p.getJointState(env.ur5, j) for j in env.joints]
        suction = float(bool(getattr(env.ee, "activated", False)))
        holding = float(bool(env.ee.check_grasp())) if hasattr(env.ee, "check_grasp") else 0.0
        robot = [env.ur5, getattr(env.ee, "base", -1), getattr(env.ee, "body", -1)]
        # the movable objects' poses (GenSim's "rigid" bodies, in the order the task added them): what the state
        # reading needs beside the arm; its "fixed" bodies (zones, pallets, stands) never move
        poses = [[*pos, *orn] for b in env.obj_ids.get("rigid", [])
                 for pos, orn in (p.getBasePositionAndOrientation(b),)]
        out = {"state": np.asarray([s[0] for s in q] + [s[1] for s in q] + [suction, holding], np.float32),
               "object_poses": np.asarray(poses, np.float32).reshape(-1, 7), "rgb": {}, "robot_mask": {}}
        for c, config in self.cams.items():
            color, _, segm = env.render_camera(config)
            out["rgb"][c] = np.asarray(color, np.uint8)
            out["robot_mask"][c] = np.isin(segm, robot)
        return out

    def _keep(self, obs: dict) -> None:
        self.rows["state"].append(obs["state"])
        self.rows["object_poses"].append(obs["object_poses"])
        for c in self.cams:
            self.rows[f"rgb/{c}"].append(obs["rgb"][c])
            self.rows[f"robot_mask/{c}"].append(obs["robot_mask"][c])
        self.rows["progress"].append(self.total_reward)

    def _keep_action(self) -> None:
        target = self.spy.target if self.spy.target is not None else [float(x) for x in self.env.homej]
        self.rows["action"].append(target + [float(bool(getattr(self.env.ee, "activated", False)))])

    def primitive(self, action: dict):
        """One pick/place ({pose0: (xyz, xyzw), pose1: ...}) through GenSim's env.step."""
        obs, reward, done, info = self.env.step(action)
        self.primitives += 1
        self.total_reward += float(reward)
        self.done = bool(done)
        if self.recording and self.rows["progress"]:
            self.rows["progress"][-1] = self.total_reward  # GenSim scores a primitive once it settles: the last row
        return obs, float(reward), bool(done), info


def record(req: dict) -> dict:
    """Record the episode `req` asks for with GenSim's oracle; returns the arrays and the metadata (see the module
    docstring)."""
    import numpy as np

    session = Session(req)
    seed = int(req["seed"])
    t0 = time.perf_counter()
    obs, info = session.reset(seed)
    lang_goal = info.get("lang_goal", "")
    session.recording = True
    session._keep(session.observe())
    high_level, high_level_step, languages = [], [], [lang_goal]
    for _ in range(session.task.max_steps):
        action = session.agent.act(obs, info)
        if action is None:
            break
        high_level_step.append(len(session.rows["action"]))
        high_level.append(_pose_vector(action))
        obs, _, done, info = session.primitive(action)
        languages.append(info.get("lang_goal", lang_goal))
        if done:
            break
    session.recording = False
    arrays = {k: np.asarray(v) for k, v in session.rows.items()}
    arrays["state"] = arrays["state"].astype(np.float32).reshape(-1, 14)
    arrays["object_poses"] = arrays["object_poses"].astype(np.float32).reshape(len(arrays["state"]), -1, 7)
    arrays["action"] = arrays["action"].astype(np.float32).reshape(-1, 7)
    arrays["progress"] = arrays["progress"].astype(np.float32)
    arrays["high_level_action"] = np.asarray(high_level, np.float32).reshape(-1, 14)
    arrays["high_level_step"] = np.asarray(high_level_step, np.int64)
    task = session.task
    meta = {"task": req["task"], "seed": seed, "mode": task.mode, "unseen_colors": bool(req.get("unseen_colors")), "lang_goal": lang_goal, "lang_goals": languages,
            "total_reward": session.total_reward, "success": session.total_reward >= 0.99, "done": session.done,
            "primitives": session.primitives, "max_steps": int(task.max_steps),
            "physics_steps": session.physics_steps, "hz": int(req["hz"]), "frame_every": int(req["frame_every"]),
            "seconds": time.perf_counter() - t0, "task_class": type(task).__name__, "docstring": type(task).__doc__,
            "clock": req.get("clock", "simulated"), "movej_timeouts": session.movej_timeouts}
    return {"arrays": arrays, "meta": meta}


def _where(error: BaseException) -> str:
    frames = traceback.extract_tb(error.__traceback__)
    return next((f"{f.filename}:{f.lineno}" for f in reversed(frames)), "")


def _fail(code: int, error: BaseException, where: str) -> None:
    print(json.dumps({"error": f"{type(error).__name__}: {error}", "where": _where(error), "stage": where}),
          file=sys.stderr)
    raise SystemExit(code)


def _pose_pair(action) -> dict:
    """A 14-d pick/place vector as GenSim's action: {pose0: (xyz, xyzw), pose1: (xyz, xyzw)}."""
    a = [float(x) for x in action]
    return {"pose0": (a[0:3], a[3:7]), "pose1": (a[7:10], a[10:14])}


def _pose_vector(action: dict) -> list[float]:
    return [*action["pose0"][0], *action["pose0"][1], *action["pose1"][0], *action["pose1"][1]]


def serve(req: dict, commands, replies) -> None:
    """Closed loop: answer ("reset", seed), ("step", 14-d action), ("oracle",) and ("close",) on `commands`, each
    with ("ok", ...) or ("error", message, where) on `replies` (multiprocessing connections over the pipes)."""
    session = Session(req)
    state: dict = {}

    def small(info: dict) -> dict:
        return {"success": session.total_reward >= 0.99, "progress": session.total_reward, "done": session.done,
                "lang_goal": info.get("lang_goal", ""), "max_steps": int(session.task.max_steps)}

    while True:
        try:
            command, *args = commands.recv()
        except EOFError:
            return
        try:
            if command == "close":
                replies.send(("ok",))
                return
            if command == "reset":
                state["obs"], state["info"] = session.reset(int(args[0]))
                replies.send(("ok", session.observe(), small(state["info"])))
            elif command == "step":
                state["obs"], reward, done, state["info"] = session.primitive(_pose_pair(args[0]))
                replies.send(("ok", session.observe(), reward, done, small(state["info"])))
            elif command == "oracle":
                action = session.agent.act(state["obs"], state["info"])
                replies.send(("ok", None if action is None else _pose_vector(action)))
            else:
                replies.send(("error", f"unknown command {command!r}", ""))
        except Exception as e:  # noqa: BLE001  (GenSim's code raised: the parent reports it)
            replies.send(("error", f"{type(e).__name__}: {e}", _where(e)))


def _die_with_parent(parent: int | None) -> None:
    """Be killed when the collector dies, however it dies (Linux PR_SET_PDEATHSIG); a collector already gone
    before that took effect is seen by its pid."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes
            import signal

            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)
        except (OSError, AttributeError):
            pass
    if parent is not None and os.getppid() != parent:
        os._exit(1)


def main(argv: list[str]) -> None:
    serving = argv[1] == "--serve"
    with open(argv[-1], encoding="utf-8") as f:
        req = json.load(f)
    _die_with_parent(req.get("parent"))
    if serving:  # the replies go on the real stdout; GenSim's prints to stdout go to stderr instead
        from multiprocessing.connection import Connection

        replies = Connection(os.dup(1), readable=False)
        os.dup2(2, 1)
        commands = Connection(os.dup(0), writable=False)
    try:
        loaded = load_gensim(req["root"])
    except Exception as e:  # noqa: BLE001  (any import failure of the user's checkout is reported, not raised)
        _fail(EXIT_UNUSABLE, e, "import")
    if serving:
        try:
            serve(req, commands, replies)
        except Exception as e:  # noqa: BLE001  (the task could not even be set up)
            replies.send(("error", f"{type(e).__name__}: {e}", _where(e)))
        return
    try:
        out = record(req)
    except Exception as e:  # noqa: BLE001  (GenSim's own code raised: the parent reports it per episode)
        _fail(EXIT_TASK_RAISED, e, "episode")
    import numpy as np

    out["meta"].update(loaded)
    tmp = req["out"] + ".part.npz"
    np.savez(tmp, **out["arrays"])
    with open(req["out"] + ".json.part", "w", encoding="utf-8") as f:
        json.dump(out["meta"], f)
    os.replace(tmp, req["out"] + ".npz")
    os.replace(req["out"] + ".json.part", req["out"] + ".json")


if __name__ == "__main__":
    main(sys.argv)
