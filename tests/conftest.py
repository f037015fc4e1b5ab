from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
os.environ.setdefault("WANDB_SILENT", "true")

from simeval.devserver import LoopbackOpenAI  # noqa: E402
from helpers import SECRET  # noqa: E402


FILE_SECONDS = Path(__file__).with_name("file_seconds.json")


def pytest_collection_modifyitems(config, items) -> None:
    """Longest test files first (their seconds in the last full run, tests/file_seconds.json; `make test-order`
    rewrites it): `-n 2 --dist loadfile` hands out files in collection order, so a long file collected last keeps
    one worker busy alone at the end. Within a file the order is unchanged; a file not listed counts as long."""
    import json

    if not FILE_SECONDS.is_file():
        return
    seconds = json.loads(FILE_SECONDS.read_text())
    longest = max(seconds.values(), default=0.0)
    items.sort(key=lambda item: -seconds.get(Path(item.fspath).name, longest))


@pytest.fixture
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not beside this checkout")
    return SHARED_DATA


@pytest.fixture
def openai_server():
    with LoopbackOpenAI() as srv:
        yield srv


@pytest.fixture(scope="session")
def tiny_sim_store(tmp_path_factory) -> Path:
    """Three real simulator episodes of stack-two-blocks (seeds 0-2), collected by src/collect.py debug=tiny (32x32
    frames, cameras top and front) into a fresh format-2 store: what the metrics that learn from episodes
    (dynamics diversity, generalization) are run on end to end. Shared by the session: collecting takes seconds."""
    import subprocess
    import sys

    root = tmp_path_factory.mktemp("sim_store")
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "HYDRA_FULL_ERROR": "0"}
    r = subprocess.run([sys.executable, str(ROOT / "src" / "collect.py"), "pipeline=gensim", "tasks=[stack-two-blocks]",
                        "debug=tiny", "episodes=3", "workers=1", f"store={root / 'store'}",
                        f"hydra.run.dir={root / 'collect'}"], cwd=root, env=env, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert len(list((root / "store" / "gensim" / "stack-two-blocks").glob("episode_*.h5"))) == 3
    return root / "store"


def _run_entrypoint(name: str, *args: str, cwd: Path) -> None:
    import subprocess
    import sys

    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "HYDRA_FULL_ERROR": "0"}
    r = subprocess.run([sys.executable, str(ROOT / "src" / f"{name}.py"), *args], cwd=cwd, env=env,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]


@pytest.fixture(scope="session")
def world_model_runs(tmp_path_factory) -> Path:
    """A folder of 6 real dynamics_diversity runs, as `make table4` makes them: src/diversity.py debug=tiny (the
    tiny world model) on two synthetic groups of simeval.measures.dynamics_diversity.controls.synthetic written into a
    store as pipeline gensim ("shared": one dynamics, "diverse": two; 2 tasks x 4 episodes of 12 actions, 16x16),
    trained on the first 1, 2 and 3 episodes per task and evaluated on all 4. Takes seconds; a report or notebook test
    copies it."""
    from simeval.measures.dynamics_diversity.controls.synthetic import write_group

    root = tmp_path_factory.mktemp("world_model_runs")
    for kind in ("shared", "diverse"):
        write_group(root / "store", kind, n_tasks=2, episodes=4, n_actions=12, size=16, pipeline="gensim")
    _run_entrypoint("diversity", "debug=tiny", "pipeline=gensim", f"store={root / 'store'}",
                    f"checkpoint_dir={root / 'ck'}", "progress=false", "threads=1", "protocol=paper", "eval_episodes=[1,4]",
                    "heldout_episodes=null", f"hydra.sweep.dir={root / 'runs' / 'table4'}", "-m",
                    "task_group=shared,diverse", "episodes=1,2,3", cwd=root)
    return root / "runs"


@pytest.fixture(scope="session")
def policy_run(tiny_sim_store, tmp_path_factory) -> Path:
    """One real generalization run folder, as `make table5` makes them: src/generalization.py debug=tiny (the tiny
    policy, 20 training steps) on tiny_sim_store's stack-two-blocks episodes, one rollout on the train split and one
    under a perturbed robot start (eval). About 10 s."""
    root = tmp_path_factory.mktemp("policy_run")
    _run_entrypoint("generalization", "debug=tiny", f"store={tiny_sim_store}", "task_group=stacking",
                    "tasks=[stack-two-blocks]", f"checkpoint_dir={root / 'ck'}", "eval.splits=[train,eval]",
                    "eval.variation={robot: {home_noise: 0.1}}", "eval.videos=false", "eval.sampler_check=false",
                    f"hydra.run.dir={root / 'table5' / 'stacking'}", cwd=root)
    return root / "table5" / "stacking"


@pytest.fixture
def wandb_env(tmp_path):
    """Offline W&B with every W&B folder inside tmp_path, and a judge/embedding key in the environment."""
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "WANDB_MODE": "offline", "OPENAI_API_KEY": SECRET}
    for var, name in (("WANDB_DIR", "wandb_dir"), ("WANDB_CACHE_DIR", "wandb_cache"),
                      ("WANDB_CONFIG_DIR", "wandb_config")):
        env[var] = str(tmp_path / name)
    env.pop("WANDB_DATA_DIR", None)  # the logger keeps staged files with the run
    env.pop("WANDB_API_KEY", None)
    return env
