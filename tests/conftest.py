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
