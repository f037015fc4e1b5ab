"""`debug=tiny` shrinks the expensive knobs of every entrypoint, and touches nothing else (Hydra's compose API)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
PRIMARIES = sorted(p.stem for p in CONF.glob("*.yaml"))

# entrypoint -> {dotted key: (default, with debug=tiny)}
SHRINKS = {
    "text_diversity": {"metrics.n_boot": (1000, 20), "metrics.subsample_repeats": (50, 3)},
    "agreement": {"n_boot": (2000, 50)},
    "quality": {"repeats": (5, 2), "max_reasks": (2, 1), "n_frames": (8, 2), "episodes.max_frames": (64, 8)},
    "collect": {"episodes": (40, 2), "record.image_size": ([64, 64], [32, 32]),
                "record.scene_view_size": ([128, 128], [64, 64])},
    "import_data": {"image_size": (None, [32, 32])},
    "export_data": {},
    # evaluate: the tiny world model on 2 and 4 training episodes, 2 held out, one seed
    "evaluate": {"dynamics.counts": ([10, 20, 40], [2, 4]), "dynamics.heldout": (10, 2), "dynamics.seeds": ([0, 1, 2], [0]),
                 "dynamics.debug": ("none", "tiny"), "generalization.debug": ("none", "tiny")},  # writes the episodes at their own size: nothing to shrink, but debug=tiny is accepted
    "report": {},  # reads result.json files only: nothing to shrink, but debug=tiny is accepted
    "paper": {},  # the profile sets every stage's sizes (profile=quick: tiny models); debug=tiny is accepted
    # diversity: the tiny world model (conf/world_model/tiny.yaml) over the default cpu preset
    "diversity": {"world_model.name": ("cpu", "tiny"), "world_model.model.image_size": (64, 16),
                  "world_model.model.deter": (256, 32), "world_model.model.hidden": (256, 32),
                  "world_model.model.stoch": (16, 4), "world_model.model.classes": (16, 4),
                  "world_model.model.cnn_depth": (16, 8), "world_model.model.mlp_layers": (2, 1),
                  "world_model.model.mlp_units": (128, 32), "world_model.train.epochs": (10, 2),
                  "world_model.train.lr": (1e-4, 1e-3), "world_model.train.checkpoint_every": (200, 5),
                  "world_model.window.length": (20, 8), "world_model.window.stride": (10, 4),
                  "protocol.steps": (1000, 40), "protocol.horizon": (10, 4)},
    # generalization: the tiny policy (conf/policy/tiny.yaml), 2 episodes per task, 1 rollout of 40 steps
    "generalization": {"episodes_per_task": (40, 2), "val_episodes_per_task": (2, 1), "torch_threads": (None, 1),
                       "eval.seeds": (10, 1), "eval.max_steps": (None, 40), "policy.name": ("cpu", "tiny"),
                       "policy.model.image_size": ([64, 64], [32, 32]), "policy.model.crop": (56, 28),
                       "policy.model.encoder_width": (32, 8), "policy.model.keypoints": (32, 8),
                       "policy.model.feature_dim": (64, 16), "policy.model.stem_pool": (True, False),
                       "policy.model.horizon": (16, 8), "policy.model.n_action_steps": (8, 4),
                       "policy.model.down_dims": ([64, 128, 256], [16, 32]), "policy.model.step_embed_dim": (128, 16),
                       "policy.model.kernel_size": (5, 3), "policy.model.n_groups": (8, 4),
                       "policy.model.num_train_timesteps": (100, 20), "policy.model.num_inference_steps": (16, 5),
                       "policy.train.train_steps": (1000, 20), "policy.train.batch_size": (64, 8),
                       "policy.train.lr": (3e-4, 1e-3), "policy.train.warmup_steps": (50, 2),
                       "policy.train.checkpoint_every": (100, 10), "policy.train.log_every": (20, 5)},
}


def _leaves(cfg, prefix=""):
    out = {}
    for key, value in cfg.items():
        if isinstance(value, dict):
            out.update(_leaves(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _compose(name, *overrides):
    with initialize_config_dir(version_base="1.3", config_dir=str(CONF)):
        return OmegaConf.to_container(compose(name, overrides=list(overrides)), resolve=False)


def test_every_entrypoint_has_an_expectation():
    assert set(PRIMARIES) == set(SHRINKS)
    overlays = {p.parent.name for p in CONF.glob("debug/*/tiny.yaml")}
    assert overlays <= set(PRIMARIES), "conf/debug/<name>/ must be named after a primary config"


@pytest.mark.parametrize("name", PRIMARIES)
def test_debug_tiny_shrinks_only_the_expensive_knobs(name):
    plain, tiny = _leaves(_compose(name)), _leaves(_compose(name, "debug=tiny"))
    assert set(tiny) == set(plain), "the overlay added or removed keys"
    changed = {k: (plain[k], tiny[k]) for k in plain if plain[k] != tiny[k]}
    assert changed == {k: tuple(v) for k, v in SHRINKS[name].items()}


def test_debug_tiny_composes_with_the_table3_sweep():
    cfg = _compose("text_diversity", "experiment=table3", "debug=tiny")
    assert cfg["metrics"] == {"n_boot": 20, "subsample_n": 10, "subsample_repeats": 3}


def test_debug_tiny_reaches_the_saved_config_of_a_real_run(shared_data, tmp_path):
    res = subprocess.run([sys.executable, str(ROOT / "src" / "agreement.py"), "debug=tiny",
                          f"scores_path={shared_data / 'human_eval_tables.json'}", f"hydra.run.dir={tmp_path}"],
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    rec = json.loads((tmp_path / "result.json").read_text())
    assert rec["config"]["n_boot"] == 50 and "metrics" not in rec["config"]
    assert rec["choices"]["debug"] == "tiny" and rec["choices"]["debug/agreement"] == "tiny"
