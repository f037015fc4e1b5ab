"""The networks of the CNN Diffusion Policy (Chi et al., 2023), written for simeval.

    ImageEncoder: (N, 3, H, W) float in [0, 1] -> (N, feature_dim). A ResNet-18 layout (stem, 4 stages of 2 basic
        blocks, widths w, 2w, 4w, 8w) trained from scratch, GroupNorm instead of BatchNorm (EMA weights and
        BatchNorm statistics do not mix; the official code makes the same swap), spatial-softmax pooling to
        `keypoints` expected (x, y) positions, and a linear layer (robomimic's VisualCore, which the official
        hybrid-image policy uses).
    ConditionalUnet1D: noisy action sequence (B, T, A), diffusion step (B,), global condition (B, C) -> the
        predicted noise (B, T, A). Residual 1-D conv blocks whose features are scaled and shifted by the condition
        (FiLM), downsampled by 2 between levels and upsampled back with skip connections.
"""

from __future__ import annotations

import math

import torch
from einops import rearrange
from torch import nn
from torch.nn import functional as F

from simeval.errors import UserError


def group_norm(channels: int, groups: int = 8) -> nn.GroupNorm:
    """GroupNorm with `groups` groups, or fewer when the channel count is not a multiple (a narrow stage)."""
    g = math.gcd(channels, groups)
    return nn.GroupNorm(g, channels)


class BasicBlock(nn.Module):
    def __init__(self, c_in: int, c_out: int, stride: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_out, 3, stride, 1, bias=False)
        self.norm1 = group_norm(c_out, max(c_out // 16, 1))  # the official swap: num_groups = channels // 16
        self.conv2 = nn.Conv2d(c_out, c_out, 3, 1, 1, bias=False)
        self.norm2 = group_norm(c_out, max(c_out // 16, 1))
        self.skip = (nn.Sequential(nn.Conv2d(c_in, c_out, 1, stride, bias=False), group_norm(c_out, max(c_out // 16, 1)))
                     if stride != 1 or c_in != c_out else nn.Identity())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.norm1(self.conv1(x)))
        y = self.norm2(self.conv2(y))
        return F.relu(y + self.skip(x))


class SpatialSoftmax(nn.Module):
    """(N, C, H, W) -> (N, 2K): a 1x1 conv to K maps, a softmax over each map's pixels, and the expected (x, y) of
    each map in [-1, 1] coordinates (Levine et al., 2016; robomimic's SpatialSoftmax)."""

    def __init__(self, channels: int, keypoints: int) -> None:
        super().__init__()
        self.proj = nn.Conv2d(channels, keypoints, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h, w = x.shape[-2:]
        attn = torch.softmax(rearrange(self.proj(x), "n k h w -> n k (h w)"), dim=-1)
        ys, xs = torch.meshgrid(torch.linspace(-1, 1, h, device=x.device), torch.linspace(-1, 1, w, device=x.device),
                                indexing="ij")
        grid = torch.stack([xs.reshape(-1), ys.reshape(-1)], dim=-1)  # (h*w, 2)
        return rearrange(attn @ grid, "n k xy -> n (k xy)")


class ImageEncoder(nn.Module):
    def __init__(self, width: int = 64, keypoints: int = 32, feature_dim: int = 64, stem_pool: bool = True) -> None:
        super().__init__()
        widths = [width, 2 * width, 4 * width, 8 * width]
        self.stem = nn.Sequential(nn.Conv2d(3, width, 7, 2, 3, bias=False), group_norm(width, max(width // 16, 1)),
                                  nn.ReLU(), nn.MaxPool2d(3, 2, 1) if stem_pool else nn.Identity())
        stages, c_in = [], width
        for i, c in enumerate(widths):
            stages += [BasicBlock(c_in, c, 1 if i == 0 else 2), BasicBlock(c, c, 1)]
            c_in = c
        self.stages = nn.Sequential(*stages)
        self.pool = SpatialSoftmax(widths[-1], keypoints)
        self.out = nn.Linear(2 * keypoints, feature_dim)
        self.feature_dim = feature_dim

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.out(self.pool(self.stages(self.stem(x))))


def random_crop(x: torch.Tensor, size: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """(N, C, H, W) -> (N, C, size, size), each image cropped at its own uniformly drawn offset. The offsets are
    drawn on the CPU (a CPU `generator`) and moved to x's device: the same crops on every device."""
    n, _, h, w = x.shape
    top = torch.randint(0, h - size + 1, (n,), generator=generator).to(x.device)
    left = torch.randint(0, w - size + 1, (n,), generator=generator).to(x.device)
    ar = torch.arange(size, device=x.device)
    rows = (top[:, None] + ar)[:, :, None]  # (N, size, 1)
    cols = (left[:, None] + ar)[:, None, :]  # (N, 1, size)
    batch = torch.arange(n, device=x.device)[:, None, None]
    return rearrange(x.permute(0, 2, 3, 1)[batch, rows, cols], "n h w c -> n c h w")


def center_crop(x: torch.Tensor, size: int) -> torch.Tensor:
    h, w = x.shape[-2:]
    top, left = (h - size) // 2, (w - size) // 2
    return x[..., top : top + size, left : left + size]


class SinusoidalEmbedding(nn.Module):
    def __init__(self, dim: int) -> None:
        super().__init__()
        self.dim = dim

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        half = self.dim // 2
        freqs = torch.exp(-math.log(10000) * torch.arange(half, device=t.device) / (half - 1))
        args = t.float()[:, None] * freqs[None]
        return torch.cat([args.sin(), args.cos()], dim=-1)


class ConvBlock1d(nn.Sequential):
    def __init__(self, c_in: int, c_out: int, kernel: int, groups: int) -> None:
        super().__init__(nn.Conv1d(c_in, c_out, kernel, padding=kernel // 2), group_norm(c_out, groups), nn.Mish())


class FiLMResBlock1d(nn.Module):
    """conv block -> out * scale(cond) + bias(cond) -> conv block, plus a residual (1x1 conv if widths differ)."""

    def __init__(self, c_in: int, c_out: int, cond_dim: int, kernel: int, groups: int) -> None:
        super().__init__()
        self.block1 = ConvBlock1d(c_in, c_out, kernel, groups)
        self.block2 = ConvBlock1d(c_out, c_out, kernel, groups)
        self.film = nn.Sequential(nn.Mish(), nn.Linear(cond_dim, 2 * c_out))
        self.skip = nn.Conv1d(c_in, c_out, 1) if c_in != c_out else nn.Identity()

    def forward(self, x: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        scale, bias = rearrange(self.film(cond), "b (two c) -> two b c 1", two=2)
        y = self.block1(x) * scale + bias
        return self.block2(y) + self.skip(x)


class ConditionalUnet1D(nn.Module):
    def __init__(self, action_dim: int, cond_dim: int, down_dims: list[int] = (256, 512, 1024),
                 step_embed_dim: int = 128, kernel_size: int = 5, n_groups: int = 8) -> None:
        super().__init__()
        if not down_dims:
            raise UserError("policy.down_dims must list at least one width, got []")
        dims = [action_dim, *down_dims]
        self.step_encoder = nn.Sequential(SinusoidalEmbedding(step_embed_dim), nn.Linear(step_embed_dim, 4 * step_embed_dim),
                                          nn.Mish(), nn.Linear(4 * step_embed_dim, step_embed_dim))
        c = step_embed_dim + cond_dim
        levels = list(zip(dims[:-1], dims[1:]))
        self.down = nn.ModuleList()
        for i, (a, b) in enumerate(levels):
            last = i == len(levels) - 1
            self.down.append(nn.ModuleList([FiLMResBlock1d(a, b, c, kernel_size, n_groups),
                                            FiLMResBlock1d(b, b, c, kernel_size, n_groups),
                                            nn.Conv1d(b, b, 3, 2, 1) if not last else nn.Identity()]))
        mid = dims[-1]
        self.mid = nn.ModuleList([FiLMResBlock1d(mid, mid, c, kernel_size, n_groups) for _ in range(2)])
        self.up = nn.ModuleList()
        for a, b in reversed(levels[1:]):
            self.up.append(nn.ModuleList([FiLMResBlock1d(2 * b, a, c, kernel_size, n_groups),
                                          FiLMResBlock1d(a, a, c, kernel_size, n_groups),
                                          nn.ConvTranspose1d(a, a, 4, 2, 1)]))
        self.final = nn.Sequential(ConvBlock1d(down_dims[0], down_dims[0], kernel_size, n_groups),
                                   nn.Conv1d(down_dims[0], action_dim, 1))
        self.n_down = len(levels) - 1  # how many times the sequence is halved

    def forward(self, sample: torch.Tensor, timestep: torch.Tensor, global_cond: torch.Tensor) -> torch.Tensor:
        """sample (B, T, A), timestep (B,) or scalar, global_cond (B, C) -> (B, T, A)."""
        x = rearrange(sample, "b t a -> b a t")
        t = timestep if torch.is_tensor(timestep) else torch.tensor(timestep, device=sample.device)
        t = t.to(sample.device).reshape(-1).expand(sample.shape[0])  # a sampler's timesteps are on the CPU
        cond = torch.cat([self.step_encoder(t), global_cond], dim=-1)
        skips = []
        for res1, res2, down in self.down:
            x = res2(res1(x, cond), cond)
            skips.append(x)
            x = down(x)
        for block in self.mid:
            x = block(x, cond)
        for res1, res2, up in self.up:
            x = torch.cat([x, skips.pop()], dim=1)
            x = up(res2(res1(x, cond), cond))
        return rearrange(self.final(x), "b a t -> b t a")
