"""`src/generalization_tools.py offline` (simeval.measures.generalization.offline): a policy trained from a pack (no
store, no simulator) is the one src/generalization.py trains, under the key it reuses; the held-out score against a
hand computation; bad inputs are one line."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import GROUP, synthetic_store

from simeval.measures.generalization import offline as po

ROOT = Path(__file__).resolve().parents[1]
TOOLS = ROOT / "src" / "generalization_tools.py"


def offline(*args):
    return _python(TOOLS, "offline", *args)


def run(*args):
    return _python(ROOT / "src" / "generalization.py", *args)


def assert_one_line_errors(cases) -> list[str]:
    """Each (args, needle): exit status 2 and one stderr line holding the needle, no traceback; their stderr."""
    out = []
    for args, needle in cases:
        p = offline(*args)
        assert p.returncode == 2, (args, p.stderr[-1500:])
        assert p.stderr.count("\n") == 1 and needle in p.stderr and "Traceback" not in p.stderr, (args, p.stderr)
        out.append(p.stderr)
    return out


def _python(script: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    return subprocess.run([sys.executable, str(script), *args], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=280, check=False)


@pytest.fixture(scope="module")
def packed(tmp_path_factory):
    root = tmp_path_factory.mktemp("offline")
    store = synthetic_store(root / "store", per_task=4)  # 2 to train on per task, 2 after them held out
    overrides = ["debug=tiny", f"store={store}", f"task_group={GROUP}"]
    p = offline("pack", "--out", str(root / "pack.pt"), *overrides)
    assert p.returncode == 0, p.stderr[-2000:]
    return root, overrides


def test_a_pack_trains_the_policy_generalization_would_and_under_the_key_it_reuses(packed):
    root, overrides = packed
    p = offline("train", "--pack", str(root / "pack.pt"), "--out", str(root / "train.json"), "--device", "cpu",
                "--checkpoint-dir", str(root / "ck"))
    assert p.returncode == 0, p.stderr[-2000:]
    rec = json.loads((root / "train.json").read_text())
    assert rec["status"] == "scored" and rec["training"]["steps"] == 20
    # the held-out steps: episodes 2 and 3 of each trained task, 29 actions each (30 rows)
    assert rec["heldout"]["episodes"] == 4 and rec["heldout"]["windows"] == 4 * 29
    ckpt = root / "ck" / rec["checkpoint_key"] / "last.ckpt"
    assert ckpt.is_file() and rec["checkpoint"] == str(ckpt)

    # the entrypoint, same overrides, that checkpoint folder: it finds the finished training and trains nothing
    reused = run(*overrides, f"checkpoint_dir={root / 'ck'}", "eval.splits=[]", f"hydra.run.dir={root / 'r1'}")
    assert reused.returncode == 0, reused.stderr[-2000:]
    result = json.loads((root / "r1" / "result.json").read_text())
    assert result["values"]["training"]["checkpoint"] == str(ckpt)
    assert result["values"]["training"]["trained_tasks"] == rec["pack"]["trained_tasks"]
    assert len(rec["pack"]["trained_tasks"]) == 2  # the group's 3 tasks less the held-out sweep-two-piles
    assert "at step 20/20" in (root / "r1" / "generalization.log").read_text()

    # and it is the policy the entrypoint trains itself from the store
    fresh = run(*overrides, f"checkpoint_dir={root / 'fresh'}", "eval.splits=[]", f"hydra.run.dir={root / 'r2'}")
    assert fresh.returncode == 0, fresh.stderr[-2000:]
    (own,) = list((root / "fresh").glob("*/last.ckpt"))
    assert own.parent.name == rec["checkpoint_key"]
    a, b = torch.load(ckpt, weights_only=False), torch.load(own, weights_only=False)
    # bit for bit: the pack's torch_threads (debug=tiny's 1) is the entrypoint's, and the CPU's sums follow it
    assert a["losses"] == b["losses"] and a["step"] == b["step"] == 20
    for k in b["ema_model"]:
        assert torch.equal(a["ema_model"][k], b["ema_model"][k]), k


def test_scoring_a_checkpoint_gives_the_score_its_training_gave(packed):
    root, _ = packed
    trained = json.loads((root / "train.json").read_text())
    ckpt = trained["checkpoint"]
    p = offline("score", "--pack", str(root / "pack.pt"), "--checkpoint", ckpt, "--out", str(root / "score.json"),
                "--device", "cpu")
    assert p.returncode == 0, p.stderr[-2000:]
    rec = json.loads((root / "score.json").read_text())
    assert rec["checkpoint_key"] == rec["pack_key"] == trained["checkpoint_key"]
    for k in ("ddpm", "ddim", "train_mean_baseline"):
        assert rec["heldout"][k]["per_window"] == trained["heldout"][k]["per_window"], k


def test_an_exported_and_imported_policy_is_the_rounded_one_and_the_entrypoint_rolls_it_out(packed):
    """export -> import: the entrypoint reuses the finished weights (no training state travels) and says so in
    result.json; they are the EMA weights with the large tensors rounded to float16 and the rest exact."""
    root, overrides = packed
    trained = json.loads((root / "train.json").read_text())
    key, ckpt = trained["checkpoint_key"], trained["checkpoint"]
    p = offline("export", "--checkpoint", ckpt, "--out-dir", str(root / "ex"), "--part-mib", "0.05")
    assert p.returncode == 0, p.stderr[-2000:]
    manifest = json.loads((root / "ex" / "weights.json").read_text())
    assert manifest["checkpoint_key"] == key and len(manifest["parts"]) >= 3
    assert all(q["bytes"] <= 0.05 * 2**20 for q in manifest["parts"])
    p = offline("import", "--manifest", str(root / "ex" / "weights.json"), "--checkpoint-dir", str(root / "im"))
    assert p.returncode == 0, p.stderr[-2000:]

    full, slim = (torch.load(f, weights_only=False) for f in (ckpt, root / "im" / key / "last.ckpt"))
    assert "optimizer" not in slim and "model" not in slim and slim["losses"] == full["losses"]
    assert slim["weights"]["float16_tensors"] > 0 and slim["weights"]["float32_tensors"] > 0
    for name, w in full["ema_model"].items():
        big = w.is_floating_point() and w.numel() >= 4096
        assert slim["ema_model"][name].dtype == (torch.float16 if big else w.dtype), name
        assert torch.equal(slim["ema_model"][name], w.half() if big else w), name

    reused = run(*overrides, f"checkpoint_dir={root / 'im'}", "eval.splits=[]", f"hydra.run.dir={root / 'r3'}")
    assert reused.returncode == 0, reused.stderr[-2000:]
    assert "a finished training (20 steps" in (root / "r3" / "generalization.log").read_text()
    training = json.loads((root / "r3" / "result.json").read_text())["values"]["training"]
    assert training["steps"] == 20 and training["weights"]["rounding"].startswith("tensors of >= 4096")
    assert training["device"].startswith("device cpu")  # where it trained, from the checkpoint

    p = offline("score", "--pack", str(root / "pack.pt"), "--checkpoint", str(root / "im" / key / "last.ckpt"),
                "--out", str(root / "score_im.json"), "--device", "cpu")
    assert p.returncode == 0, p.stderr[-2000:]
    rounded = json.loads((root / "score_im.json").read_text())
    assert rounded["weights"]["float16_tensors"] == slim["weights"]["float16_tensors"]
    np.testing.assert_allclose(rounded["heldout"]["ddpm"]["per_window"], trained["heldout"]["ddpm"]["per_window"],
                               atol=5e-3)


def test_transfer_faults_are_one_line_and_write_nothing(packed, tmp_path):
    import shutil

    root, _ = packed
    trained = json.loads((root / "train.json").read_text())
    ex = tmp_path / "ex"
    assert offline("export", "--checkpoint", trained["checkpoint"], "--out-dir", str(ex), "--part-mib",
                   "0.05").returncode == 0
    manifest = ex / "weights.json"
    unfinished = torch.load(trained["checkpoint"], weights_only=False)
    unfinished["step"] = 10
    (tmp_path / "0123456789abcdef").mkdir()
    torch.save(unfinished, tmp_path / "0123456789abcdef" / "last.ckpt")
    cases = [(("export", "--checkpoint", str(tmp_path / "0123456789abcdef" / "last.ckpt"), "--out-dir",
               str(tmp_path / "x")),
              "step 10 of 20"),
             (("export", "--checkpoint", str(root / "pack.pt"), "--out-dir", str(tmp_path / "x")), "--checkpoint")]
    (tmp_path / "garbage.json").write_text("{not json")
    cases.append((("import", "--manifest", str(tmp_path / "garbage.json"), "--checkpoint-dir", str(tmp_path / "ck")),
                  "garbage.json"))
    broken = tmp_path / "broken"
    shutil.copytree(ex, broken)
    (broken / "weights.part01").write_bytes(b"\0" * 100)
    cases.append((("import", "--manifest", str(broken / "weights.json"), "--checkpoint-dir", str(tmp_path / "ck")),
                  "weights.part01 does not match"))
    (ex / "weights.part02").rename(tmp_path / "away")
    cases.append((("import", "--manifest", str(manifest), "--checkpoint-dir", str(tmp_path / "ck")),
                  "weights.part02"))
    cases.append((("import", "--manifest", str(broken / "weights.json"), "--checkpoint-dir", str(root / "ck")),
                  "exists"))  # refused before any part is read
    # a checkpoint out of its <key>/ folder would be imported under another key and trained again: refused
    shutil.copy(trained["checkpoint"], tmp_path / "mine.ckpt")
    cases.append((("export", "--checkpoint", str(tmp_path / "mine.ckpt"), "--out-dir", str(tmp_path / "x")),
                  "not inside its <key>/ folder"))
    cases.append((("export", "--checkpoint", trained["checkpoint"], "--out-dir", str(ex)), "earlier or interrupted"))
    cases.append((("export", "--checkpoint", trained["checkpoint"], "--out-dir", str(tmp_path / "garbage.json")),
                  "is a file"))
    for size in ("0", "nan", "-1", "inf"):
        cases.append((("export", "--checkpoint", trained["checkpoint"], "--out-dir", str(tmp_path / "x"),
                       "--part-mib", size), "--part-mib"))
    escaping = json.loads(manifest.read_text()) | {"checkpoint_key": "../../escaped"}
    (tmp_path / "escaping.json").write_text(json.dumps(escaping))
    cases.append((("import", "--manifest", str(tmp_path / "escaping.json"), "--checkpoint-dir", str(tmp_path / "ck")),
                  "is not a key"))
    (tmp_path / "partless.json").write_text(json.dumps({k: v for k, v in escaping.items() if k != "parts"}
                                                       | {"checkpoint_key": "0123456789abcdef"}))
    cases.append((("import", "--manifest", str(tmp_path / "partless.json"), "--checkpoint-dir", str(tmp_path / "ck")),
                  "parts should be"))
    cases.append((("import", "--manifest", str(ex), "--checkpoint-dir", str(tmp_path / "ck")), "a folder"))
    cases.append((("import", "--manifest", str(broken / "weights.json"), "--checkpoint-dir",
                   str(tmp_path / "garbage.json")), "is a file"))
    for cmd in (("train", "--pack", str(root / "pack.pt"), "--out", str(tmp_path)),
                ("score", "--pack", str(root / "pack.pt"), "--checkpoint", trained["checkpoint"], "--out",
                 str(tmp_path))):
        cases.append((cmd, "is a folder"))  # before any work, not at the first write after it
    cases.append((("train", "--pack", str(root / "pack.pt"), "--out", str(tmp_path / "t.json"), "--checkpoint-dir",
                   str(tmp_path / "garbage.json")), "is a file"))
    assert_one_line_errors(cases)
    assert not (tmp_path / "x").exists() and not (tmp_path / "ck").exists() and not (tmp_path / "t.json").exists()
    assert not (tmp_path.parent / "escaped").exists()
    # an import never overwrites: the original full checkpoint stays where it is
    (tmp_path / "away").rename(ex / "weights.part02")
    p = offline("import", "--manifest", str(manifest), "--checkpoint-dir", str(root / "ck"))
    assert p.returncode == 2 and "exists" in p.stderr and p.stderr.count("\n") == 1
    assert "optimizer" in torch.load(trained["checkpoint"], weights_only=False)


def test_a_weights_only_checkpoint_short_of_its_steps_is_refused(packed, tmp_path):
    from simeval.errors import UserError
    from simeval.models.diffusion_policy import (
        DiffusionPolicy,
        PolicyConfig,
        TrainSettings,
        finished_weights,
    )

    root, _ = packed
    pk = po.load_pack(str(root / "pack.pt"))
    train, _ = po.datasets(pk)
    policy = DiffusionPolicy(PolicyConfig.from_mapping(pk["policy_config"]), train.state_dim, train.action_dim,
                             train.stats(), seed=0)
    slim = {"step": 15, "losses": [], "train_seconds": 1.0, "weights": {}, "ema_model": policy.state_dict()}
    settings = TrainSettings(**{k: v for k, v in pk["train_settings"].items() if k != "seed"})
    with pytest.raises(UserError, match="at step 15, not a finished training of 20 steps"):
        finished_weights(policy, slim, tmp_path / "last.ckpt", settings)


def test_packing_round_trips_any_bytes():
    rng = np.random.default_rng(0)
    for n in (0, 1, 2, 1001):
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        assert po.unpack_bytes(po.pack_bytes(data)) == data


def test_heldout_score_against_a_hand_computation(packed, monkeypatch):
    """A policy that predicts the demonstrator's own actions scores 0; the train-mean baseline equals numpy's
    (x - lo) / (hi - lo) * 2 - 1 normalisation, the executed steps s+1..s+4 of each window (n_obs_steps 2, 4 executed,
    indices clipped to the episode), and the squared difference to the normalised training mean."""
    from simeval.models.diffusion_policy import DiffusionPolicy, PolicyConfig

    root, _ = packed
    pk = po.load_pack(str(root / "pack.pt"))
    train, held = po.datasets(pk)
    cfg = PolicyConfig.from_mapping(pk["policy_config"])
    policy = DiffusionPolicy(cfg, train.state_dim, train.action_dim, train.stats(), seed=0)
    monkeypatch.setattr(policy, "predict_action", lambda batch, *a, **k: batch["action"].float())
    out = po.heldout_score(policy, train, held, pk["heldout_tasks"], {"ddpm": ("ddpm", 20)})
    assert out["ddpm"]["mse"] == 0.0 and out["ddpm"]["ci95"] == [0.0, 0.0]

    tr = pk["train"]["action"].numpy().astype(np.float64)
    lo, hi = tr.min(0), tr.max(0)

    def norm(x):
        return 2 * (x - lo) / (hi - lo) - 1

    mean = norm(tr).mean(0)
    actions, lengths = pk["heldout"]["action"].numpy().astype(np.float64), pk["heldout"]["lengths"]
    expected, offset = [], 0
    for n in lengths:
        ep = actions[offset:offset + n]
        for s in range(-1, n - 1):  # window starts -(To-1) .. T-To
            executed = ep[np.clip(np.arange(s + 1, s + 5), 0, n - 1)]
            expected.append(((mean - norm(executed)) ** 2).mean())
        offset += n
    np.testing.assert_allclose(out["train_mean_baseline"]["per_window"], expected, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(out["train_mean_baseline"]["mse"], np.mean(expected), rtol=1e-4)


def test_bad_inputs_are_one_line(packed, tmp_path):
    root, _ = packed
    cases = [
        (("pack", "--out", str(tmp_path / "x.pt"), "policy=no-such-preset"), "policy"),
        (("pack", "--out", str(tmp_path / "x.pt"), "debug=tiny", f"store={tmp_path / 'empty'}",
          f"task_group={GROUP}"), "fewer than episodes_per_task"),
        (("pack", "--out", str(tmp_path / "x.pt"), "policy=random"), "policy=random"),
        (("train", "--pack", str(tmp_path / "missing.pt"), "--out", str(tmp_path / "t.json")), "missing.pt"),
        (("train", "--pack", str(root / "pack.pt"), "--out", str(tmp_path / "t.json"), "--device", "tpu"), "--device"),
        (("score", "--pack", str(root / "pack.pt"), "--checkpoint", str(tmp_path / "none.ckpt"), "--out",
          str(tmp_path / "s.json")), "none.ckpt"),
        (("score", "--pack", str(root / "pack.pt"), "--checkpoint", str(root / "pack.pt"), "--out",
          str(tmp_path / "s.json")), "--checkpoint"),  # the pack given as a checkpoint: named, nothing to delete
        (("pack", "--out", str(tmp_path / "x.pt"), "debug=tiny", "episodes_per_task=abc"), "episodes_per_task"),
        (("pack", "--out", str(tmp_path), "debug=tiny", f"store={root / 'store'}", f"task_group={GROUP}"),
         "is a folder"),
        (("train", "--pack", str(root / "pack.pt"), "--out", str(tmp_path / "t.json"), "--threads", "0"),
         "--threads"),
    ]
    (tmp_path / "not-a-pack.pt").write_bytes(b"garbage")
    cases.append((("train", "--pack", str(tmp_path / "not-a-pack.pt"), "--out", str(tmp_path / "t.json")),
                  "not-a-pack.pt"))
    for stderr in assert_one_line_errors(cases):
        assert "delete" not in stderr, stderr
    assert not (tmp_path / "x.pt").exists()
