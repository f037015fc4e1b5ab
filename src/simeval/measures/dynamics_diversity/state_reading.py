"""The state-space reading of dynamics diversity: a dynamics model over the recorded low-dimensional state, scored
on held-out episodes beside trivial predictors, under the same protocol as the pixel reading (simeval.models.
prediction) but blind to rendering (small objects, the arm filling the frame, colours).

State: s_t (D,) = [obs/state_t (the robot's proprioception, what the pipeline records), then per object pose where
the store has obs/object_poses (T+1, N, 7): x, y, z and the quaternion xyzw with w >= 0 (q and -q are one
rotation)]. Units are the store's (metres, radians): errors of two groups of one pipeline compare.

    model      s^_{t+1} = s_t + sd * f([ (s_t - mu) / sd, (s_{t-j+1} - s_{t-j}) / sd, (a_{t-j+1} - mu_a) / sd_a
                                             for j = 1 .. H ])
               f an MLP (SiLU), trained with Adam on the mean squared error of the normalised change
               (mu, sd, mu_a, sd_a: means and deviations over the training episodes' rows; sd = 1 where a
               dimension never changes). H = `history` past changes and actions: from them the model can infer
               in context how this episode's actions move things (a varied group's per-episode knobs), as the
               RSSM's recurrent state can
    baselines  last state         s^_{t+1} = s_t
               mean state         s^_{t+1} = the task's mean state over its training episodes' rows
               constant velocity  s^_{t+1} = s_t + (s_t - s_{t-1})
    scored on  every step t = H .. n - 2 of a held-out episode of n rows (t >= H: the history is observed;
               row n - 1's action is padding): se = sum_d (s^_{t+1, d} - s_{t+1, d})^2, per episode summed over
               its steps with the number of steps (`frames`)
    error      sum se / sum frames;  skill vs b = 1 - error / error_b

Training budget: at most `max_steps` gradient steps for every episode count; every `eval_every` steps the error on
validation episodes (the last `val_share` of each task's training episodes, held back from the gradient; never an
evaluated one) is read, and training stops once it has not improved by 1% for `patience` reads; the model of the
best read is kept and `steps_used` recorded. R training seeds give per-episode sums (R, E) for intervals and the
gate (simeval.measures.dynamics_diversity.gate) against the last and the mean state (GATED says why not constant
velocity).

Why an MLP written here and not the RSSM of simeval.models.world_model over a state vector: the reading must hold
where the pixel model fails, so it shares none of its machinery (no latent sampling, no decoder), and a
one-step regressor with a velocity feature is the least model that can beat constant velocity; it trains in seconds
on a CPU.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from simeval.errors import UserError, require_whole, require_whole_fields, settings_from_dict
from simeval.measures.dynamics_diversity.gate import GateConfig, gate

BASELINES = ("last_state", "mean_state", "constant_velocity")
# what the gate requires the model to beat: the analogues of the pixel reading's last frame and mean image. Not
# constant velocity: where each episode's dynamics are drawn anew (a diverse group) no model trained on other
# episodes predicts better than momentum, so requiring it would gate exactly the groups the metric exists to find;
# a model that learned nothing of the state's motion fails against the last or the mean state. Its skill against
# constant velocity (how much of the motion the model explains beyond momentum) is reported beside.
GATED = ("last_state", "mean_state")


@dataclass(frozen=True)
class StateModelConfig:
    hidden: int = 128
    layers: int = 2
    lr: float = 1e-3
    batch_size: int = 256
    max_steps: int = 3000  # the cap, the same for every episode count
    eval_every: int = 50
    patience: int = 10  # reads of the validation error without a 1% improvement before stopping
    val_share: float = 0.2  # of each task's training episodes (at least one), held back from the gradient
    seeds: tuple[int, ...] = (0, 1, 2)
    history: int = 4  # H: past changes and actions the model sees

    def __post_init__(self) -> None:
        require_whole_fields(self, "protocol.state_model", ("hidden", "layers", "batch_size", "max_steps",
                                                             "eval_every", "patience", "history"))
        for key in ("lr", "val_share"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or v <= 0:
                raise UserError(f"protocol.state_model.{key}={v!r}: expected a positive number")
        if not 0 < self.val_share < 1:
            raise UserError(f"protocol.state_model.val_share={self.val_share}: expected a share in (0, 1)")
        if not self.seeds:
            raise UserError("protocol.state_model.seeds: expected at least one training seed")
        for seed in self.seeds:
            require_whole("protocol.state_model.seeds[]", seed, 0)

    @classmethod
    def from_dict(cls, d: dict | None) -> StateModelConfig:
        d = dict(d or {})
        if "seeds" in d:
            d["seeds"] = tuple(d["seeds"]) if isinstance(d["seeds"], (list, tuple)) else (d["seeds"],)
        return settings_from_dict(cls, d, "protocol.state_model")


def low_dim_state(state: np.ndarray, object_poses: np.ndarray | None) -> np.ndarray:
    """(n, D) float64: the robot state (n, Dr), then per object x, y, z and the quaternion with w >= 0."""
    parts = [np.asarray(state, np.float64).reshape(len(state), -1)]
    if object_poses is not None and np.size(object_poses):
        poses = np.asarray(object_poses, np.float64).copy()  # (n, N, 7)
        flip = poses[..., 6:7] < 0
        poses[..., 3:] = np.where(flip, -poses[..., 3:], poses[..., 3:])
        parts.append(poses.reshape(len(poses), -1))
    return np.concatenate(parts, 1)


def read_states(source, episodes) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """{e: (states (n, D), actions (n, A))} for the episodes `episodes` (indices) of a source (ArraySource or
    StoreSource: their read_full of "state", "object_poses" (None where not recorded) and "action")."""
    return {int(e): (low_dim_state(source.read_full(int(e), "state"), source.read_full(int(e), "object_poses")),
                     np.asarray(source.read_full(int(e), "action"), np.float64)) for e in episodes}


def _steps(s: np.ndarray, a: np.ndarray, history: int):
    """(s_t (m, D), changes (m, H, D): s_{t-j+1} - s_{t-j}, actions (m, H, A): a_{t-j+1}, s_{t+1} (m, D)) for
    t = H .. n - 2, j = 1 .. H."""
    n = len(s)
    t = np.arange(history, n - 1)
    if not len(t):
        raise UserError(f"state reading: an episode of {n} states is too short for a history of {history} steps "
                        "(protocol.state_model.history)")
    j = np.arange(1, history + 1)
    ti = t[:, None] - j[None] + 1  # (m, H)
    return s[t], s[ti] - s[ti - 1], a[ti], s[t + 1]


class _Net(nn.Module):
    def __init__(self, d_in: int, d_out: int, hidden: int, layers: int) -> None:
        super().__init__()
        mods, d = [], d_in
        for _ in range(layers):
            mods += [nn.Linear(d, hidden), nn.SiLU()]
            d = hidden
        mods.append(nn.Linear(d, d_out))
        self.net = nn.Sequential(*mods)
        nn.init.zeros_(self.net[-1].weight)  # starts as the last-state predictor: no change
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


@dataclass
class _Norm:
    mu: np.ndarray
    sd: np.ndarray
    mu_a: np.ndarray
    sd_a: np.ndarray

    @classmethod
    def fit(cls, data: list[tuple[np.ndarray, np.ndarray]]) -> _Norm:
        s = np.concatenate([x for x, _ in data])
        a = np.concatenate([y[:-1] for _, y in data])  # the real actions (the last row's is padding)
        sd, sd_a = s.std(0), a.std(0)
        return cls(s.mean(0), np.where(sd > 1e-8, sd, 1.0), a.mean(0), np.where(sd_a > 1e-8, sd_a, 1.0))

    def features(self, s, changes, actions) -> np.ndarray:
        m = len(s)
        return np.concatenate([(s - self.mu) / self.sd, (changes / self.sd).reshape(m, -1),
                               ((actions - self.mu_a) / self.sd_a).reshape(m, -1)], 1)


def _tensors(data, norm: _Norm, history: int):
    rows = [_steps(s, a, history) for s, a in data]
    x = np.concatenate([norm.features(s, c, a) for s, c, a, _ in rows])
    y = np.concatenate([(nxt - s) / norm.sd for s, _, _, nxt in rows])
    return torch.as_tensor(x, dtype=torch.float32), torch.as_tensor(y, dtype=torch.float32)


def fit_state_model(train: list[tuple[np.ndarray, np.ndarray]], val: list[tuple[np.ndarray, np.ndarray]],
                    cfg: StateModelConfig, seed: int) -> tuple[_Net, _Norm, dict]:
    """A model on `train` episodes ((states, actions) each), stopped on `val` (see the module docstring)."""
    norm = _Norm.fit(train)
    x, y = _tensors(train, norm, cfg.history)
    xv, yv = _tensors(val, norm, cfg.history)
    torch.manual_seed(seed)
    net = _Net(x.shape[1], y.shape[1], cfg.hidden, cfg.layers)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    gen = torch.Generator().manual_seed(seed)
    best, best_state, best_step, since, step, curve = float("inf"), None, 0, 0, 0, []
    while step < cfg.max_steps:
        idx = torch.randint(0, len(x), (min(cfg.batch_size, len(x)),), generator=gen)
        loss = (net(x[idx]) - y[idx]).pow(2).sum(1).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        if step % cfg.eval_every == 0 or step == cfg.max_steps:
            with torch.no_grad():
                v = float((net(xv) - yv).pow(2).sum(1).mean())
            curve.append([step, v])
            if v < best * 0.99:
                best, best_state, best_step, since = v, {k: t.clone() for k, t in net.state_dict().items()}, step, 0
            else:
                since += 1
                if since >= cfg.patience:
                    break
    if best_state is not None:
        net.load_state_dict(best_state)
    return net, norm, {"steps_used": step, "best_step": best_step, "val_loss": best, "val_curve": curve}


def _predict(net: _Net, norm: _Norm, s, changes, actions) -> np.ndarray:
    with torch.no_grad():
        d = net(torch.as_tensor(norm.features(s, changes, actions), dtype=torch.float32)).double().numpy()
    return s + d * norm.sd


def episode_sums(pred: np.ndarray, target: np.ndarray) -> float:
    return float(((pred - target) ** 2).sum())


def split_training(tasks: list[str], train_idx: list[int], val_share: float) -> tuple[list[int], list[int]]:
    """Per task, its training episodes (in rank order) split into fitted ones and the last `val_share` (at least
    one; none when the task has a single training episode, which then validates on nothing of its own)."""
    fit, val = [], []
    for t in sorted(set(tasks[i] for i in train_idx)):
        mine = [i for i in train_idx if tasks[i] == t]
        n_val = max(1, int(round(val_share * len(mine)))) if len(mine) > 1 else 0
        fit += mine[: len(mine) - n_val]
        val += mine[len(mine) - n_val:]
    return fit, val


def state_reading(states: dict[int, tuple[np.ndarray, np.ndarray]], tasks: list[str], train_idx: list[int],
                  eval_idx: list[int], cfg: StateModelConfig = StateModelConfig(),
                  gate_cfg: GateConfig = GateConfig()) -> dict:
    """The state-space reading (module docstring) of one group and episode count: `states` from read_states,
    `tasks` every episode's task (indexed like the source), `train_idx` and `eval_idx` the training and held-out
    episodes (disjoint). Returns {dims, summary: {model, last_state, mean_state, constant_velocity: error,
    skill_vs_<b>}, per_episode: [{task, index, frames, model: [R], <b>}], seeds, training: [per seed], gate,
    line} or {reading: None, why} where there is no state to read."""
    if set(train_idx) & set(eval_idx):
        raise RuntimeError("an evaluated episode is among the training episodes")
    sizes = {}  # values per step -> the first episode of that size, for the message
    for i in (*train_idx, *eval_idx):
        sizes.setdefault(states[i][0].shape[1], i)
    if len(sizes) > 1:  # one model reads one state vector: objects that appear or vanish between episodes
        (d0, i0), (d1, i1) = sorted(sizes.items())[:2]
        raise UserError(f"the recorded states differ in size between episodes ({d0} values per step in "
                        f"{tasks[i0]}'s, {d1} in {tasks[i1]}'s: the scene's object count varies); the state model "
                        "reads one size")
    dims = states[eval_idx[0]][0].shape[1]
    if dims == 0:
        return {"dims": 0, "gate": None, "line": "no state recorded (obs/state empty, no obs/object_poses)",
                "why": "no state"}
    fit_idx, val_idx = split_training(tasks, train_idx, cfg.val_share)
    if not val_idx:
        raise UserError("state reading: every task has a single training episode; validation needs two or more")
    fit = [states[i] for i in fit_idx]
    val = [states[i] for i in val_idx]
    task_mean = {t: np.concatenate([states[i][0] for i in train_idx if tasks[i] == t]).mean(0)
                 for t in set(tasks[i] for i in train_idx)}
    models, training = [], []
    for seed in cfg.seeds:
        net, norm, info = fit_state_model(fit, val, cfg, seed)
        models.append((net, norm))
        training.append({"seed": int(seed), **info})
    per_episode = []
    for e in eval_idx:
        s, a = states[e]
        cur, changes, act, nxt = _steps(s, a, cfg.history)
        row = {"task": tasks[e], "index": int(e), "frames": int(len(nxt)),
               "model": [episode_sums(_predict(net, norm, cur, changes, act), nxt) for net, norm in models],
               "last_state": episode_sums(cur, nxt),
               "mean_state": episode_sums(np.broadcast_to(task_mean[tasks[e]], nxt.shape), nxt),
               "constant_velocity": episode_sums(cur + changes[:, 0], nxt)}
        per_episode.append(row)
    frames = sum(r["frames"] for r in per_episode)
    model = np.array([[r["model"][k] for r in per_episode] for k in range(len(models))])  # (R, E)
    bases = {b: np.tile([r[b] for r in per_episode], (len(models), 1)) for b in BASELINES}
    summary = {"model": float(model.sum() / (len(models) * frames)) if frames else None,
               **{b: float(bases[b][0].sum() / frames) if frames else None for b in BASELINES}}
    for b in BASELINES:
        summary[f"skill_vs_{b}"] = float(1 - model.sum() / bases[b].sum()) if bases[b].sum() > 0 else None
    g = gate(model, {b: bases[b] for b in GATED}, [r["task"] for r in per_episode], gate_cfg)
    line = (g["verdict"] if not g["passes"] else
            f"one-step state error {summary['model']:.3g} (last state {summary['last_state']:.3g}, mean state "
            f"{summary['mean_state']:.3g}, constant velocity {summary['constant_velocity']:.3g}; skill "
            f"{summary['skill_vs_last_state']:.2f} / {summary['skill_vs_mean_state']:.2f} / "
            f"{summary['skill_vs_constant_velocity']:.2f}), {dims} dims, {len(models)} seeds")
    return {"dims": int(dims), "summary": summary, "per_episode": per_episode, "frames": int(frames),
            "seeds": [int(s) for s in cfg.seeds], "training": training, "fit_episodes": len(fit_idx),
            "validation_episodes": len(val_idx), "gate": g, "line": line}
