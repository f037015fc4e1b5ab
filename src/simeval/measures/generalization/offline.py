r"""Train a Diffusion Policy where the simulator is not (a GPU machine), and score it on held-out demonstrations.

    python src/generalization_tools.py offline pack --out pack.pt [generalization.py's overrides ...]
        e.g. pack --out .gpu/piles.pt pipeline=gensim_own pipeline.root=$GENSIM_ROOT policy=authors_gensim \
             task_group=piles episodes_per_task=40
    python src/generalization_tools.py offline train --pack pack.pt --out train.json [--device cuda] \
        [--checkpoint-dir outputs/policies] [--steps N] [--seed S]
    python src/generalization_tools.py offline score --pack pack.pt \
        --checkpoint outputs/policies/<key>/last.ckpt --out score.json
    python src/generalization_tools.py offline export --checkpoint C --out-dir D [--part-mib 15.8]  # GPU machine
    python src/generalization_tools.py offline import --manifest D/weights.json --checkpoint-dir outputs/policies

Why: Table 5's rollouts need the simulator (PyBullet, a GenSim checkout), which a GPU machine may lack (one we used
had no PyBullet wheel for its Python and took files 64 MiB at a time). `pack` composes conf/generalization.yaml with the
given overrides and reads the store exactly as `src/generalization.py` does (simeval.measures.generalization.run.
training_data: the same episodes, tasks in the same order, the same PolicyDataset), keeping only the training steps
(for pick/place one per primitive: a few MB), plus the episodes after the first episodes_per_task of each trained
task (same selection: successful only where demonstrations=successful) as held-out demonstrations no model trained
on. `train` runs the product's own `train_policy` on them; with --checkpoint-dir it writes
<checkpoint-dir>/<key>/last.ckpt under the key `src/generalization.py` gives the same data and settings, so that run
(same overrides, checkpoint_dir=<checkpoint-dir>) reuses the weights and only rolls out. `score` reads any checkpoint
on the pack's held-out steps, so policies trained anywhere are compared window for window.

`export` + `import` bring a finished training back where its whole checkpoint cannot travel (the authors' GenSim size
holds 71M parameters: 1.4 GB with the optimiser; that machine returned at most 64 MiB per command): `export` keeps only
the EMA weights, the config and the training's curve, stores the large tensors (>= ROUND_MIN_NUMEL elements: the conv
and linear weights, nearly all the bytes) as float16 and the rest (biases, norms, the normalisers' ranges) as float32,
packs it (pack_bytes: 15% smaller) and splits it into parts of at most --part-mib with a manifest of SHA-256 sums;
`import` checks every part, joins them and writes <checkpoint-dir>/<key>/last.ckpt, which src/generalization.py reuses
as a finished training (simeval.models.diffusion_policy.finished_weights) and whose result.json says what was rounded.
`score` on both sides of the rounding says what it costs. What to keep in mind: `train` writes a checkpoint only with
--checkpoint-dir (without it there is nothing to export); `export` takes the checkpoint inside its <key>/ folder (the
key names where `import` puts it) and refuses an unfinished training (rerun `train` with the same --pack, --seed and
--steps to finish it: other values are another key) and a folder that holds an earlier export; `import --checkpoint-dir`
must be the `checkpoint_dir=` that src/generalization.py is given, with the pack's overrides.

Held-out score, per window w (one step of a held-out demonstration; the policy sees its observation):
    e_w = mean over (executed steps, action dims) of (norm(a_pred) - norm(a_demo))^2, in the policy's
          normalised units ([-1, 1] over the training data's range)
    reported: mean_w e_w with a 95% percentile bootstrap over held-out episodes (windows of one episode move
    together), per task, for the DDPM sampler (all steps) and the preset's own, beside a trivial baseline that
    predicts the training actions' mean. It says how well the policy imitates unseen demonstrations of its tasks;
    it is not Table 5's success rate, which only rollouts give.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import logging
import pickle
import re
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import torch

from simeval.cli import OneLineParser, composition_error_line
from simeval.config_schemas import GeneralizationConfig, check_values
from simeval.errors import UserError
from simeval.runtime.device import describe_device
from simeval.results import atomic_path, atomic_write_text, dumps_strict

PACK_FORMAT = 2
WEIGHTS_FORMAT = 1
KEY = re.compile(r"[0-9a-f]{16}")  # simeval.measures.generalization.run.checkpoint_key's form
PART = re.compile(r"weights\.part\d{2,}")
ROUND_MIN_NUMEL = 4096  # tensors this large travel as float16; smaller ones (biases, norms, normalisers) as float32


def compose_generalization(overrides: list[str], conf_dir: Path) -> dict:
    """<conf_dir>/generalization.yaml (the entrypoint's conf/) with `overrides`, resolved, as src/generalization.py
    sees it (no Hydra run)."""
    from hydra import compose, initialize_config_dir
    from hydra.errors import HydraException
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    try:
        with initialize_config_dir(str(Path(conf_dir).resolve()), version_base="1.3"):
            cfg = compose(config_name="generalization", overrides=list(overrides))
        return OmegaConf.to_container(cfg, resolve=True)
    except (HydraException, OmegaConfBaseException) as e:  # a bad override: the entrypoint's one line
        raise UserError(f"overrides {' '.join(overrides)}: {composition_error_line(e)}") from None


def pack(a) -> None:
    from omegaconf import OmegaConf

    from simeval.episodes.store import EpisodeStore, read_episode
    from simeval.measures.generalization.data import PolicyDataset
    from simeval.measures.generalization.run import (PolicyData, PolicyTraining, checkpoint_key,
                                                     demonstration_paths, names, training_data)
    from simeval.pipelines.registry import pipeline_from_config

    cfg = compose_generalization(a.overrides, a.conf_dir)
    check_values(OmegaConf.create(cfg), GeneralizationConfig)  # as src/generalization.py does
    if Path(a.out).is_dir():
        raise UserError(f"--out {a.out}: is a folder; give the pack's file name (e.g. {Path(a.out) / 'pack.pt'})")
    if cfg["policy"]["name"] == "random":
        raise UserError("policy=random trains nothing: pack a trained preset (policy=cpu, authors_gensim, ...)")
    pipeline = pipeline_from_config(cfg["pipeline"])
    specs, heldout = pipeline.group_and_heldout(cfg["task_group"], cfg["tasks"], names(cfg["heldout_tasks"]))
    trained = [s.name for s in specs if s.name not in heldout]
    k, seed = cfg["episodes_per_task"], cfg["seed"]
    training = PolicyTraining(cfg["policy"]["model"], cfg["policy"]["train"], seed, cfg["store"], k,
                              cfg["val_episodes_per_task"], cfg["demonstrations"])
    pcfg, settings, data, _, _, metas = training_data(PolicyData(pipeline.name, specs, trained, training,
                                                                 pipeline.collect_hint()))
    store = EpisodeStore(cfg["store"])
    held = [(task, p) for task in trained  # what follows the first k: no policy trained at this k saw it
            for p in demonstration_paths(store, pipeline.name, task, cfg["demonstrations"])[k:]]
    if not held:
        raise UserError(f"store {store.root}: no episode after the first episodes_per_task={k} of any trained task, "
                        f"so nothing is held out to score on; collect more (episodes={k + 5} or more)")
    held_episodes = [read_episode(p, list(pcfg.cameras), "policy.model.cameras") for _, p in held]
    held_data = PolicyDataset(held_episodes, pcfg.action_space, pcfg.cameras, pcfg.image_size, pcfg.horizon,
                              pcfg.n_obs_steps)
    key = checkpoint_key(metas, vars(pcfg), vars(settings), seed)
    out = {"format": PACK_FORMAT, "config": cfg, "pipeline": pipeline.name, "task_group": cfg["task_group"],
           "trained_tasks": trained, "episodes_per_task": k, "demonstrations": cfg["demonstrations"],
           "policy_name": cfg["policy"]["name"], "policy_config": vars(pcfg), "train_settings": vars(settings),
           "seed": seed, "metas": metas, "checkpoint_key": key, "train": data.arrays(), "heldout": held_data.arrays(),
           "heldout_episodes": [str(p.relative_to(store.root)) for _, p in held],
           "heldout_tasks": [task for task, _ in held]}
    with atomic_path(a.out) as tmp:  # a killed pack leaves no half file under the name
        torch.save(out, tmp)
    print(f"packed {len(data)} training steps of {len(metas)} episodes ({', '.join(trained)}) and {len(held_data)} "
          f"held-out steps of {len(held)} episodes into {a.out} ({Path(a.out).stat().st_size / 2**20:.1f} MiB); "
          f"policy {cfg['policy']['name']} seed {seed}: checkpoint key {key}")


def set_threads(threads: int | None, p: dict) -> None:
    """--threads, else the pack's torch_threads (the entrypoint's), else torch's default: on the CPU the sums, and so
    the weights and scores, follow the count in the last bits."""
    threads = threads if threads is not None else p["config"].get("torch_threads")
    if threads is not None:
        torch.set_num_threads(threads)


def writable_file(path: str, flag: str) -> None:
    """Before any work: `flag`'s file can be written (not a folder; its folder made if missing)."""
    target = Path(path)
    if target.is_dir():
        raise UserError(f"{flag} {path}: is a folder; give a file name (e.g. {target / 'out.json'})")
    if target.parent.exists() and not target.parent.is_dir():
        raise UserError(f"{flag} {path}: {target.parent} is a file, not a folder")
    target.parent.mkdir(parents=True, exist_ok=True)


def folder_or_absent(path: str, flag: str) -> None:
    if Path(path).exists() and not Path(path).is_dir():
        raise UserError(f"{flag} {path}: is a file; give a folder (it is made if missing)")


def load_pack(path: str) -> dict:
    if not Path(path).is_file():
        what = "a folder, not a pack file" if Path(path).is_dir() else "no such file"
        raise UserError(f"--pack {path}: {what} (make one with: python src/generalization_tools.py offline pack ...)")
    try:
        p = torch.load(path, weights_only=False)
    except (pickle.UnpicklingError, RuntimeError, EOFError, OSError) as e:
        raise UserError(f"--pack {path}: not readable as a pack ({type(e).__name__}); remake it with the pack "
                        "command") from None
    if not isinstance(p, dict) or p.get("format") != PACK_FORMAT:
        raise UserError(f"--pack {path}: not a pack of format {PACK_FORMAT} (remake it with the pack command)")
    return p


def datasets(p: dict):
    from simeval.measures.generalization.data import PolicyDataset

    def build(x):
        return PolicyDataset.from_arrays(x["rgb"], x["state"], x["action"], x["lengths"],
                                         p["policy_config"]["horizon"], p["policy_config"]["n_obs_steps"])
    return build(p["train"]), build(p["heldout"])


def heldout_score(policy, train, held, tasks: list[str], samplers: dict, seed: int = 0, chunk: int = 256) -> dict:
    """The module docstring's e_w per sampler, with the train-mean baseline, each with a bootstrap over episodes."""
    from simeval.stats.bootstrap import bootstrap_ci
    from simeval.runtime.device import module_device

    cfg = policy.cfg
    sl = slice(cfg.n_obs_steps - 1, cfg.n_obs_steps - 1 + cfg.n_action_steps)
    episode = held.starts[:, 0]
    rows = np.arange(len(held))
    batches = [held.window(rows[i:i + chunk]) for i in range(0, len(rows), chunk)]
    device = module_device(policy)
    with torch.no_grad():
        target = torch.cat([policy.action_norm(b["action"].float().to(device)) for b in batches])[:, sl].cpu()
        mean_action = policy.action_norm(train.action.float().to(device)).mean(0).cpu()
        errors = {"train_mean_baseline": ((mean_action - target) ** 2).mean(dim=(1, 2)).numpy()}
        for label, (kind, steps) in samplers.items():
            gen = torch.Generator().manual_seed(seed)  # the same noise for each sampler's first chunk
            preds = [policy.action_norm(policy.predict_action(b, kind, steps, gen)).cpu() for b in batches]
            errors[label] = ((torch.cat(preds)[:, sl] - target) ** 2).mean(dim=(1, 2)).numpy()
    episodes = np.unique(episode)
    members = [np.flatnonzero(episode == e) for e in episodes]

    def summary(e: np.ndarray) -> dict:
        ci = bootstrap_ci(lambda idx: float(np.concatenate([e[members[i]] for i in idx]).mean()), len(episodes))
        by_task = {}
        for t in dict.fromkeys(tasks):
            mask = np.isin(episode, [i for i, name in enumerate(tasks) if name == t])
            by_task[t] = float(e[mask].mean())
        return {"mse": float(e.mean()), "ci95": ci, "by_task": by_task, "per_window": [round(float(v), 6) for v in e]}

    return {"windows": len(rows), "episodes": len(episodes),
            "samplers": {k: list(v) for k, v in samplers.items()}, **{k: summary(v) for k, v in errors.items()}}


def samplers_of(cfg) -> dict:
    out = {"ddpm": ("ddpm", cfg.num_train_timesteps)}
    if cfg.inference_scheduler != "ddpm" or cfg.num_inference_steps != cfg.num_train_timesteps:
        out[cfg.inference_scheduler] = (cfg.inference_scheduler, cfg.num_inference_steps)
    return out


def write(path: str, result: dict) -> None:
    atomic_write_text(path, dumps_strict(result, indent=1) + "\n")


def train(a) -> None:
    from simeval.runtime.device import resolve_device
    from simeval.models.diffusion_policy import DiffusionPolicy, PolicyConfig, TrainSettings, train_policy
    from simeval.measures.generalization.run import checkpoint_key

    p = load_pack(a.pack)
    device = resolve_device(a.device, key="--device")
    writable_file(a.out, "--out")
    if a.checkpoint_dir:
        folder_or_absent(a.checkpoint_dir, "--checkpoint-dir")
    set_threads(a.threads, p)
    pcfg = PolicyConfig.from_mapping(p["policy_config"])
    seed = p["seed"] if a.seed is None else a.seed
    train_cfg = {k: v for k, v in p["train_settings"].items() if k != "seed"}
    if a.steps is not None:
        train_cfg["train_steps"] = a.steps
    settings = TrainSettings(**train_cfg, seed=seed)
    key = checkpoint_key(p["metas"], vars(pcfg), vars(settings), seed)  # what src/generalization.py would name it
    ckpt_dir = f"{a.checkpoint_dir}/{key}" if a.checkpoint_dir else None
    data, held = datasets(p)
    result = {"experiment": "policy_offline", "pack": {k: p[k] for k in ("pipeline", "task_group", "trained_tasks",
                                                                          "episodes_per_task", "demonstrations")},
              "preset": p["policy_name"], "seed": seed, "train_settings": train_cfg, **describe_device(device),
              "torch_threads": torch.get_num_threads(),
              "checkpoint_key": key, "checkpoint": f"{ckpt_dir}/last.ckpt" if ckpt_dir else None,
              "training_windows": len(data), "status": "training"}
    t0 = time.perf_counter()

    def log_fn(metrics: dict, step: int) -> None:
        result.setdefault("losses", []).append([step, round(metrics["train/loss"], 5)])
        result["elapsed_s"] = round(time.perf_counter() - t0, 1)
        print(f"{p['policy_name']} seed {seed} step {step}: loss {metrics['train/loss']:.4f} "
              f"({result['elapsed_s']} s)", flush=True)
        write(a.out, result)  # a run stopped at a machine's time limit still brings back its curve

    fresh = DiffusionPolicy(pcfg, data.state_dim, data.action_dim, data.stats(), seed=seed)
    config = dict(p["config"], seed=seed, policy={**p["config"]["policy"], "train": train_cfg})
    if device.type == "cuda":
        torch.backends.cudnn.benchmark = True  # fixed shapes: let cuDNN pick its fastest convolutions once
    policy, summary = train_policy(fresh, data, settings, ckpt_dir, log_fn, extra={"config": config},
                                   progress=False, device=device)
    result["losses"] = [[step, round(loss, 5)] for step, loss in summary["losses"]]  # a resumed run's whole curve
    result.update(status="trained", training={k: v for k, v in summary.items() if k != "losses"},
                  wall_s=round(time.perf_counter() - t0, 1))
    write(a.out, result)
    t1 = time.perf_counter()
    result["heldout"] = heldout_score(policy, data, held, p["heldout_tasks"], samplers_of(pcfg))
    result.update(status="scored", score_s=round(time.perf_counter() - t1, 1))
    write(a.out, result)
    print(json.dumps({k: v for k, v in result.items() if k not in ("losses", "heldout")}), flush=True)
    print_scores(result["heldout"])


def print_scores(heldout: dict) -> None:
    for k, v in heldout.items():
        if isinstance(v, dict) and "mse" in v:
            ci = "no interval" if v["ci95"] is None else f"[{v['ci95'][0]:.4f}, {v['ci95'][1]:.4f}]"
            print(f"held-out {k}: {v['mse']:.4f} {ci}", flush=True)


def score(a) -> None:
    from simeval.runtime.device import resolve_device
    from simeval.models.diffusion_policy import DiffusionPolicy, PolicyConfig

    p = load_pack(a.pack)
    ckpt = read_policy_checkpoint(a.checkpoint)
    writable_file(a.out, "--out")
    set_threads(a.threads, p)
    pcfg = PolicyConfig.from_mapping(ckpt["policy_config"])
    policy = DiffusionPolicy(pcfg, ckpt["state_dim"], ckpt["action_dim"], seed=0)
    policy.load_state_dict(ckpt["ema_model"])
    device = resolve_device(a.device, key="--device")
    policy.to(device).eval()
    data, held = datasets(p)
    key = Path(a.checkpoint).parent.name
    t0 = time.perf_counter()
    result = {"experiment": "policy_offline", "checkpoint": a.checkpoint, "checkpoint_key": key,
              "pack_key": p["checkpoint_key"], "step": ckpt["step"], "weights": ckpt.get("weights"),
              **describe_device(device),
              "heldout": heldout_score(policy, data, held, p["heldout_tasks"], samplers_of(pcfg))}
    result["score_s"] = round(time.perf_counter() - t0, 1)
    write(a.out, result)
    print_scores(result["heldout"])


def read_policy_checkpoint(path: str) -> dict:
    from simeval.models.diffusion_policy import load_checkpoint

    if not Path(path).is_file():
        what = "a folder; give the last.ckpt inside it" if Path(path).is_dir() else "no such file"
        raise UserError(f"--checkpoint {path}: {what} (a policy's last.ckpt, e.g. outputs/policies/<key>/last.ckpt)")
    try:
        return load_checkpoint(path)
    except UserError:
        raise UserError(f"--checkpoint {path}: not a simeval policy checkpoint (a policy's last.ckpt, e.g. "
                        "outputs/policies/<key>/last.ckpt)") from None


def rounded_weights(state: dict) -> tuple[dict, dict]:
    """The state dict with tensors of >= ROUND_MIN_NUMEL elements as float16 (those that fit its range), and counts."""
    out, counts = {}, {"float16_tensors": 0, "float32_tensors": 0, "float16_elements": 0, "float32_elements": 0}
    for name, t in state.items():
        fits = t.is_floating_point() and t.numel() >= ROUND_MIN_NUMEL and bool(t.abs().max() < 65504)
        out[name] = t.to(torch.float16) if fits else t.clone()
        kind = "float16" if fits else "float32"
        counts[f"{kind}_tensors"] += 1
        counts[f"{kind}_elements"] += t.numel()
    return out, counts


def pack_bytes(data: bytes) -> bytes:
    """zlib of the even bytes, then of the odd ones, behind their lengths. Why not zlib alone: a float16 tensor's
    high bytes (sign, exponent) repeat and compress, its low bytes do not; mixed, zlib saves 9% of trained weights,
    split 15% (measured on a trained piles policy), which takes the authors' GenSim size from three copies to two."""
    a = np.frombuffer(data + b"\0" * (len(data) % 2), np.uint8)
    even, odd = zlib.compress(a[0::2].tobytes(), 6), zlib.compress(a[1::2].tobytes(), 6)
    return len(data).to_bytes(8, "little") + len(even).to_bytes(8, "little") + even + odd


def unpack_bytes(blob: bytes) -> bytes:
    n, n_even = int.from_bytes(blob[:8], "little"), int.from_bytes(blob[8:16], "little")
    even, odd = zlib.decompress(blob[16:16 + n_even]), zlib.decompress(blob[16 + n_even:])
    a = np.empty(len(even) + len(odd), np.uint8)
    a[0::2], a[1::2] = np.frombuffer(even, np.uint8), np.frombuffer(odd, np.uint8)
    return a[:n].tobytes()


def export(a) -> None:
    key = Path(a.checkpoint).parent.name
    if not KEY.fullmatch(key):
        raise UserError(f"--checkpoint {a.checkpoint}: not inside its <key>/ folder (16 hex digits, e.g. "
                        "outputs/policies/a999b0acce361a4b/last.ckpt): the key names where import puts it")
    folder_or_absent(a.out_dir, "--out-dir")
    out = Path(a.out_dir)
    earlier = sorted(q.name for q in out.glob("weights.*")) if out.is_dir() else []
    if earlier:
        raise UserError(f"--out-dir {a.out_dir}: holds an earlier or interrupted export ({', '.join(earlier[:3])}"
                        f"{', ...' if len(earlier) > 3 else ''}); remove it or give an empty folder")
    ckpt = read_policy_checkpoint(a.checkpoint)
    if ckpt["step"] != ckpt["train"]["train_steps"]:
        raise UserError(f"--checkpoint {a.checkpoint}: training stopped at step {ckpt['step']} of "
                        f"{ckpt['train']['train_steps']}; finish it first: rerun train with the same --pack, --seed "
                        "and --steps (other values are another key)")
    trained_on = ckpt.get("trained_on") or ckpt.get("extra", {}).get("trained_on") or {}
    weights, counts = rounded_weights(ckpt["ema_model"])
    slim = {k: ckpt[k] for k in ("version", "policy_config", "train", "state_dim", "action_dim", "step", "losses",
                                 "train_seconds")}
    slim.update(ema_model=weights, extra={k: v for k, v in ckpt.get("extra", {}).items()},
                weights={"kind": "EMA weights of a finished training, exported without its training state",
                         "rounding": f"tensors of >= {ROUND_MIN_NUMEL} elements to float16, the rest float32",
                         **counts, "trained_on": ", ".join(f"{k} {v}" for k, v in trained_on.items()) or
                         "not recorded (a checkpoint written before simeval recorded it)"})
    buf = io.BytesIO()
    torch.save(slim, buf)
    data = buf.getvalue()
    packed = pack_bytes(data)
    part = int(a.part_mib * 2**20)
    out.mkdir(parents=True, exist_ok=True)
    parts = []
    for i in range(0, len(packed), part):
        name = f"weights.part{i // part:02d}"
        chunk = packed[i:i + part]
        with atomic_path(out / name) as tmp:
            Path(tmp).write_bytes(chunk)
        parts.append({"name": name, "bytes": len(chunk), "sha256": hashlib.sha256(chunk).hexdigest()})
    # the manifest last: a folder with parts and no weights.json is an interrupted export
    manifest = {"format": WEIGHTS_FORMAT, "checkpoint_key": key, "step": ckpt["step"],
                "bytes": len(data), "sha256": hashlib.sha256(data).hexdigest(), "packed_bytes": len(packed),
                "packing": "pack_bytes (zlib of the even, then the odd bytes)", "parts": parts,
                "weights": slim["weights"]}
    write(str(out / "weights.json"), manifest)
    print(f"exported {a.checkpoint} (step {ckpt['step']}) as {len(data) / 2**20:.1f} MiB, packed "
          f"{len(packed) / 2**20:.1f} MiB in {len(parts)} parts under "
          f"{out}: {counts['float16_elements']:,} elements float16, {counts['float32_elements']:,} float32", flush=True)


def check_manifest(manifest, path: Path) -> None:
    """The fields import reads, of the types export writes, or a UserError naming the first that is not; the key
    and part names of the forms export gives, so a manifest cannot send a write outside --checkpoint-dir."""
    if not isinstance(manifest, dict) or manifest.get("format") != WEIGHTS_FORMAT:
        raise UserError(f"--manifest {path}: not an export manifest of format {WEIGHTS_FORMAT} (weights.json)")
    key, parts, sha = manifest.get("checkpoint_key"), manifest.get("parts"), manifest.get("sha256")
    if not isinstance(key, str) or not KEY.fullmatch(key):
        raise UserError(f"--manifest {path}: checkpoint_key {key!r} is not a key (16 hex digits); export it again")
    if not isinstance(sha, str) or not isinstance(manifest.get("step"), int) \
            or not isinstance(manifest.get("weights"), dict):
        raise UserError(f"--manifest {path}: sha256, step or weights missing or of the wrong type; export it again")
    if not isinstance(parts, list) or not parts or not all(
            isinstance(q, dict) and isinstance(q.get("name"), str) and PART.fullmatch(q["name"])
            and isinstance(q.get("sha256"), str) for q in parts):
        raise UserError(f"--manifest {path}: parts should be a list of {{name: weights.partNN, sha256}}; export it "
                        "again")


def import_weights(a) -> None:
    from simeval.models.diffusion_policy import load_checkpoint

    path = Path(a.manifest)
    if not path.is_file():
        what = "a folder; give the weights.json inside it" if path.is_dir() else "no such file"
        raise UserError(f"--manifest {path}: {what} (the weights.json that export wrote)")
    try:
        manifest = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as e:
        raise UserError(f"--manifest {path}: not readable as JSON ({type(e).__name__}); give the weights.json "
                        "that export wrote") from None
    check_manifest(manifest, path)
    folder_or_absent(a.checkpoint_dir, "--checkpoint-dir")
    target = Path(a.checkpoint_dir) / manifest["checkpoint_key"] / "last.ckpt"
    if target.exists() or (target.parent.exists() and not target.parent.is_dir()):
        raise UserError(f"{target}: exists; move it away or give another --checkpoint-dir (an import never "
                        "overwrites a checkpoint)")
    missing = [q["name"] for q in manifest["parts"] if not (path.parent / q["name"]).is_file()]
    if missing:
        raise UserError(f"--manifest {path}: {len(missing)} of {len(manifest['parts'])} parts missing beside it "
                        f"({', '.join(missing)}); copy them there")
    chunks = []
    for q in manifest["parts"]:
        chunk = (path.parent / q["name"]).read_bytes()
        if hashlib.sha256(chunk).hexdigest() != q["sha256"]:
            raise UserError(f"--manifest {path}: part {q['name']} does not match its SHA-256 (a broken copy); copy "
                            "it again")
        chunks.append(chunk)
    try:
        data = unpack_bytes(b"".join(chunks))
    except zlib.error:
        data = b""
    if hashlib.sha256(data).hexdigest() != manifest["sha256"]:
        raise UserError(f"--manifest {path}: the joined parts do not match the manifest's SHA-256")
    with atomic_path(target) as tmp:  # the bytes export serialised, as they were: nothing to load and save again
        Path(tmp).write_bytes(data)
    try:
        load_checkpoint(target)  # the product's own reader accepts it
    except UserError:
        target.unlink()
        raise
    print(f"imported step {manifest['step']} into {target}: {manifest['weights']['rounding']}", flush=True)


def mib(text: str) -> float:
    """An argparse type: a part size in MiB, 0.01 to 2048 (argparse turns the ValueError into one usage line)."""
    value = float(text)
    if not 0.01 <= value <= 2048:  # also false for nan
        raise ValueError(text)
    return value


mib.__name__ = "size in MiB, 0.01 to 2048"


def whole(low: int):
    """An argparse type: a whole number >= low (argparse turns its ValueError into one usage line, exit 2)."""
    def parse(text: str) -> int:
        value = int(text)
        if value < low:
            raise ValueError(text)
        return value
    parse.__name__ = f"whole number >= {low}"
    return parse


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    """Defaults shown, the usage block kept as written."""


def main(argv: list[str] | None = None, conf_dir: Path = Path("conf")) -> None:
    """The subcommands above; `conf_dir` is the entrypoint's conf/ (src/generalization_tools.py passes it)."""
    usage = __doc__.split("\n\nWhy:")[0]
    ap = OneLineParser(prog="generalization_tools.py offline", description=usage, formatter_class=HelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True, parser_class=OneLineParser)
    def command(name: str, help: str):
        return sub.add_parser(name, help=help, description=help, formatter_class=HelpFormatter)

    pk = command("pack", "a task group's training and held-out steps, read as src/generalization.py reads them with "
                         "the same overrides, into one file (on the machine with the episode store)")
    pk.add_argument("--out", required=True, help="the pack file to write, e.g. pack.pt")
    pk.add_argument("overrides", nargs="*", help="src/generalization.py's overrides (pipeline=, policy=, task_group=, "
                                                 "tasks=, episodes_per_task=, seed=, store=, ...)")
    tr = command("train", "train the pack's policy on its steps (resuming its checkpoint if one is there), then score "
                          "it on its held-out steps")
    tr.add_argument("--pack", required=True, help="a file the pack command wrote")
    tr.add_argument("--out", required=True, help="a JSON file: the curve, written as it trains, then the score")
    tr.add_argument("--device", default="auto", help="auto (cuda if torch sees a GPU, else cpu) | cpu | cuda | cuda:N")
    tr.add_argument("--seed", type=whole(0), default=None, help="default: the pack's (its seed= override)")
    tr.add_argument("--steps", type=whole(1), default=None, help="override the preset's train_steps (another key)")
    tr.add_argument("--threads", type=whole(1), default=None,
                    help="torch threads (default: the pack's torch_threads, else torch's); on the CPU the weights "
                         "depend on it in the last bits")
    tr.add_argument("--checkpoint-dir", default=None,
                    help="write <dir>/<key>/last.ckpt, the folder src/generalization.py checkpoint_dir=<dir> reuses; "
                         "without it nothing is kept to resume or export")
    sc = command("score", "score a trained checkpoint on a pack's held-out steps")
    sc.add_argument("--pack", required=True, help="a file the pack command wrote")
    sc.add_argument("--checkpoint", required=True, help="a policy's last.ckpt (full or imported)")
    sc.add_argument("--device", default="auto", help="auto (cuda if torch sees a GPU, else cpu) | cpu | cuda | cuda:N")
    sc.add_argument("--threads", type=whole(1), default=None, help="torch threads (default: the pack's, else torch's)")
    sc.add_argument("--out", required=True, help="a JSON file for the score")
    ex = command("export", "a finished checkpoint's EMA weights (large tensors float16), packed, in parts small enough "
                           "to copy, with a manifest (weights.json)")
    ex.add_argument("--checkpoint", required=True,
                    help="<checkpoint-dir>/<key>/last.ckpt of a finished training, in its <key>/ folder")
    ex.add_argument("--out-dir", required=True, help="an empty or new folder for weights.json and weights.partNN")
    ex.add_argument("--part-mib", type=mib, default=15.8, help="the largest part, MiB (0.01 to 2048)")
    im = command("import", "join an export's parts into <checkpoint-dir>/<key>/last.ckpt, checking each")
    im.add_argument("--manifest", required=True, help="the weights.json export wrote, its parts beside it")
    im.add_argument("--checkpoint-dir", required=True,
                    help="the checkpoint_dir= src/generalization.py will be given (default there: outputs/policies)")
    a = ap.parse_args(argv)
    a.conf_dir = conf_dir
    logging.basicConfig(level=logging.INFO, format="%(message)s")  # the library's lines, "resuming ..." among them
    try:
        {"pack": pack, "train": train, "score": score, "export": export, "import": import_weights}[a.command](a)
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(2) from None
