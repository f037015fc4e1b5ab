"""Text embeddings with an on-disk cache. A backend turns a list of texts into an (N, D) array; `CachedEmbedder`
asks it only for texts it has not embedded before (and so never loads the model on a fully cached run)."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from simeval.embeddings.cache import EmbeddingCache


class EmbeddingBackend(Protocol):
    model_id: str

    def embed(self, texts: list[str]) -> np.ndarray: ...


class CachedEmbedder:
    def __init__(self, backend: EmbeddingBackend, cache: EmbeddingCache | None = None) -> None:
        self.backend, self.cache = backend, cache
        self.last_misses = 0

    def encode(self, texts: list[str]) -> np.ndarray:
        """(N, D) float32 embeddings of `texts`, in order."""
        if not texts:
            raise ValueError("no texts to embed")
        model_id = self.backend.model_id
        known = self.cache.get_many(model_id, texts) if self.cache is not None else {}
        missing = list(dict.fromkeys(t for t in texts if t not in known))
        self.last_misses = len(missing)
        if missing:
            vectors = np.asarray(self.backend.embed(missing), dtype=np.float32)
            if vectors.shape[0] != len(missing):
                raise RuntimeError(f"{model_id} returned {vectors.shape[0]} embeddings for {len(missing)} texts")
            if self.cache is not None:
                self.cache.put_many(model_id, missing, vectors)
            known.update(zip(missing, vectors))
        return np.stack([known[t] for t in texts])
