"""A world-model training step's forward and backward pass captured as CUDA graphs and replayed (`capture=true`).

Why: at the batch sizes of the paper (8 windows) a step on a GPU is bound by launching kernels from Python, not by
the GPU: a `paper` step launches ~6,100 small kernels whose GPU time is ~11-14% of its wall time on an H100 or
H200, and torch.compile (compile=true) removes only part of that (experiments/benchmarks/world_model_gpu.py). A
CUDA graph launches the whole forward and backward pass and the gradient clipping as one unit, so a step costs
about the kernels' own time. torch.compile(mode="reduce-overhead") would also use CUDA graphs, but only around what
it compiles as one graph, and the step's sequential RSSM steps with their backward make that slow to build; a
manual capture of the eager pass (torch.cuda.graph) needs no compiler and keeps eager's kernels.

A replay computes what train()'s eager step computes, to the bit where the GPU's kernels are deterministic:
  - the batch and the step's latent uniforms (drawn on the CPU from the step's generator, as the eager step draws
    them: RSSM.uniforms) are copied into the graph's fixed input tensors before each replay;
  - which time steps of a window reset the latent state decides the autograd graph (RSSM.observe blends in the
    initial state only there), and a capture cannot ask the device. The resets are read from the batch while it
    is still on the CPU, and each reset pattern gets its own graph (a window that starts an episode resets at its
    first step: real data has two patterns); a pattern beyond `max_graphs` runs eagerly. A single graph that
    always blends would compute the same values forward but sum the gradients' parts in another order, and the
    latent samples' argmax turns float32 rounding into different samples within a few steps;
  - Adam's update runs eagerly after the replay, on the graph's gradients: its bias correction is computed on the
    host as in eager training (a captured Adam needs capturable=True, whose float32 correction on the device
    differs in the last bits), for a handful of kernel launches per step;
  - batches of another shape (an epoch's last, shorter batch) run the eager step on the same optimizer.
Parameters and optimizer state keep their storage (the graphs read them in place), so checkpoints, resumes and
evaluation between steps see the trained weights as usual; nothing of this is saved.
Memory: each graph keeps its own pool for the pass's activations and gradients (a `paper` step peaked at 2.9 GB
with one graph on an H200, as eager does), so a run with both reset patterns holds about twice an eager step's
memory; `max_graphs` caps it. Pools are not shared between graphs: that would be safe only under replay-order
rules this class does not need to rely on.
"""

from __future__ import annotations

import torch

from simeval.errors import UserError
from simeval.runtime.device import to_device

def capture_needs_cuda(where: str) -> UserError:
    """The one error for capture=true without a GPU; `where`: what the device was, e.g. "device=auto resolves to cpu"."""
    fix = ("use capture=false or device=cuda" if torch.cuda.is_available() else
           "use capture=false (this machine has no CUDA GPU)")  # device=cuda would only fail next
    return UserError(f"capture=true needs a CUDA GPU ({where}); {fix}")


def training_device(device: str, capture: bool) -> torch.device:
    """resolve_device(device) (a bad value or a missing GPU is a UserError), and capture=true refused off CUDA."""
    from simeval.runtime.device import resolve_device

    resolved = resolve_device(device)
    if capture and resolved.type != "cuda":
        raise capture_needs_cuda(f"device={device} resolves to {resolved} here")
    return resolved


WARMUP_STEPS = 3  # eager steps on a side stream before the first capture: cuDNN's and cuBLAS's lazy set-up


class CapturedTrainStep:
    """One training step of `model` with `opt` (over model.parameters()) and global-norm clipping at `clip`. Call with
    a batch of CPU tensors (pinned, for copies that overlap) and the step's CPU generator; returns the metrics the
    eager step returns (its loss terms and grad_norm), read from the device once. With `capture`, the forward and
    backward pass of each reset pattern is captured (after WARMUP_STEPS eager steps) and replayed; without, the
    same step runs eagerly (what a CPU can check)."""

    def __init__(self, model, opt: torch.optim.Optimizer, clip: float, capture: bool = True,
                 max_graphs: int = 4) -> None:
        device = next(model.parameters()).device
        if capture and device.type != "cuda":
            raise capture_needs_cuda(f"the model is on {device}")
        self.model, self.opt, self.clip, self.capture, self.device = model, opt, clip, capture, device
        self.params = [p for group in opt.param_groups for p in group["params"]]
        self.max_graphs = max_graphs
        self.steps_done = 0
        self.graphs: dict[tuple, _Graph] = {}  # (shapes, resets) -> its graph
        self.names: list[str] = []

    def __call__(self, batch: dict[str, torch.Tensor], generator: torch.Generator) -> dict[str, float]:
        b, t = batch["is_first"].shape
        noise = self.model.rssm.uniforms(t, 2, b, generator)  # on the CPU, from the step's generator, as eagerly
        resets = tuple(batch["is_first"].any(0).tolist())  # on the CPU: no wait for the device
        key = (tuple((k, tuple(v.shape), v.dtype) for k, v in sorted(batch.items())), resets)
        graph = self.graphs.get(key)
        if graph is None and self.capture and self.steps_done >= WARMUP_STEPS and len(self.graphs) < self.max_graphs:
            graph = self.graphs[key] = self._capture(batch, noise, list(resets))
        if graph is not None:
            for k, v in batch.items():
                graph.inputs[k].copy_(v, non_blocking=True)
            graph.inputs["noise"].copy_(noise, non_blocking=True)
            graph.graph.replay()
            for p, g in zip(self.params, graph.grads):
                p.grad = g
            out = graph.outputs
        else:
            out = self._eager(to_device(batch, self.device, non_blocking=True), noise.to(self.device), list(resets))
        self.opt.step()
        self.steps_done += 1
        return dict(zip([*self.names, "grad_norm"], out.tolist()))

    def _eager(self, batch: dict, noise: torch.Tensor, resets: list[bool]) -> torch.Tensor:
        self.opt.zero_grad(set_to_none=True)
        if not self.capture or self.graphs:
            return self._forward_backward(batch, noise, resets)
        side = torch.cuda.Stream(self.device)  # warm-ups off the default stream, as torch.cuda.graph asks
        side.wait_stream(torch.cuda.current_stream(self.device))
        with torch.cuda.stream(side):
            out = self._forward_backward(batch, noise, resets)
        torch.cuda.current_stream(self.device).wait_stream(side)
        return out

    def _capture(self, batch: dict, noise: torch.Tensor, resets: list[bool]) -> _Graph:
        inputs = {k: torch.empty(v.shape, dtype=v.dtype, device=self.device) for k, v in batch.items()}
        inputs["noise"] = torch.empty(noise.shape, dtype=noise.dtype, device=self.device)
        self.opt.zero_grad(set_to_none=True)  # the capture's backward then makes this graph's own gradients
        graph = torch.cuda.CUDAGraph()
        # thread_local: a DataLoader's pin-memory thread may allocate host memory while this thread captures
        with torch.cuda.graph(graph, capture_error_mode="thread_local"):
            outputs = self._forward_backward({k: v for k, v in inputs.items() if k != "noise"}, inputs["noise"],
                                             resets)
        return _Graph(graph, inputs, outputs, [p.grad for p in self.params])

    def _forward_backward(self, batch: dict, noise: torch.Tensor, resets: list[bool]) -> torch.Tensor:
        """Loss, backward and clipping without reading the device; returns [loss terms..., grad_norm]."""
        loss, self.names, values = self.model.loss_terms(batch, noise=noise, resets=resets)
        loss.backward()
        grad_norm = torch.nn.utils.clip_grad_norm_(self.params, self.clip)
        return torch.cat([values, grad_norm.reshape(1).to(values.dtype)])


class _Graph:
    """A captured pass: its graph, fixed input tensors, output tensor and the gradients its backward writes."""

    def __init__(self, graph, inputs: dict, outputs: torch.Tensor, grads: list) -> None:
        self.graph, self.inputs, self.outputs, self.grads = graph, inputs, outputs, grads
