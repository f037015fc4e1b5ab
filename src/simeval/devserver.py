"""A real OpenAI-compatible HTTP server on 127.0.0.1 with scriptable faults, for tests, benchmarks and offline
smoke runs of the judge and embedding clients (`python -m simeval.devserver` serves until interrupted).

Routes: POST /v1/embeddings (deterministic hashed bag-of-words vectors) and POST /v1/chat/completions (replies
from a script or a default). `server.faults` is a queue of actions consumed one per request, e.g.
{"status": 429, "retry_after": "0.1"}, {"status": 500}, {"status": 401}, {"delay": 0.5}, {"hang": 5},
{"raw": "not json"}, {"reply": "Score: 3"}; a status action may add `"message"` (the error body's message) and
`"headers"` (e.g. {"retry-after-ms": "50"}). Every request is recorded in `server.requests`.
"""

from __future__ import annotations

import hashlib
import json
import re
import threading
import time
from collections import deque
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np

EMBED_DIM = 64


def hashed_embedding(text: str, dim: int = EMBED_DIM) -> list[float]:
    """Bag of words hashed into `dim` buckets plus a constant component, so similar texts are similar and
    every pair has positive similarity."""
    v = np.zeros(dim)
    v[0] = 1.0
    for word in re.findall(r"\w+", text.lower()):
        v[1 + int(hashlib.md5(word.encode()).hexdigest(), 16) % (dim - 1)] += 1.0
    return (v / np.linalg.norm(v)).tolist()


class _Handler(BaseHTTPRequestHandler):
    server: "LoopbackOpenAI"

    def log_message(self, *args) -> None:  # keep test output quiet
        pass

    def _send(self, status: int, body: bytes, headers: dict | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        for k, v in (headers or {}).items():
            self.send_header(k, v)
        self.end_headers()
        self.wfile.write(body)

    def do_POST(self) -> None:  # noqa: N802 (http.server API)
        length = int(self.headers.get("Content-Length", 0))
        raw = self.rfile.read(length)
        try:
            payload = json.loads(raw)
        except json.JSONDecodeError:
            payload = None
        srv = self.server
        with srv.lock:
            action = srv.faults.popleft() if srv.faults else {}
            srv.requests.append({"path": self.path, "payload": payload, "headers": dict(self.headers),
                                 "action": action, "t": time.time()})
        if "hang" in action:
            time.sleep(action["hang"])
            return
        time.sleep(action.get("delay", srv.latency_s))
        if "status" in action:
            headers = {"Retry-After": action["retry_after"]} if "retry_after" in action else {}
            headers.update(action.get("headers", {}))
            self._send(action["status"], json.dumps({"error": {"message": action.get("message", "scripted")}}).encode(),
                       headers)
            return
        if "raw" in action:
            self._send(200, action["raw"].encode())
            return
        if payload is None:
            self._send(400, b'{"error": {"message": "invalid JSON"}}')
            return
        if self.path.endswith("/embeddings"):
            inputs = payload["input"] if isinstance(payload["input"], list) else [payload["input"]]
            data = [{"object": "embedding", "index": i, "embedding": hashed_embedding(t)} for i, t in enumerate(inputs)]
            body = {"object": "list", "data": data, "model": payload.get("model"),
                    "usage": {"prompt_tokens": sum(len(t.split()) for t in inputs), "total_tokens": 0}}
        elif self.path.endswith("/chat/completions"):
            text = action.get("reply", srv.default_reply(payload) if callable(srv.default_reply) else srv.default_reply)
            body = {"id": "cmpl-test", "object": "chat.completion", "model": payload.get("model"),
                    "choices": [{"index": 0, "message": {"role": "assistant", "content": text}, "finish_reason": "stop"}],
                    "usage": {"prompt_tokens": 100, "completion_tokens": 5, "total_tokens": 105}}
        else:
            self._send(404, b'{"error": {"message": "no such route"}}')
            return
        self._send(200, json.dumps(body).encode())


class LoopbackOpenAI(ThreadingHTTPServer):
    daemon_threads = True

    def __init__(self, latency_s: float = 0.0, default_reply="Score: 3") -> None:
        super().__init__(("127.0.0.1", 0), _Handler)
        self.latency_s, self.default_reply = latency_s, default_reply
        self.faults: deque = deque()
        self.requests: list[dict] = []
        self.lock = threading.Lock()
        self._thread = threading.Thread(target=self.serve_forever, daemon=True)

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.server_address[1]}/v1"

    def __enter__(self) -> "LoopbackOpenAI":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.shutdown()
        self.server_close()


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--latency", type=float, default=0.0, help="seconds added to every reply")
    ap.add_argument("--reply", default="Score: 3", help="chat reply text")
    args = ap.parse_args()
    srv = LoopbackOpenAI(latency_s=args.latency, default_reply=args.reply)
    print(f"serving {srv.base_url} (Ctrl-C to stop)", flush=True)
    try:
        srv.serve_forever()
    except KeyboardInterrupt:
        srv.server_close()
