"""A DreamerV3-style latent world model (RSSM) with decoder heads only, for dynamics-based trajectory diversity
(paper Sec. 3.4 and 4.2, Table 4; Hafner et al. 2023).

The model, per step t of a window (B batch, T steps):
    h_t = GRU(h_{t-1}, MLP([z_{t-1}, a_{t-1}]))                 deterministic state (`deter`)
    prior      p(z_t | h_t)          = Cat(unimix(softmax(MLP(h_t))))
    posterior  q(z_t | h_t, e_t)     = Cat(unimix(softmax(MLP([h_t, e_t]))))   e_t = [CNN(image_t), MLP(symlog(state_t))]
    z_t: `stoch` categoricals of `classes` classes, a straight-through one-hot sample (forward: the one-hot; gradient:
         that of the probabilities); unimix(p) = (1 - u) p + u / classes with u = 0.01
    decoders from [z_t, h_t]: image mean (MSE, summed over pixels) and symlog(state) (MSE, summed over dimensions);
    with pixel_norm "standardise" the image enters, is drawn and is scored as z = (o - mu) / sd per pixel
Where `is_first` is set, (h, z) are reset to the learned initial state and a_{t-1} to zero before the step.
Actions enter as a / max(|a|, 1) (DreamerV3's bound), after the dataset has standardised them.

Loss per step (then averaged over the valid steps of the batch):
    image_se + state_se + 0.5 * max(1, KL[sg(q) || p]) + 0.1 * max(1, KL[q || sg(p)])
the KL terms summed over the `stoch` categoricals (dyn 0.5, rep 0.1, free nats 1.0). No reward or continuation
heads: the paper's authors removed them (their DreamerV3 fork is trained on trajectories without rewards).
These formulas were checked against NM512/dreamerv3-torch (networks.RSSM.kl_loss, tools.OneHotDist); the
architecture follows it with SiLU + LayerNorm everywhere, a layer-normed GRU with update bias -1, "same"-padded
stride-2 convolutions whose channels double per stage down to `minres`, and a learned initial state.

Input layout: a batch is a dict of tensors (B, T, ...): image uint8 (B, T, H, W, 3), state float (B, T, D),
prev_action float (B, T, A) (the action taken *before* observation t, i.e. the one that produced it; zero at an
episode's first row), is_first bool (B, T), mask bool (B, T) (False on padding). `simeval.episodes.dataset`
produces it from the store, whose row t holds o_t and the action a_t taken after it.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from dataclasses import asdict, dataclass, fields

import numpy as np
import torch
import torch.nn.functional as F
from einops import rearrange
from torch import nn

from simeval.errors import UserError, check_field_types, require_whole_fields
from simeval.runtime.device import module_device, to_device

VERSION = "1.0"
PIXEL_NORMS = ("none", "standardise")


@dataclass
class WorldModelConfig:
    image_size: int = 64  # square RGB frames, H = W; a power-of-two multiple of minres
    deter: int = 256  # GRU state size
    hidden: int = 256  # width of the RSSM's input/output layers
    stoch: int = 16  # number of categorical latents
    classes: int = 16  # classes per categorical
    cnn_depth: int = 16  # channels of the first conv stage; doubled per stage
    kernel: int = 4
    minres: int = 4  # the encoder stops (and the decoder starts) at minres x minres
    mlp_layers: int = 2  # state encoder / decoder
    mlp_units: int = 128
    unimix: float = 0.01
    free_nats: float = 1.0
    dyn_scale: float = 0.5
    rep_scale: float = 0.1
    image_scale: float = 1.0
    state_scale: float = 1.0
    # "none": frames in [0, 1] (the encoder sees o - 0.5, the decoder draws o), the loss their squared error;
    # "standardise": per pixel and channel z = (o - mu) / max(sd, pixel_std_floor) over the training frames
    # (set_pixel_stats): the encoder sees z, the decoder draws z (decoded frames mu + sd z), the loss is z's
    # squared error. Why: with "none" an object's pull on the loss scales with its area times its contrast
    # squared, and a small or faint one (a 2% disk) leaves the model on the mean image for 1,000s of steps
    # (README, "Dynamics diversity: why the model did not learn one disk")
    pixel_norm: str = "none"
    pixel_std_floor: float = 0.05

    def __post_init__(self) -> None:
        check_field_types(self, "world_model.model")
        require_whole_fields(self, "world_model.model", ("image_size", "deter", "hidden", "stoch", "classes", "cnn_depth",
                                                         "minres", "mlp_layers", "mlp_units"))
        if self.kernel < 2:
            raise UserError(f"world_model.model.kernel={self.kernel}: expected >= 2 (stride-2 convolutions)")
        ratio = self.image_size / self.minres
        if ratio < 2 or ratio != int(ratio) or int(ratio) & (int(ratio) - 1):
            raise UserError(f"world_model.model.image_size={self.image_size} with minres={self.minres}: image_size "
                            f"must be minres times a power of two >= 2 (e.g. 64 with minres 4)")
        if not 0.0 <= self.unimix < 1.0:
            raise UserError(f"world_model.model.unimix={self.unimix}: expected a fraction in [0, 1)")
        for name in ("free_nats", "dyn_scale", "rep_scale", "image_scale", "state_scale"):
            if getattr(self, name) < 0:
                raise UserError(f"world_model.model.{name}={getattr(self, name)}: expected >= 0")
        if self.pixel_norm not in PIXEL_NORMS:
            raise UserError(f"world_model.model.pixel_norm={self.pixel_norm!r}: expected one of "
                            f"{', '.join(PIXEL_NORMS)}")
        if not 0 < self.pixel_std_floor <= 1:
            raise UserError(f"world_model.model.pixel_std_floor={self.pixel_std_floor}: expected a deviation in (0, 1]")

    @property
    def stages(self) -> int:
        return int(round(math.log2(self.image_size // self.minres)))

    @classmethod
    def from_dict(cls, d: dict) -> WorldModelConfig:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise UserError(f"world_model: unknown key(s) {unknown}; valid: {sorted(known)}")
        return cls(**d)

    def to_dict(self) -> dict:
        return asdict(self)


def symlog(x: torch.Tensor) -> torch.Tensor:
    return torch.sign(x) * torch.log1p(x.abs())


def unimix_logits(logits: torch.Tensor, unimix: float) -> torch.Tensor:
    """log((1 - u) softmax(logits) + u / K): normalised log-probabilities with every class at least u / K."""
    probs = F.softmax(logits, -1)
    if unimix > 0:
        probs = (1.0 - unimix) * probs + unimix / logits.shape[-1]
    return torch.log(probs)


def straight_through_sample(logp: torch.Tensor, generator: torch.Generator | None = None,
                            uniform: torch.Tensor | None = None) -> torch.Tensor:
    """A one-hot sample of Cat(exp(logp)) (Gumbel-max, so a seeded generator reproduces it) whose gradient is that
    of the probabilities. `generator`: a CPU one; the uniforms are drawn on the CPU and moved to logp's device, so a
    seed gives the same samples on every device. `uniform`: those uniforms (logp's shape, on its device), drawn
    beforehand (RSSM.observe draws a whole window's at once: one host-to-device copy instead of one per step)."""
    u = torch.rand(logp.shape, generator=generator, dtype=logp.dtype).to(logp.device) if uniform is None else uniform
    gumbel = -torch.log((-torch.log(u.clamp_min(1e-20))).clamp_min(1e-20))
    one_hot = F.one_hot(torch.argmax(logp + gumbel, -1), logp.shape[-1]).to(logp.dtype)
    probs = logp.exp()
    return one_hot + probs - probs.detach()


def categorical_kl(logp: torch.Tensor, logq: torch.Tensor) -> torch.Tensor:
    """KL[p || q] of (..., S, K) log-probabilities, summed over the S categoricals -> (...)."""
    return (logp.exp() * (logp - logq)).sum((-2, -1))


def _fans(w: torch.Tensor) -> tuple[int, int]:
    space = int(w[0, 0].numel()) if w.dim() > 2 else 1
    return w.shape[1] * space, w.shape[0] * space  # (fan_in, fan_out); ConvTranspose2d's are swapped, as in the reference


def dreamer_init(module: nn.Module) -> None:
    """DreamerV3's initialiser: weights ~ truncated normal (2 std) with variance 1 / mean(fan_in, fan_out) (std
    divided by 0.8796, the truncation's shrinkage), biases 0. PyTorch's default gives ~3x smaller logits at the
    start, whose near-uniform categorical samples the decoder cannot use for hundreds of steps."""
    for m in module.modules():
        if isinstance(m, (nn.Linear, nn.Conv2d, nn.ConvTranspose2d)):
            fan_in, fan_out = _fans(m.weight)
            std = math.sqrt(2.0 / (fan_in + fan_out)) / 0.87962566103423978
            nn.init.trunc_normal_(m.weight, 0.0, std, -2.0 * std, 2.0 * std)
            if m.bias is not None:
                nn.init.zeros_(m.bias)


def uniform_init(layer: nn.Module, scale: float = 1.0) -> None:
    """DreamerV3's output layers: uniform with variance scale / mean(fan_in, fan_out), bias 0."""
    fan_in, fan_out = _fans(layer.weight)
    limit = math.sqrt(3.0 * scale * 2.0 / (fan_in + fan_out))
    nn.init.uniform_(layer.weight, -limit, limit)
    if layer.bias is not None:
        nn.init.zeros_(layer.bias)


def mlp(inp: int, units: int, layers: int, out: int | None = None) -> nn.Sequential:
    mods: list[nn.Module] = []
    for _ in range(layers):
        mods += [nn.Linear(inp, units, bias=False), nn.LayerNorm(units, eps=1e-3), nn.SiLU()]
        inp = units
    if out is not None:
        mods.append(nn.Linear(inp, out))
    return nn.Sequential(*mods)


class ChannelLayerNorm(nn.Module):
    """LayerNorm over the channels of (N, C, H, W) feature maps."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(channels, eps=1e-3)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return rearrange(self.norm(rearrange(x, "n c h w -> n h w c")), "n h w c -> n c h w")


class PixelNorm(nn.Module):
    """Per pixel and channel mean and deviation (H, W, 3) of the training frames (WorldModelConfig.pixel_norm);
    buffers, so a checkpoint carries them. Until set_pixel_stats: mean 0.5, deviation 1 (the "none" layout)."""

    def __init__(self, size: int) -> None:
        super().__init__()
        self.register_buffer("mean", torch.full((size, size, 3), 0.5))
        self.register_buffer("scale", torch.ones(size, size, 3))

    def to_z(self, image: torch.Tensor) -> torch.Tensor:
        return (image - self.mean) / self.scale

    def from_z(self, z: torch.Tensor) -> torch.Tensor:
        return self.mean + self.scale * z


class ConvEncoder(nn.Module):
    def __init__(self, cfg: WorldModelConfig) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        cin, cout = 3, cfg.cnn_depth
        pad = cfg.kernel - 2  # "same" padding of a stride-2 conv on an even size: total k - s
        for _ in range(cfg.stages):
            layers += [nn.ZeroPad2d((pad // 2, pad - pad // 2, pad // 2, pad - pad // 2)),
                       nn.Conv2d(cin, cout, cfg.kernel, stride=2, bias=False), ChannelLayerNorm(cout), nn.SiLU()]
            cin, cout = cout, cout * 2
        self.layers = nn.Sequential(*layers)
        self.out_dim = cin * cfg.minres**2

    def forward(self, image: torch.Tensor) -> torch.Tensor:  # (B, T, H, W, 3) in [0, 1] -> (B, T, E)
        b = image.shape[0]
        norm = self.__dict__.get("pixel_norm")  # the model's PixelNorm (not a submodule here: one copy of buffers)
        x = self.layers(rearrange(image - 0.5 if norm is None else norm.to_z(image), "b t h w c -> (b t) c h w"))
        return rearrange(x, "(b t) c h w -> b t (c h w)", b=b)


class ConvDecoder(nn.Module):
    def __init__(self, cfg: WorldModelConfig, feat_dim: int) -> None:
        super().__init__()
        self.minres = cfg.minres
        top = cfg.cnn_depth * 2 ** (cfg.stages - 1)
        self.linear = nn.Linear(feat_dim, top * cfg.minres**2)
        val = cfg.kernel - 2  # ConvTranspose2d doubling the size: padding ceil(val/2), output_padding 2*pad - val
        pad = (val + 1) // 2
        layers: list[nn.Module] = []
        cin = top
        for i in range(cfg.stages):
            last = i == cfg.stages - 1
            cout = 3 if last else cin // 2
            layers.append(nn.ConvTranspose2d(cin, cout, cfg.kernel, stride=2, padding=pad, output_padding=2 * pad - val,
                                             bias=last))
            if not last:
                layers += [ChannelLayerNorm(cout), nn.SiLU()]
            cin = cout
        self.layers = nn.Sequential(*layers)

    def forward(self, feat: torch.Tensor) -> torch.Tensor:  # (B, T, F) -> (B, T, H, W, 3), mean image
        b = feat.shape[0]
        x = rearrange(self.linear(feat), "b t (c h w) -> (b t) c h w", h=self.minres, w=self.minres)
        z = rearrange(self.layers(x), "(b t) c h w -> b t h w c", b=b)
        norm = self.__dict__.get("pixel_norm")
        return z + 0.5 if norm is None else norm.from_z(z)


class GRUCell(nn.Module):
    """DreamerV3's layer-normed GRU: update gate biased towards keeping the state (sigmoid(u - 1))."""

    def __init__(self, inp: int, size: int) -> None:
        super().__init__()
        self.layer = nn.Linear(inp + size, 3 * size, bias=False)
        self.norm = nn.LayerNorm(3 * size, eps=1e-3)

    def forward(self, x: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        reset, cand, update = self.norm(self.layer(torch.cat([x, h], -1))).chunk(3, -1)
        reset = torch.sigmoid(reset)
        cand = torch.tanh(reset * cand)
        update = torch.sigmoid(update - 1.0)
        return update * cand + (1.0 - update) * h


class RSSM(nn.Module):
    """States are dicts: deter (B, deter), stoch (B, S, K) one-hot (straight-through), logp (B, S, K)."""

    def __init__(self, cfg: WorldModelConfig, action_dim: int, embed_dim: int) -> None:
        super().__init__()
        self.cfg = cfg
        s, k = cfg.stoch, cfg.classes
        self.img_in = mlp(s * k + action_dim, cfg.hidden, 1)
        self.cell = GRUCell(cfg.hidden, cfg.deter)
        self.img_out = mlp(cfg.deter, cfg.hidden, 1)
        self.prior_head = nn.Linear(cfg.hidden, s * k)
        self.obs_out = mlp(cfg.deter + embed_dim, cfg.hidden, 1)
        self.post_head = nn.Linear(cfg.hidden, s * k)
        self.init_deter = nn.Parameter(torch.zeros(cfg.deter))

    def _logp(self, head: nn.Module, x: torch.Tensor) -> torch.Tensor:
        return unimix_logits(rearrange(head(x), "... (s k) -> ... s k", s=self.cfg.stoch), self.cfg.unimix)

    def initial(self, batch: int) -> dict[str, torch.Tensor]:
        deter = torch.tanh(self.init_deter).expand(batch, -1)
        logp = self._logp(self.prior_head, self.img_out(deter))
        mode = F.one_hot(logp.argmax(-1), self.cfg.classes).to(logp.dtype)
        return {"deter": deter, "stoch": mode + logp.exp() - logp.exp().detach(), "logp": logp}

    def img_step(self, prev: dict, prev_action: torch.Tensor, generator=None,
                 uniform: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        prev_action = prev_action / prev_action.abs().clamp_min(1.0).detach()
        x = self.img_in(torch.cat([rearrange(prev["stoch"], "b s k -> b (s k)"), prev_action], -1))
        deter = self.cell(x, prev["deter"])
        logp = self._logp(self.prior_head, self.img_out(deter))
        return {"deter": deter, "stoch": straight_through_sample(logp, generator, uniform), "logp": logp}

    def split_obs_layer(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The posterior MLP's first layer, bias-free and applied to cat(deter, embed), as its two blocks [W_d | W_e].
        Why: W_e @ embed can then be computed for a whole window in one matmul instead of once per step (the paper
        preset's W_e is 512 x 32,768, the largest cost of its training), and the weight is split once per window:
        a slice taken at every step gave each step's backward a zero-filled gradient the size of the weight."""
        layer = self.obs_out[0]
        return layer.weight.split([self.cfg.deter, layer.in_features - self.cfg.deter], 1)

    def uniforms(self, steps: int, draws: int, batch: int, generator=None, device=None) -> torch.Tensor:
        """(steps, draws, B, stoch, classes) uniforms for the latent samples of `steps` steps of `draws` samples each,
        drawn on the CPU in one call and moved to `device` in one copy. One call of torch.rand over the whole shape
        gives the same numbers as one call per sample in that order (tests/test_world_model.py checks it), so a
        window samples what step-by-step draws would; on a GPU a copy per step would wait for the queued work
        each time (a pageable host-to-device copy synchronises the stream)."""
        shape = (steps, draws, batch, self.cfg.stoch, self.cfg.classes)
        return torch.rand(shape, generator=generator).to(device)

    def obs_step(self, prev: dict, prev_action: torch.Tensor, embed_share: torch.Tensor, is_first: torch.Tensor,
                 deter_weight: torch.Tensor, generator=None, uniform: torch.Tensor | None = None,
                 reset: bool | None = None) -> tuple[dict, dict]:
        """One posterior step. `embed_share` is W_e @ embed and `deter_weight` W_d (split_obs_layer): the posterior
        layer's output is W_d @ deter + W_e @ embed = W @ cat(deter, embed). `uniform`: (2, B, S, K) uniforms for
        the prior's and then the posterior's sample (else drawn from `generator`). `reset`: whether any row of
        `is_first` is set, when the caller knows it without asking the device (else asked here, which on a GPU
        waits for the queued work)."""
        first = is_first.to(embed_share.dtype)[:, None]
        if bool(is_first.any()) if reset is None else reset:
            init = self.initial(len(first))
            prev = {"deter": prev["deter"] * (1 - first) + init["deter"] * first,
                    "stoch": prev["stoch"] * (1 - first[..., None]) + init["stoch"] * first[..., None]}
            prev_action = prev_action * (1 - first)
        prior = self.img_step(prev, prev_action, generator, None if uniform is None else uniform[0])
        hidden = F.linear(prior["deter"], deter_weight) + embed_share
        logp = self._logp(self.post_head, self.obs_out[1:](hidden))
        post = {"deter": prior["deter"], "stoch": straight_through_sample(logp, generator,
                                                                          None if uniform is None else uniform[1]),
                "logp": logp}
        return post, prior

    def observe(self, embed: torch.Tensor, prev_action: torch.Tensor, is_first: torch.Tensor, state=None,
                generator=None, noise: torch.Tensor | None = None,
                resets: list[bool] | None = None) -> tuple[dict, dict]:
        """Posterior and prior states over a window: each a dict of (B, T, ...). The window's latent noise is drawn
        at once and its resets read from the device once, so a GPU runs the window without waiting on the host.
        `noise`: the window's (T, 2, B, S, K) uniforms (`uniforms`), else drawn from `generator`. `resets`: per step,
        whether to blend in the initial state where is_first is set (else read from is_first); a step told True
        where no row resets computes the same values, since the blend is then x * 1 + init * 0 (what a CUDA graph,
        which cannot read the device mid-capture, relies on: simeval.runtime.captured)."""
        b, t = embed.shape[:2]
        if state is None:
            state = self.initial(b)
        posts, priors = [], []
        deter_weight, embed_weight = self.split_obs_layer()
        if noise is None:
            noise = self.uniforms(t, 2, b, generator, embed.device)
        if resets is None:
            resets = is_first.any(0).tolist()
        # unbind, not [:, i]: one gradient for the whole window instead of a zero-filled full-size one per step
        steps = zip(F.linear(embed, embed_weight).unbind(1), prev_action.unbind(1), is_first.unbind(1), noise, resets)
        for share, action, first, uniform, reset in steps:
            state, prior = self.obs_step(state, action, share, first, deter_weight, uniform=uniform, reset=reset)
            posts.append(state)
            priors.append(prior)
        stack = lambda seq: {k: torch.stack([s[k] for s in seq], 1) for k in seq[0]}  # noqa: E731
        return stack(posts), stack(priors)

    def imagine(self, prev_action: torch.Tensor, state: dict, generator=None) -> dict:
        """Prior states for (B, K, A) actions from a (B, ...) state, no observations."""
        out = []
        noise = self.uniforms(prev_action.shape[1], 1, prev_action.shape[0], generator, prev_action.device)
        for i in range(prev_action.shape[1]):
            state = self.img_step(state, prev_action[:, i], uniform=noise[i, 0])
            out.append(state)
        return {k: torch.stack([s[k] for s in out], 1) for k in out[0]}

    @staticmethod
    def features(state: dict) -> torch.Tensor:
        return torch.cat([rearrange(state["stoch"], "... s k -> ... (s k)"), state["deter"]], -1)


class WorldModel(nn.Module):
    def __init__(self, cfg: WorldModelConfig, state_dim: int, action_dim: int) -> None:
        super().__init__()
        if state_dim < 0 or action_dim < 1:
            raise UserError(f"world model needs action_dim >= 1 and state_dim >= 0, got {action_dim}, {state_dim}")
        self.cfg, self.state_dim, self.action_dim = cfg, state_dim, action_dim
        self.encoder = ConvEncoder(cfg)
        self.state_encoder = mlp(state_dim, cfg.mlp_units, cfg.mlp_layers) if state_dim else None
        embed_dim = self.encoder.out_dim + (cfg.mlp_units if state_dim else 0)
        self.rssm = RSSM(cfg, action_dim, embed_dim)
        feat = cfg.stoch * cfg.classes + cfg.deter
        self.image_decoder = ConvDecoder(cfg, feat)
        if cfg.pixel_norm == "standardise":
            self.pixel_norm = PixelNorm(cfg.image_size)
            for part in (self.encoder, self.image_decoder):
                part.__dict__["pixel_norm"] = self.pixel_norm
        self.state_decoder = mlp(feat, cfg.mlp_units, cfg.mlp_layers, out=state_dim) if state_dim else None
        dreamer_init(self)
        for out in (self.rssm.prior_head, self.rssm.post_head, self.image_decoder.layers[-1]):
            uniform_init(out)
        if self.state_decoder is not None:
            uniform_init(self.state_decoder[-1])

    def compile_steps(self) -> None:
        """torch.compile, in place, what a training step runs many times: the image encoder and decoder and the
        RSSM's per-step functions (img_step, obs_step), whose dozens of small kernels per step the compiler fuses.
        Why: on a GPU a step at batch 8 is bound by launching kernels from Python, not by the GPU (the kernels of a
        `paper` step take ~13% of its wall time on an H100; experiments/benchmarks/world_model_gpu.py). The
        parameters and state_dict keys are unchanged (nn.Module.compile), so checkpoints are the same either way;
        numbers differ from eager ones at float32 rounding, as they do between devices. The first steps wait for the
        compiler (~40 s on an H100 host), and a batch of another size compiles once more (shapes then turn dynamic)."""
        self.encoder.compile()
        self.image_decoder.compile()
        self.rssm.img_step = torch.compile(self.rssm.img_step)
        self.rssm.obs_step = torch.compile(self.rssm.obs_step)

    @staticmethod
    @contextlib.contextmanager
    def compile_failures_named(enabled: bool = True) -> Iterator[None]:
        """A failure of torch.compile's dynamo or inductor inside the block (no working C++ compiler, an unsupported
        operation on this torch) becomes a UserError saying to run without compile, instead of a long traceback
        after the first step; other errors pass as they are."""
        try:
            yield
        except Exception as e:  # noqa: BLE001 - only the compiler's own errors are translated, the rest re-raised
            where = type(e).__module__
            if not enabled or not where.startswith(("torch._dynamo", "torch._inductor")):
                raise
            first = (str(e).strip().splitlines() or [""])[0][:200]
            raise UserError(f"compile=true: torch.compile could not build the model's steps ({type(e).__name__}: "
                            f"{first}); run with compile=false") from e

    @torch.no_grad()
    def set_pixel_stats(self, mean: np.ndarray, std: np.ndarray) -> None:
        """The training frames' per pixel and channel mean and deviation (H, W, 3) in [0, 1] (pixel_norm
        "standardise"; the deviation floored at pixel_std_floor so a pixel that never changes does not weigh
        without bound)."""
        if self.cfg.pixel_norm != "standardise":
            return
        self.pixel_norm.mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
        self.pixel_norm.scale.copy_(torch.as_tensor(std, dtype=torch.float32).clamp_min(self.cfg.pixel_std_floor))

    def n_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())

    def embed(self, image: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        e = self.encoder(image)
        if self.state_encoder is not None:
            e = torch.cat([e, self.state_encoder(symlog(state))], -1)
        return e

    @staticmethod
    def _images(batch: dict) -> torch.Tensor:
        image = batch["image"]
        return image.float() / 255.0 if image.dtype == torch.uint8 else image

    def step_errors(self, batch: dict, generator=None, noise: torch.Tensor | None = None,
                    resets: list[bool] | None = None) -> dict[str, torch.Tensor]:
        """Per-step (B, T) terms of the loss: image_se (squared error summed over pixels and channels, images in
        [0, 1]; a batch that carries `robot_mask` (B, T, H, W) leaves those pixels out), state_se (summed over dimensions, symlog space), kl_dyn = KL[sg(q) || p], kl_rep = KL[q || sg(p)]
        (their values are equal; the two differ only in where gradients flow). `noise`, `resets`: RSSM.observe's."""
        image = self._images(batch)
        post, prior = self.rssm.observe(self.embed(image, batch["state"]), batch["prev_action"], batch["is_first"],
                                        generator=generator, noise=noise, resets=resets)
        feat = self.rssm.features(post)
        if self.cfg.pixel_norm == "standardise":  # the loss in standardised units (WorldModelConfig.pixel_norm)
            se = (self.image_decoder(feat) - image).div(self.pixel_norm.scale).pow(2)
        else:
            se = (self.image_decoder(feat) - image).pow(2)
        robot = batch.get("robot_mask")
        if robot is not None:  # pixels the robot covers carry no loss: the model spends nothing on its looks
            se = se * (~robot.bool()).to(se.dtype)[..., None]
        out = {"image_se": se.sum((-3, -2, -1))}
        if self.state_decoder is not None:
            out["state_se"] = (self.state_decoder(feat) - symlog(batch["state"])).pow(2).sum(-1)
        else:
            out["state_se"] = torch.zeros_like(out["image_se"])
        out["kl_dyn"] = categorical_kl(post["logp"].detach(), prior["logp"])
        out["kl_rep"] = categorical_kl(post["logp"], prior["logp"].detach())
        return out

    def loss(self, batch: dict, generator=None) -> tuple[torch.Tensor, dict[str, float]]:
        loss, names, values = self.loss_terms(batch, generator)
        # one copy to the host for all of them: on a GPU each float() would wait for the device
        return loss, dict(zip(names, values.tolist()))

    def loss_terms(self, batch: dict, generator=None, noise: torch.Tensor | None = None,
                   resets: list[bool] | None = None) -> tuple[torch.Tensor, list[str], torch.Tensor]:
        """The training loss and its terms (names, one detached tensor of their batch means) left on the device."""
        c = self.cfg
        e = self.step_errors(batch, generator, noise, resets)
        mask = batch["mask"].to(e["image_se"].dtype)
        n = mask.sum().clamp_min(1.0)
        per_step = (c.image_scale * e["image_se"] + c.state_scale * e["state_se"]
                    + c.dyn_scale * e["kl_dyn"].clamp_min(c.free_nats) + c.rep_scale * e["kl_rep"].clamp_min(c.free_nats))
        loss = (per_step * mask).sum() / n
        values = torch.stack([*((v.detach() * mask).sum() / n for v in e.values()), loss.detach()])
        return loss, [*e, "loss"], values

    def _open_loop(self, image: torch.Tensor, batch: dict, context: int, generator=None) -> tuple[dict, dict]:
        """Posterior states of the first `context` steps and the prior states imagined after them from the actions
        alone (each a dict of (B, steps, ...)); the generator draws for the context first, then for imagination."""
        sl = slice(0, context)
        post, _ = self.rssm.observe(self.embed(image[:, sl], batch["state"][:, sl]), batch["prev_action"][:, sl],
                                    batch["is_first"][:, sl], generator=generator)
        last = {k: v[:, -1] for k, v in post.items()}
        return post, self.rssm.imagine(batch["prev_action"][:, context:], last, generator)

    @torch.no_grad()
    def open_loop_errors(self, batch: dict, context: int, generator=None) -> dict[str, torch.Tensor]:
        """Observe the first `context` steps, then imagine the rest from the actions alone and decode the prior:
        per-step (B, T - context) image_se and state_se of the imagined frames."""
        image = self._images(batch)
        _, prior = self._open_loop(image, batch, context, generator)
        feat = self.rssm.features(prior)
        out = {"image_se": (self.image_decoder(feat) - image[:, context:]).pow(2).sum((-3, -2, -1))}
        if self.state_decoder is not None:
            out["state_se"] = (self.state_decoder(feat) - symlog(batch["state"][:, context:])).pow(2).sum(-1)
        return out

    @torch.no_grad()
    def open_loop_images(self, batch: dict, context: int, generator=None) -> torch.Tensor:
        """(B, T, H, W, 3) mean images (not clamped): steps < context decoded from the posterior of the observed
        frames, steps >= context imagined from the actions alone, the frames `open_loop_errors` scores (the same
        generator seed gives the same samples)."""
        post, prior = self._open_loop(self._images(batch), batch, context, generator)
        return torch.cat([self.image_decoder(self.rssm.features(post)), self.image_decoder(self.rssm.features(prior))],
                         1)

    @torch.no_grad()
    def reconstruct(self, batch: dict, generator=None) -> torch.Tensor:
        """Posterior reconstructions (B, T, H, W, 3) in [0, 1] (for figures)."""
        image = self._images(batch)
        post, _ = self.rssm.observe(self.embed(image, batch["state"]), batch["prev_action"], batch["is_first"],
                                    generator=generator)
        return self.image_decoder(self.rssm.features(post)).clamp(0, 1)


IMAGINED_GAP_RGB = (220, 40, 40)  # the separators of open_loop_video while the open-loop panel is imagined


def open_loop_video(model: WorldModel, window: dict, context: int, seed: int = 0, gap: int = 2) -> np.ndarray:
    """One window as three panels side by side, a (T, H, 3 W + 2 gap, 3) uint8 array (T: the window's real rows):
        ground truth | posterior reconstruction (every frame observed) | open loop (the first `context` frames
        observed, the rest imagined from the actions alone)
    The separators are white while the open-loop panel shows observed frames and red once it shows imagined ones.
    `window`: a window of a WindowDataset (arrays (T, ...): image uint8, state, prev_action, is_first, mask), with or
    without a batch axis of one. Samples come from generators seeded with `seed`: the imagined frames are those that
    `open_loop_errors` scores with a generator of the same seed. The model runs where it is."""
    from simeval.media import side_by_side

    batch = {k: torch.as_tensor(np.asarray(window[k])) for k in ("image", "state", "prev_action", "is_first", "mask")}
    if batch["image"].dim() == 4:  # one window without a batch axis
        batch = {k: v[None] for k, v in batch.items()}
    if batch["image"].shape[0] != 1:
        raise ValueError(f"expected one window, got a batch of {batch['image'].shape[0]}")
    length = batch["image"].shape[1]
    if not 1 <= context < length:
        raise UserError(f"eval.context={context}: expected 1 <= context < window length ({length})")
    on_device = to_device(batch, module_device(model))
    recon = model.reconstruct(on_device, generator=torch.Generator().manual_seed(int(seed))).cpu()
    imagined = model.open_loop_images(on_device, context, generator=torch.Generator().manual_seed(int(seed))).cpu()

    def to_uint8(x: torch.Tensor) -> np.ndarray:
        return (x[0].clamp(0, 1) * 255).round().to(torch.uint8).numpy()

    image = batch["image"]
    truth = image[0].numpy() if image.dtype == torch.uint8 else to_uint8(image)  # float images are in [0, 1]
    real = batch["mask"][0].numpy().astype(bool)
    colors = np.where((np.arange(length) >= context)[:, None], IMAGINED_GAP_RGB, 255).astype(np.uint8)
    return side_by_side([truth[real], to_uint8(recon)[real], to_uint8(imagined)[real]], gap=gap,
                        gap_colors=colors[real])
