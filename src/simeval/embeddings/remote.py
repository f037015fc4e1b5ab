"""Embeddings from any OpenAI-compatible `/v1/embeddings` endpoint (OpenAI, Azure, vLLM, Ollama, TEI...).
This is how users get the paper's Llama columns: serve the model with vLLM and point `base_url` at it."""

from __future__ import annotations

import os

import httpx
import numpy as np

from simeval.httpretry import RetryPolicy, post_json


class OpenAIEmbeddingBackend:
    def __init__(self, base_url: str, model: str, api_key_env: str | None = "OPENAI_API_KEY", batch_size: int = 64,
                 timeout_s: float = 60.0, max_retries: int = 5, backoff_s: float = 1.0,
                 dimensions: int | None = None) -> None:
        if not base_url:
            raise ValueError("embedding.backend.base_url must be set (e.g. http://localhost:8000/v1)")
        if batch_size < 1:
            raise ValueError(f"embedding.backend.batch_size must be >= 1, got {batch_size}")
        self.base_url, self.model, self.api_key_env = base_url.rstrip("/"), model, api_key_env
        self.batch_size, self.timeout_s, self.dimensions = batch_size, timeout_s, dimensions
        self.retry = RetryPolicy(max_retries=max_retries, backoff_s=backoff_s)
        self.model_id = f"openai-compatible:{self.base_url}:{model}" + (f":d{dimensions}" if dimensions else "")

    def _headers(self) -> dict:
        key = os.environ.get(self.api_key_env) if self.api_key_env else None
        return {"Authorization": f"Bearer {key}"} if key else {}

    def embed(self, texts: list[str]) -> np.ndarray:
        out = []
        with httpx.Client() as client:
            for i in range(0, len(texts), self.batch_size):
                batch = texts[i : i + self.batch_size]
                payload = {"model": self.model, "input": batch}
                if self.dimensions:
                    payload["dimensions"] = self.dimensions
                body, _ = post_json(client, f"{self.base_url}/embeddings", payload, headers=self._headers(),
                                    retry=self.retry, timeout_s=self.timeout_s)
                try:
                    data = sorted(body["data"], key=lambda d: d["index"])
                    vecs = [d["embedding"] for d in data]
                except (KeyError, TypeError) as e:
                    raise RuntimeError(f"{self.base_url}/embeddings: malformed reply (missing {e}): {str(body)[:200]}")
                if len(vecs) != len(batch):
                    raise RuntimeError(f"{self.base_url}/embeddings: {len(vecs)} embeddings for {len(batch)} inputs")
                out.extend(vecs)
        return np.asarray(out, dtype=np.float32)
