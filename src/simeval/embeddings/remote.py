"""Embeddings from any OpenAI-compatible `/v1/embeddings` endpoint (OpenAI, Azure, vLLM, Ollama, TEI...).
This is how users get the paper's Llama columns: serve the model with vLLM and point `base_url` at it."""

from __future__ import annotations

import httpx
import numpy as np

from simeval.httpretry import (FatalHTTPError, RetryPolicy, api_key_from_env, check_key_transport, post_json,
                               require_key_for_remote)

CONFIG_KEY = "embedding.backend"


class OpenAIEmbeddingBackend:
    def __init__(self, base_url: str, model: str, api_key_env: str | None = "OPENAI_API_KEY", batch_size: int = 64,
                 timeout_s: float = 60.0, max_retries: int = 5, backoff_s: float = 1.0,
                 dimensions: int | None = None, allow_insecure_http: bool = False) -> None:
        """The key is read, and checked to travel only over https or to loopback (unless `allow_insecure_http`),
        when the first request is sent (a UserError from a constructor reaches the user wrapped by Hydra)."""
        if not base_url:
            raise ValueError("embedding.backend.base_url must be set (e.g. http://localhost:8000/v1)")
        if batch_size < 1:
            raise ValueError(f"embedding.backend.batch_size must be >= 1, got {batch_size}")
        self.base_url, self.model, self.api_key_env = base_url.rstrip("/"), model, api_key_env
        self.batch_size, self.timeout_s, self.dimensions = batch_size, timeout_s, dimensions
        self.allow_insecure_http = bool(allow_insecure_http)
        self.retry = RetryPolicy(max_retries=max_retries, backoff_s=backoff_s)
        self.model_id = f"openai-compatible:{self.base_url}:{model}" + (f":d{dimensions}" if dimensions else "")

    def _headers(self) -> dict:
        key = api_key_from_env(self.api_key_env, config_key=CONFIG_KEY)
        require_key_for_remote(key, self.base_url, config_key=CONFIG_KEY, key_env=self.api_key_env)
        if key:
            check_key_transport(self.base_url, config_key=CONFIG_KEY, key_env=self.api_key_env,
                                allow_insecure_http=self.allow_insecure_http)
        return {"Authorization": f"Bearer {key}"} if key else {}

    def embed(self, texts: list[str]) -> np.ndarray:
        out = []
        headers = self._headers()
        with httpx.Client() as client:
            for i in range(0, len(texts), self.batch_size):
                batch = texts[i : i + self.batch_size]
                payload = {"model": self.model, "input": batch}
                if self.dimensions:
                    payload["dimensions"] = self.dimensions
                body, _ = post_json(client, f"{self.base_url}/embeddings", payload, headers=headers,
                                    retry=self.retry, timeout_s=self.timeout_s)
                try:
                    data = sorted(body["data"], key=lambda d: d["index"])
                    vecs = [d["embedding"] for d in data]
                except (KeyError, TypeError) as e:
                    raise FatalHTTPError(f"{self.base_url}/embeddings: malformed reply (missing {e}); is "
                                         f"{CONFIG_KEY}.base_url an OpenAI-compatible endpoint? {str(body)[:200]!r}")
                if len(vecs) != len(batch):
                    raise FatalHTTPError(f"{self.base_url}/embeddings: {len(vecs)} embeddings for {len(batch)} inputs")
                out.extend(vecs)
        return np.asarray(out, dtype=np.float32)
