"""Judge providers. Each turns (system text, user text, images) into a reply with token usage:
  - OpenAIChatProvider: any OpenAI-compatible chat-completions endpoint with images (OpenAI, Azure OpenAI, vLLM,
    Ollama, LM Studio), over HTTP with retries (429/5xx honouring Retry-After, timeouts); 401/400 stop the run.
  - HFVisionProvider: a local `transformers` image-text-to-text model (LLaVA, Qwen-VL, BLIP-2 class) from a path.
Replay (answer only from the cache) is a runner mode, not a provider: see runner.run_judge(replay=True)."""

from __future__ import annotations

import base64
import hashlib
import io
import os
import threading
import time
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np

from simeval.errors import UserError
from simeval.httpretry import (RetryPolicy, api_key_from_env, check_key_transport, post_json,
                               require_key_for_remote)


def endpoint_id(url: str) -> str:
    """A URL normalised for cache keys: scheme and host lower-cased, default ports and trailing slashes dropped."""
    from urllib.parse import urlsplit, urlunsplit

    parts = urlsplit(url.strip())
    host = (parts.hostname or "").lower()
    default = {"http": 80, "https": 443}.get(parts.scheme.lower())
    netloc = host if parts.port in (None, default) else f"{host}:{parts.port}"
    return urlunsplit((parts.scheme.lower(), netloc, parts.path.rstrip("/"), parts.query, ""))


@dataclass(frozen=True)
class Image:
    """A PNG-encoded image and its sha256 (what the cache key uses)."""

    png: bytes
    sha256: str

    @classmethod
    def from_png(cls, data: bytes) -> "Image":
        return cls(data, hashlib.sha256(data).hexdigest())

    @classmethod
    def from_array(cls, rgb: np.ndarray) -> "Image":
        from PIL import Image as PILImage

        buf = io.BytesIO()
        PILImage.fromarray(np.asarray(rgb, dtype=np.uint8)).save(buf, format="PNG")
        return cls.from_png(buf.getvalue())

    def data_url(self) -> str:
        return "data:image/png;base64," + base64.b64encode(self.png).decode()


@dataclass
class Reply:
    text: str
    prompt_tokens: int
    completion_tokens: int
    latency_s: float
    # the failed attempts before this reply (HTTP status or error, seconds waited): recorded, never hidden
    retries: list[dict] = field(default_factory=list)


class OpenAIChatProvider:
    name = "openai"

    def __init__(self, base_url: str, model: str, api_key_env: str | None = "OPENAI_API_KEY",
                 api_style: str = "openai", api_version: str | None = None, temperature: float = 0.7,
                 max_tokens: int = 64, timeout_s: float = 60.0, max_retries: int = 5, backoff_s: float = 1.0,
                 image_detail: str = "auto", seed: int | None = None, allow_insecure_http: bool = False,
                 config_key: str = "judge.provider") -> None:
        """`config_key` is where this provider sits in the config (judge.provider, captioner.provider), for error
        messages. The key is read, and checked to travel only over https or to loopback (unless
        `allow_insecure_http`), when the first request is sent: a UserError raised here in the constructor would
        reach the user wrapped by Hydra's instantiate, as a traceback."""
        k = config_key
        if api_style not in ("openai", "azure"):
            raise UserError(f"{k}.api_style={api_style!r}: expected openai or azure")
        if api_style == "azure" and not api_version:
            raise UserError(f"{k}.api_version must be set for api_style=azure (e.g. 2024-02-15-preview)")
        if not base_url or not model:
            raise UserError(f"{k}.base_url and {k}.model must be set")
        if max_tokens < 1 or timeout_s <= 0:
            raise UserError(f"{k}: max_tokens must be >= 1 and timeout_s > 0, got {max_tokens}, {timeout_s}")
        self.base_url, self.model, self.api_key_env = base_url.rstrip("/"), model, api_key_env
        self.api_style, self.api_version, self.image_detail = api_style, api_version, image_detail
        self.temperature, self.max_tokens, self.timeout_s, self.seed = temperature, max_tokens, timeout_s, seed
        self.allow_insecure_http, self.config_key = bool(allow_insecure_http), config_key
        self._auth: dict | None = None
        self.retry = RetryPolicy(max_retries=max_retries, backoff_s=backoff_s)
        self._client = httpx.Client(limits=httpx.Limits(max_connections=64, max_keepalive_connections=64))

    @property
    def decoding(self) -> dict:
        return {"temperature": self.temperature, "max_tokens": self.max_tokens, "seed": self.seed}

    @property
    def endpoint(self) -> str:
        """Where replies come from, part of every cache key: the same model name on a local test server and on
        api.openai.com must never share cached replies."""
        return endpoint_id(self.url)

    @property
    def url(self) -> str:
        if self.api_style == "azure":
            return f"{self.base_url}/openai/deployments/{self.model}/chat/completions?api-version={self.api_version}"
        return f"{self.base_url}/chat/completions"

    def _headers(self) -> dict:
        if self._auth is None:
            key = api_key_from_env(self.api_key_env, config_key=self.config_key)
            require_key_for_remote(key, self.base_url, config_key=self.config_key, key_env=self.api_key_env)
            if key:
                check_key_transport(self.base_url, config_key=self.config_key, key_env=self.api_key_env,
                                    allow_insecure_http=self.allow_insecure_http)
            self._auth = ({"api-key": key} if self.api_style == "azure" else {"Authorization": f"Bearer {key}"}) \
                if key else {}
        return self._auth

    def payload(self, system: str, user: str, images: list[Image]) -> dict:
        content: list[dict] = [{"type": "text", "text": user}]
        content += [{"type": "image_url", "image_url": {"url": im.data_url(), "detail": self.image_detail}}
                    for im in images]
        body = {"model": self.model, "messages": [{"role": "system", "content": system},
                                                  {"role": "user", "content": content}],
                "temperature": self.temperature, "max_tokens": self.max_tokens}
        if self.seed is not None:
            body["seed"] = self.seed
        return body

    def complete(self, system: str, user: str, images: list[Image]) -> Reply:
        t0 = time.perf_counter()
        body, attempts = post_json(self._client, self.url, self.payload(system, user, images),
                                   headers=self._headers(), retry=self.retry, timeout_s=self.timeout_s)
        latency = time.perf_counter() - t0
        try:
            text = body["choices"][0]["message"]["content"]
        except (KeyError, IndexError, TypeError):
            text = None  # a reply without text is an invalid reply, re-asked like an unparseable one
        usage = body.get("usage") or {} if isinstance(body, dict) else {}
        retries = [{"status": a.status, "error": a.error, "waited_s": round(a.waited_s, 3)} for a in attempts[:-1]]
        return Reply(text if isinstance(text, str) else "", int(usage.get("prompt_tokens") or 0),
                     int(usage.get("completion_tokens") or 0), latency, retries)

    def close(self) -> None:
        self._client.close()


class HFVisionProvider:
    """A local transformers vision-language model. Nothing is downloaded: `model_path` must be a directory.

    Batching: requests arriving together from the runner's threads (judge.concurrency) are gathered, up to
    `batch_size` or for at most `batch_wait_s`, and run as one pipeline call; the first waiting thread leads."""

    name = "hf"

    def __init__(self, model_path: str, device: str = "cpu", max_new_tokens: int = 64, temperature: float = 0.7,
                 batch_size: int = 1, batch_wait_s: float = 0.05, model: str | None = None) -> None:
        if not model_path or not Path(model_path).expanduser().is_dir():
            raise UserError(
                f"judge.provider.model_path={model_path!r} is not a local model directory; simeval never downloads "
                "weights: fetch the model yourself (e.g. `huggingface-cli download llava-hf/llava-1.5-7b-hf "
                "--local-dir DIR`) and point model_path at DIR")
        if batch_size < 1 or batch_wait_s < 0:
            raise UserError(f"judge.provider: batch_size >= 1 and batch_wait_s >= 0 required, got {batch_size}, "
                             f"{batch_wait_s}")
        self.model_path, self.device = str(Path(model_path).expanduser()), device
        self.max_new_tokens, self.temperature = max_new_tokens, temperature
        self.batch_size, self.batch_wait_s = batch_size, batch_wait_s
        self.model = model or Path(self.model_path).name
        self.endpoint = "local:" + str(Path(self.model_path).resolve())
        self._pipe = None
        self._cv = threading.Condition()
        self._pending: list[tuple[list, Future]] = []
        self._leading = False

    @property
    def decoding(self) -> dict:
        return {"temperature": self.temperature, "max_new_tokens": self.max_new_tokens}

    def _load(self):
        if self._pipe is None:
            os.environ.setdefault("HF_HUB_OFFLINE", "1")
            from transformers import pipeline

            # a local directory and HF_HUB_OFFLINE: nothing can be fetched
            self._pipe = pipeline("image-text-to-text", model=self.model_path, device=self.device)
        return self._pipe

    def _run_batch(self, conversations: list[list]) -> list[str]:
        pipe = self._load()
        out = pipe(text=conversations, batch_size=len(conversations), max_new_tokens=self.max_new_tokens,
                   return_full_text=False,
                   generate_kwargs={"do_sample": self.temperature > 0, "temperature": self.temperature or None})
        texts = []
        for item in out:
            item = item[0] if isinstance(item, list) else item
            texts.append(item.get("generated_text", "") if isinstance(item, dict) else str(item))
        return texts

    def _lead(self) -> None:
        """Run batches until no request is waiting; the caller's own request is in the first one."""
        first = True
        while True:
            with self._cv:
                if first:
                    deadline = time.monotonic() + self.batch_wait_s
                    while len(self._pending) < self.batch_size and (left := deadline - time.monotonic()) > 0:
                        self._cv.wait(left)
                    first = False
                batch, self._pending = self._pending[: self.batch_size], self._pending[self.batch_size :]
                if not batch:
                    self._leading = False
                    return
            try:
                texts = self._run_batch([conv for conv, _ in batch])
                for (_, fut), text in zip(batch, texts):
                    fut.set_result(text)
            except BaseException as e:  # every request of the failed batch gets the error
                for _, fut in batch:
                    if not fut.done():
                        fut.set_exception(e)

    def complete(self, system: str, user: str, images: list[Image]) -> Reply:
        from PIL import Image as PILImage

        pil = [PILImage.open(io.BytesIO(im.png)).convert("RGB") for im in images]
        conversation = [{"role": "system", "content": [{"type": "text", "text": system}]},
                        {"role": "user", "content": [{"type": "image", "image": p} for p in pil]
                         + [{"type": "text", "text": user}]}]
        fut: Future = Future()
        t0 = time.perf_counter()
        with self._cv:
            self._pending.append((conversation, fut))
            self._cv.notify_all()
            lead = not self._leading
            self._leading = True
        if lead:
            self._lead()
        text = fut.result()
        tok = getattr(self._pipe, "tokenizer", None)
        n_in = len(tok(system + user)["input_ids"]) if tok else 0
        n_out = len(tok(text)["input_ids"]) if tok else 0
        return Reply(text, n_in, n_out, time.perf_counter() - t0)

    def close(self) -> None:
        pass
