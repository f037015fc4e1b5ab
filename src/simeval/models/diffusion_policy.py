"""CNN Diffusion Policy (Chi et al., 2023) with image + state observations, as the paper's Table 5 trains it.

    policy = DiffusionPolicy(PolicyConfig(...), state_dim=S, action_dim=A, stats=dataset.stats())
    loss = policy.compute_loss(batch)                       # epsilon-prediction MSE, DDPM forward process
    actions = policy.predict_action(obs)                    # obs: {"rgb": {cam: (B, To, H, W, 3) uint8},
                                                            #       "state": (B, To, S)} -> (B, horizon, A)
    train_policy(policy, dataset, TrainSettings(...), ckpt_dir)    # AdamW + cosine warm-up + EMA, resumable
    runner = RecedingHorizonRunner(ema_policy)              # env loop: act(obs) -> one action per call

Training: x0 = the normalised action window (B, Tp, A) in [-1, 1]; t ~ U{0..K-1}; eps ~ N(0, I);
x_t = sqrt(abar_t) x0 + sqrt(1 - abar_t) eps (diffusers' DDPMScheduler.add_noise, squaredcos_cap_v2 betas);
loss = mean (eps_theta(x_t, t, cond) - eps)^2 with cond = [image features of To frames, normalised To states].
Sampling: x_K ~ N(0, I) and the scheduler's reverse steps: DDPM (all K steps) or DDIM (few steps, eta = 0).
EMA: diffusers' EMAModel with the official warm-up decay 1 - (1 + step)^-0.75, capped at 0.9999.
Receding horizon: predict Tp actions from the last To observations, execute Ta of them (from index To-1), repeat.
Device: train_policy(..., device=...) moves the policy there (auto, cpu, cuda, cuda:N; simeval.runtime.device);
compute_loss, predict_action and the runner bring their inputs to wherever the policy is. Every random tensor (crop
offsets, noise, timesteps, the sampler's initial noise) is drawn from a CPU generator and moved, so a seed gives the
same draws on every device. Checkpoints hold CPU tensors and are not keyed by the device.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import os
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from einops import rearrange
from torch import nn
from torch.nn import functional as F

from simeval.errors import UserError, check_field_types, require_whole, require_whole_fields
from simeval.runtime.checkpoints import read_checkpoint, save_checkpoint
from simeval.runtime.device import describe_device, module_device, resolve_device, to_cpu, to_device
from simeval.models.policy_networks import ConditionalUnet1D, ImageEncoder, center_crop, random_crop
from simeval.runtime.trainer import duration, refuse_other_settings, run_steps

log = logging.getLogger(__name__)
CHECKPOINT_VERSION = 1
SCHEDULERS = ("ddpm", "ddim")
SAMPLING_FIELDS = ("inference_scheduler", "num_inference_steps")  # inference only: not part of a checkpoint's identity
POLICY_ACTION_SPACES = ("native", "joint", "ee_delta", "ee_pose", "pick_place", "metaworld", "recorded")


BETA_SCHEDULES = ("linear", "scaled_linear", "squaredcos_cap_v2")  # what diffusers' DDPM and DDIM schedulers take


@dataclass
class PolicyConfig:
    """The model and its sampler; `policy` config group (conf/policy/*.yaml). Validated on construction."""

    # native (the task group's own: joint for GenSim-style, ee_delta for RoboGen-style, ee_pose for BBSEA-style
    # tasks; resolved by simeval.measures.generalization.run.resolve_action_space) | joint | ee_delta | ee_pose (one
    # action per control step) | pick_place (14-d poses, one per primitive) | metaworld (Meta-World's 4-d action) |
    # recorded (the episodes' own actions, one per step, whatever kind: a Gymnasium pipeline's)
    action_space: str = "joint"
    cameras: list = field(default_factory=lambda: ["top"])
    image_size: list = field(default_factory=lambda: [64, 64])
    crop: int = 56
    encoder_width: int = 32
    keypoints: int = 32
    feature_dim: int = 64
    stem_pool: bool = True
    horizon: int = 16
    n_obs_steps: int = 2
    n_action_steps: int = 8
    down_dims: list = field(default_factory=lambda: [64, 128, 256])
    step_embed_dim: int = 128
    kernel_size: int = 5
    n_groups: int = 8
    num_train_timesteps: int = 100
    beta_schedule: str = "squaredcos_cap_v2"
    inference_scheduler: str = "ddim"
    num_inference_steps: int = 16
    normalize_quaternions: bool = False

    def __post_init__(self) -> None:
        check_field_types(self, "policy.model")
        self.cameras, self.image_size, self.down_dims = list(self.cameras), list(self.image_size), list(self.down_dims)
        require_whole_fields(self, "policy.model", ("crop", "encoder_width", "keypoints", "feature_dim", "horizon",
                                                    "n_obs_steps", "n_action_steps", "step_embed_dim", "kernel_size",
                                                    "n_groups", "num_train_timesteps", "num_inference_steps"))
        if self.action_space not in POLICY_ACTION_SPACES:
            raise UserError(f"policy.model.action_space={self.action_space!r}: expected one of "
                            f"{', '.join(POLICY_ACTION_SPACES)}")
        if not self.down_dims or not all(isinstance(d, int) and not isinstance(d, bool) and d >= 1
                                         for d in self.down_dims):
            raise UserError(f"policy.model.down_dims={self.down_dims!r}: expected a list of channel counts, e.g. "
                            "[64,128,256]")
        if self.beta_schedule not in BETA_SCHEDULES:
            raise UserError(f"policy.model.beta_schedule={self.beta_schedule!r}: expected one of "
                            f"{', '.join(BETA_SCHEDULES)}")
        if not self.cameras:
            raise UserError("policy.model.cameras must name at least one camera (an image policy), got []")
        if len(self.image_size) != 2 or self.crop > min(self.image_size):
            raise UserError(f"policy.model.crop={self.crop} must fit policy.model.image_size={self.image_size} "
                            "([H, W])")
        if self.n_obs_steps + self.n_action_steps - 1 > self.horizon:
            raise UserError(f"policy.model.horizon={self.horizon} must cover n_obs_steps-1+n_action_steps="
                            f"{self.n_obs_steps - 1 + self.n_action_steps}")
        halvings = len(self.down_dims) - 1
        if self.horizon % (2**halvings):
            raise UserError(f"policy.model.horizon={self.horizon} must be a multiple of {2**halvings}: the U-Net with "
                            f"down_dims={self.down_dims} halves the sequence {halvings} time(s)")
        if self.inference_scheduler not in SCHEDULERS:
            raise UserError(f"policy.model.inference_scheduler={self.inference_scheduler!r}: expected ddpm or ddim")
        if self.num_inference_steps > self.num_train_timesteps:
            raise UserError(f"policy.model.num_inference_steps={self.num_inference_steps} exceeds "
                            f"num_train_timesteps={self.num_train_timesteps}")

    def training_fields(self) -> dict:
        """The fields that shape the trained weights: every field but the sampler used at inference, so a
        checkpoint trained once can be rolled out with DDIM-k or DDPM without retraining."""
        return {k: v for k, v in dataclasses.asdict(self).items() if k not in SAMPLING_FIELDS}

    @classmethod
    def from_mapping(cls, d: Mapping) -> "PolicyConfig":
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise UserError(f"policy: unknown key(s) {unknown}; valid: {', '.join(sorted(names))}")
        return cls(**dict(d))


def make_scheduler(kind: str, num_train_timesteps: int, beta_schedule: str):
    """The official settings: 100 steps, squaredcos_cap_v2, clip to [-1, 1], epsilon prediction."""
    from diffusers import DDIMScheduler, DDPMScheduler

    common = dict(num_train_timesteps=num_train_timesteps, beta_start=1e-4, beta_end=0.02, beta_schedule=beta_schedule,
                  clip_sample=True, prediction_type="epsilon")
    if kind == "ddpm":
        return DDPMScheduler(variance_type="fixed_small", **common)
    return DDIMScheduler(set_alpha_to_one=True, steps_offset=0, **common)


class RangeNormalizer(nn.Module):
    """x -> 2 (x - lo) / (hi - lo) - 1 per dimension; a dimension with hi - lo < 1e-4 is only shifted (to 0)."""

    def __init__(self, lo: torch.Tensor, hi: torch.Tensor) -> None:
        super().__init__()
        span = hi - lo
        const = span < 1e-4
        self.register_buffer("scale", torch.where(const, torch.ones_like(span), 2.0 / span.clamp_min(1e-4)))
        self.register_buffer("offset", torch.where(const, -lo, -1.0 - 2.0 * lo / span.clamp_min(1e-4)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.scale + self.offset

    def inverse(self, y: torch.Tensor) -> torch.Tensor:
        return (y - self.offset) / self.scale


class DiffusionPolicy(nn.Module):
    def __init__(self, cfg: PolicyConfig, state_dim: int, action_dim: int,
                 stats: Mapping[str, tuple[torch.Tensor, torch.Tensor]] | None = None, seed: int | None = None) -> None:
        """`seed`: initialise the weights from this seed (the global RNG is left as it was) so a run is repeatable."""
        super().__init__()
        with torch.random.fork_rng(devices=[]):
            if seed is not None:
                torch.manual_seed(seed)
            self._build(cfg, state_dim, action_dim, stats)

    def _build(self, cfg: PolicyConfig, state_dim: int, action_dim: int, stats) -> None:
        self.cfg, self.state_dim, self.action_dim = cfg, int(state_dim), int(action_dim)
        self.encoders = nn.ModuleDict({c: ImageEncoder(cfg.encoder_width, cfg.keypoints, cfg.feature_dim, cfg.stem_pool)
                                       for c in cfg.cameras})
        cond_dim = cfg.n_obs_steps * (len(cfg.cameras) * cfg.feature_dim + state_dim)
        self.unet = ConditionalUnet1D(action_dim, cond_dim, cfg.down_dims, cfg.step_embed_dim, cfg.kernel_size,
                                      cfg.n_groups)
        stats = stats or {"state": (torch.zeros(state_dim), torch.ones(state_dim)),
                          "action": (torch.zeros(action_dim), torch.ones(action_dim))}
        self.state_norm = RangeNormalizer(*[torch.as_tensor(v, dtype=torch.float32) for v in stats["state"]])
        self.action_norm = RangeNormalizer(*[torch.as_tensor(v, dtype=torch.float32) for v in stats["action"]])
        self.noise_scheduler = make_scheduler("ddpm", cfg.num_train_timesteps, cfg.beta_schedule)

    # --- observation encoding --------------------------------------------------------------------------------
    def encode_obs(self, obs: Mapping, train: bool, generator: torch.Generator | None = None) -> torch.Tensor:
        """{"rgb": {cam: (B, To, H, W, 3) uint8}, "state": (B, To, S)} -> global condition (B, To*(F*cams + S))."""
        feats = []
        for cam, enc in self.encoders.items():
            frames = obs["rgb"][cam]
            b = frames.shape[0]
            x = rearrange(frames, "b t h w c -> (b t) c h w").float() / 255.0
            if tuple(x.shape[-2:]) != tuple(self.cfg.image_size):
                x = F.interpolate(x, size=tuple(self.cfg.image_size), mode="bilinear", antialias=True)
            x = random_crop(x, self.cfg.crop, generator) if train else center_crop(x, self.cfg.crop)
            feats.append(rearrange(enc(x), "(b t) f -> b t f", b=b))
        feats.append(self.state_norm(obs["state"].float()))
        return rearrange(torch.cat(feats, dim=-1), "b t f -> b (t f)")

    # --- training --------------------------------------------------------------------------------------------
    def compute_loss(self, batch: Mapping, generator: torch.Generator | None = None) -> torch.Tensor:
        """`batch` anywhere (it is moved to the policy's device); `generator`: a CPU one (see the module docstring)."""
        batch = to_device(batch, module_device(self))
        cond = self.encode_obs(batch, train=True, generator=generator)
        x0 = self.action_norm(batch["action"].float())
        noise = torch.randn(x0.shape, generator=generator).to(x0.device)
        t = torch.randint(0, self.noise_scheduler.config.num_train_timesteps, (x0.shape[0],),
                          generator=generator).to(x0.device)
        noisy = self.noise_scheduler.add_noise(x0, noise, t)
        return F.mse_loss(self.unet(noisy, t, cond), noise)

    # --- sampling --------------------------------------------------------------------------------------------
    @torch.no_grad()
    def sample(self, cond: torch.Tensor, scheduler=None, steps: int | None = None,
               generator: torch.Generator | None = None) -> torch.Tensor:
        """Reverse diffusion from N(0, I) to a normalised action window (B, Tp, A)."""
        cfg = self.cfg
        scheduler = scheduler or make_scheduler(cfg.inference_scheduler, cfg.num_train_timesteps, cfg.beta_schedule)
        scheduler.set_timesteps(steps or cfg.num_inference_steps)
        x = torch.randn((cond.shape[0], cfg.horizon, self.action_dim), generator=generator).to(cond.device)
        # the timesteps stay on the CPU (the U-Net moves each); diffusers draws DDPM's noise from a CPU generator on
        # the CPU and moves it (diffusers.utils.torch_utils.randn_tensor)
        for t in scheduler.timesteps:
            eps = self.unet(x, t, cond)
            x = scheduler.step(eps, t, x, generator=generator).prev_sample
        return x

    @torch.no_grad()
    def predict_action(self, obs: Mapping, scheduler: str | None = None, steps: int | None = None,
                       generator: torch.Generator | None = None) -> torch.Tensor:
        """(B, horizon, A) actions in the data's units (quaternions unit-norm if cfg.normalize_quaternions), on the
        policy's device; `obs` may be anywhere."""
        cfg = self.cfg
        sched = make_scheduler(scheduler or cfg.inference_scheduler, cfg.num_train_timesteps, cfg.beta_schedule)
        if steps is None:
            steps = cfg.num_train_timesteps if (scheduler or cfg.inference_scheduler) == "ddpm" else cfg.num_inference_steps
        cond = self.encode_obs(to_device(obs, module_device(self)), train=False)
        actions = self.action_norm.inverse(self.sample(cond, sched, steps, generator))
        if cfg.normalize_quaternions:
            actions = normalize_pose14_quaternions(actions)
        return actions


def normalize_pose14_quaternions(a: torch.Tensor) -> torch.Tensor:
    """[..., 14] pick/place poses with both quaternions (dims 3:7 and 10:14) scaled to unit norm."""
    a = a.clone()
    for s in (slice(3, 7), slice(10, 14)):
        a[..., s] = F.normalize(a[..., s], dim=-1)
    return a


# --- training loop ---------------------------------------------------------------------------------------------
@dataclass
class TrainSettings:
    """Optimiser and budget; the official values are AdamW lr 1e-4, betas (0.95, 0.999), weight decay 1e-6, cosine
    schedule with 500 warm-up steps, EMA power 0.75 up to 0.9999, batch 64."""

    train_steps: int = 2000
    batch_size: int = 64
    lr: float = 1e-4
    betas: tuple = (0.95, 0.999)
    weight_decay: float = 1e-6
    warmup_steps: int = 500
    lr_schedule: str = "cosine"
    ema_power: float = 0.75
    ema_max_decay: float = 0.9999
    checkpoint_every: int = 500
    log_every: int = 50
    seed: int = 0

    def __post_init__(self) -> None:
        check_field_types(self, "policy.train")
        require_whole_fields(self, "policy.train", ("train_steps", "batch_size", "checkpoint_every", "log_every"))
        if not self.lr > 0:
            raise UserError(f"policy.train.lr must be > 0, got {self.lr!r}")
        require_whole("policy.train.warmup_steps", self.warmup_steps, 0)
        betas = list(self.betas) if isinstance(self.betas, list | tuple) else None
        if betas is None or len(betas) != 2 or not all(isinstance(b, int | float) and not isinstance(b, bool)
                                                       and 0 <= b < 1 for b in betas):
            raise UserError(f"policy.train.betas={self.betas!r}: expected two numbers in [0, 1), e.g. [0.95,0.999]")
        from diffusers.optimization import SchedulerType

        schedules = [s.value for s in SchedulerType]
        if self.lr_schedule not in schedules:
            raise UserError(f"policy.train.lr_schedule={self.lr_schedule!r}: expected one of {', '.join(schedules)}")
        self.betas = tuple(self.betas)


def make_ema(policy: nn.Module, settings: TrainSettings, foreach: bool = False):
    """foreach: one multi-tensor kernel per update instead of three per parameter. On a GPU, where a step of the
    largest presets is bound by kernel launches, that is the faster way; on the CPU it stays off, since its fused
    `a - alpha * b` may round differently from the loop's and a CPU run should give the weights it always gave."""
    from diffusers.training_utils import EMAModel

    return EMAModel(policy.parameters(), decay=settings.ema_max_decay, min_decay=0.0, update_after_step=0,
                    use_ema_warmup=True, inv_gamma=1.0, power=settings.ema_power, foreach=foreach)


def load_checkpoint(path: str | os.PathLike) -> dict:
    ckpt = read_checkpoint(path, "policy")
    if ckpt.get("version") != CHECKPOINT_VERSION or "policy_config" not in ckpt:
        what = "a world-model checkpoint" if "meta" in ckpt and "format" in ckpt else f"version {ckpt.get('version')!r}"
        raise UserError(f"{path}: not a simeval policy checkpoint of version {CHECKPOINT_VERSION} ({what}); delete it "
                        "or use another checkpoint_dir")
    return ckpt


def policy_from_checkpoint(ckpt: Mapping, ema: bool = True,
                           device: str | torch.device | None = "auto") -> DiffusionPolicy:
    """The policy a checkpoint describes (its config is inside), with EMA weights unless ema=False, on `device`
    (load_checkpoint reads it onto the CPU, so one trained on a GPU loads anywhere)."""
    device = resolve_device(device)
    policy = DiffusionPolicy(PolicyConfig.from_mapping(ckpt["policy_config"]), ckpt["state_dim"], ckpt["action_dim"])
    policy.load_state_dict(ckpt["ema_model" if ema else "model"])
    return policy.to(device).eval()


class _PolicyTraining:
    """One training's state (optimiser, LR schedule, EMA, the batch-and-noise generator, the loss log) and the
    three things run_steps asks of it: a step, a checkpoint, and the bookkeeping after a step."""

    def __init__(self, policy: DiffusionPolicy, settings: TrainSettings, device: torch.device,
                 ckpt_path: Path | None, log_fn: Callable[[dict, int], None] | None, extra: Mapping | None) -> None:
        from diffusers.optimization import get_scheduler

        self.policy, self.settings, self.device, self.ckpt_path = policy, settings, device, ckpt_path
        self.log_fn, self.extra = log_fn, dict(extra or {})
        policy.to(device)  # before the optimiser and the EMA are made: their state is created beside the parameters
        torch.manual_seed(settings.seed)
        on_gpu = device.type == "cuda"  # launch-bound there: fused/multi-tensor updates (same maths, other rounding)
        self.optimizer = torch.optim.AdamW(policy.parameters(), lr=settings.lr, betas=settings.betas,
                                           weight_decay=settings.weight_decay, fused=on_gpu or None)
        self.lr_sched = get_scheduler(settings.lr_schedule, self.optimizer, num_warmup_steps=settings.warmup_steps,
                                      num_training_steps=settings.train_steps)
        self.ema = make_ema(policy, settings, foreach=on_gpu)
        self.gen = torch.Generator().manual_seed(settings.seed)
        self.step, self.losses, self.t_train = 0, [], 0.0
        self.window: list[torch.Tensor] = []  # the losses since the last log step, still on the device
        self.bar = None
        self.since = (time.perf_counter(), 0)  # (clock, step) where this process started training: the pace's origin

    def resume(self, ckpt: Mapping) -> None:
        self.policy.load_state_dict(ckpt["model"])  # copied into the parameters on `device`
        self.optimizer.load_state_dict(ckpt["optimizer"])  # torch moves the state to its parameters' device
        self.lr_sched.load_state_dict(ckpt["lr_scheduler"])
        self.ema.load_state_dict(ckpt["ema"])
        self.ema.to(self.device)  # EMAModel keeps the loaded (CPU) shadow weights where they are
        self.gen.set_state(ckpt["generator"])
        self.step, self.losses, self.t_train = ckpt["step"], list(ckpt["losses"]), ckpt.get("train_seconds", 0.0)
        self.since = (time.perf_counter(), self.step)
        done = self.step >= self.settings.train_steps
        log.info("policy training in %s finished at step %d/%d: reused, nothing to train" if done else
                 "resuming policy training from %s at step %d/%d", self.ckpt_path, self.step, self.settings.train_steps)

    def ema_policy(self) -> DiffusionPolicy:
        ema_model = copy.deepcopy(self.policy)
        self.ema.copy_to(ema_model.parameters())
        return ema_model

    def save(self, step: int) -> None:
        if self.ckpt_path is None:
            return
        policy, settings = self.policy, self.settings
        # temp file + rename (checkpoints.save_checkpoint): a kill never leaves half a checkpoint
        save_checkpoint(self.ckpt_path, {
            "version": CHECKPOINT_VERSION, "policy_config": dataclasses.asdict(policy.cfg),
            "train": dataclasses.asdict(settings), "state_dim": policy.state_dim, "action_dim": policy.action_dim,
            "model": to_cpu(policy.state_dict()), "ema_model": to_cpu(self.ema_policy().state_dict()),
            "ema": to_cpu(self.ema.state_dict()), "optimizer": to_cpu(self.optimizer.state_dict()),
            "lr_scheduler": self.lr_sched.state_dict(), "generator": self.gen.get_state(), "step": step,
            "losses": self.losses, "train_seconds": self.t_train, "trained_on": describe_device(self.device),
            "extra": self.extra})

    def take_step(self, batch, step: int) -> dict:  # the noise comes from `gen`, not from the step count
        loss = self.policy.compute_loss(batch, generator=self.gen)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        self.lr_sched.step()
        self.ema.step(self.policy.parameters())
        # read at the log step: a .item() here would make the CPU wait for each step's kernels on a GPU
        return {"loss": loss.detach()}

    def after_step(self, step: int, metrics: dict, seconds: float) -> None:
        self.t_train += seconds
        self.window.append(metrics["loss"])
        if self.bar is not None:
            self.bar.update(1)
        if step % self.settings.log_every == 0 or step == self.settings.train_steps:
            mean = float(np.mean([float(loss) for loss in self.window]))
            self.losses.append([step, mean])
            self.window = []
            if self.log_fn is not None:
                self.log_fn({"train/loss": mean, "train/lr": self.lr_sched.get_last_lr()[0]}, step)
            if self.bar is not None:
                self.bar.set_postfix(loss=f"{mean:.4f}")
        if self.bar is None and (step % max(1, self.settings.train_steps // 10) == 0
                                 or step == self.settings.train_steps):
            self._log_pace(step)

    def _log_pace(self, step: int) -> None:
        """A line per tenth of the training where no progress bar is drawn (progress=false, SLURM logs): its pace
        since this process started training and what is left."""
        pace = (time.perf_counter() - self.since[0]) / max(step - self.since[1], 1)
        loss = f"{self.losses[-1][1]:.4f}" if self.losses else "not logged yet"
        log.info("policy training: step %d/%d, loss %s, %.3f s/step, ~%s left", step, self.settings.train_steps,
                 loss, pace, duration((self.settings.train_steps - step) * pace))


def train_policy(policy: DiffusionPolicy, dataset, settings: TrainSettings, ckpt_dir: str | os.PathLike | None = None,
                 log_fn: Callable[[dict, int], None] | None = None, extra: Mapping | None = None,
                 progress: bool = False, device: str | torch.device | None = "auto") -> tuple[DiffusionPolicy, dict]:
    """Train for settings.train_steps gradient steps; return (EMA policy, summary). With ckpt_dir, `last.ckpt`
    there (model, EMA, optimiser, LR schedule, sampler RNG, config) is written every checkpoint_every steps and
    at the end, atomically, and a run finding one resumes from it: a killed run loses at most checkpoint_every
    steps, and the resumed run draws the same batches as an uninterrupted one would have."""
    device = resolve_device(device)
    ckpt_path = Path(ckpt_dir) / "last.ckpt" if ckpt_dir else None
    run = _PolicyTraining(policy, settings, device, ckpt_path, log_fn, extra)
    if ckpt_path is not None and ckpt_path.is_file():
        ckpt = load_checkpoint(ckpt_path)
        trained = {k: v for k, v in ckpt["policy_config"].items() if k not in SAMPLING_FIELDS}
        refuse_other_settings(ckpt_path, {"policy.model": trained, "policy.train": ckpt["train"]},
                              {"policy.model": policy.cfg.training_fields(),
                               "policy.train": dataclasses.asdict(settings)}, "checkpoint_dir")
        if "optimizer" not in ckpt:
            return finished_weights(policy, ckpt, ckpt_path, settings)
        run.resume(ckpt)
    if progress:
        from tqdm import tqdm

        run.bar = tqdm(total=settings.train_steps, initial=run.step, desc="train policy", unit="step")
    policy.train()
    # drawn one at a time, just before their step, from the same generator as the step's noise (as before a resume)
    batches = (dataset.sample(settings.batch_size, run.gen) for _ in range(run.step, settings.train_steps))
    # the last checkpoint is written once, after the loop (last_step), and not again by a run that found it finished
    # (rewriting it would only replace its `extra` with this run's)
    started = run.step
    step = run_steps(batches, run.take_step, run.save, step=run.step, checkpoint_every=settings.checkpoint_every,
                     last_step=settings.train_steps, after_step=run.after_step,
                     final_save=lambda s: None if s == started else run.save(s))
    if run.bar is not None:
        run.bar.close()
    return run.ema_policy().eval(), training_summary(step, run.losses, run.t_train, str(device))


def training_summary(step: int, losses: list, train_seconds: float, device: str) -> dict:
    return {"steps": step, "losses": losses, "final_loss": losses[-1][1] if losses else None,
            "train_seconds": train_seconds, "seconds_per_step": train_seconds / max(step, 1), "device": device}


def finished_weights(policy: DiffusionPolicy, ckpt: Mapping, path: Path,
                     settings: TrainSettings) -> tuple[DiffusionPolicy, dict]:
    """A checkpoint holding only a finished training's EMA weights (no model, optimiser or RNG state: what
    `src/generalization_tools.py offline export` + `import` bring from a machine whose checkpoint is too large to
    copy whole): the policy with those weights and the training's summary, with what was done to the weights. It cannot
    be resumed, so one short of settings.train_steps is refused."""
    if ckpt["step"] != settings.train_steps:
        raise UserError(f"{path}: holds only the EMA weights at step {ckpt['step']}, not a finished training of "
                        f"{settings.train_steps} steps, so it cannot be resumed; delete it to train here")
    policy.load_state_dict(ckpt["ema_model"])  # float16-rounded tensors are copied into the float32 parameters
    trained_on = ckpt["weights"].get("trained_on") or "where it trained not recorded"
    log.info("policy weights from %s: a finished training (%d steps, %s) reused", path, ckpt["step"], trained_on)
    summary = training_summary(ckpt["step"], list(ckpt["losses"]), ckpt["train_seconds"], trained_on)
    return policy.eval(), {**summary, "weights": dict(ckpt["weights"])}


# --- execution -------------------------------------------------------------------------------------------------
class RecedingHorizonRunner:
    """Closed-loop control: keep the last To observations (the first one repeated after a reset), predict a window
    of Tp actions, execute Ta of them starting at index To-1, then predict again."""

    def __init__(self, policy: DiffusionPolicy, scheduler: str | None = None, steps: int | None = None,
                 seed: int = 0) -> None:
        self.policy, self.scheduler, self.steps = policy.eval(), scheduler, steps
        self.generator = torch.Generator().manual_seed(seed)
        self.history: deque = deque(maxlen=policy.cfg.n_obs_steps)
        self.queue: deque = deque()
        self.chunks = 0

    def reset(self, seed: int | None = None) -> None:
        self.history.clear()
        self.queue.clear()
        if seed is not None:
            self.generator.manual_seed(seed)

    def act(self, obs: Mapping) -> np.ndarray:
        """obs {"rgb": {cam: (H, W, 3) uint8}, "state": (S,)} -> one action (A,) float32."""
        cfg = self.policy.cfg
        self.history.append(obs)
        while len(self.history) < cfg.n_obs_steps:
            self.history.appendleft(obs)
        if not self.queue:
            hist = list(self.history)
            batch = {"rgb": {c: torch.from_numpy(np.stack([o["rgb"][c] for o in hist]))[None] for c in cfg.cameras},
                     "state": torch.from_numpy(np.stack([np.asarray(o["state"], np.float32) for o in hist]))[None]}
            actions = self.policy.predict_action(batch, self.scheduler, self.steps, self.generator)[0].cpu().numpy()
            start = cfg.n_obs_steps - 1
            self.queue.extend(actions[start : start + cfg.n_action_steps])
            self.chunks += 1
        return np.asarray(self.queue.popleft(), np.float32)
