"""``remote_model``: a model actor reached over TCP with CURVE, against the same over ipc.

Two real model actors (SmolLM2-135M on llama.cpp; the MTCNN face detector
on onnxruntime), each a :class:`~embagents.models.remote.RemoteModelActor`
in its own process, bound on its ipc endpoint and on loopback TCP as a CURVE
server (real key pairs, the allow list, encryption). From this process a
:class:`~embagents.models.LocalModelClient` (ipc, arrays through shared
memory) and a :class:`~embagents.models.RemoteModelClient` (TCP + CURVE,
arrays copied into encrypted frames) ask the same actor, interleaved, so the
model and the machine's drifts are the same for both:

- ``llm_ratio``: tokens/s of a streamed chat, remote / local (bar >= 0.95);
- ``detect_ratio``: p50 latency of one 640x480 detection, remote / local (bar <= 1.5).
"""

from __future__ import annotations

import shutil
import statistics
import tempfile
import time
from typing import Any

import numpy as np

import embagents.msgs  # noqa: F401 - registers the message types this case decodes
from actors import ActorSystem
from actors.curve import write_keypair
from embagents.bench.registry import BenchOptions, case
from embagents.models import LocalModelClient, RemoteModelClient
from embagents.models.files.hub import default_llm_path, mtcnn_dir
from embagents.models.remote import RemoteModelActor

__all__: list[str] = []

PROMPT = [{"role": "user", "content": "List the planets of the solar system, one per line."}]


def _stream_tps(client: Any, max_tokens: int) -> float:
    """Tokens per second of one streamed chat, from the request to the last token."""
    t0 = time.monotonic()
    n, last = 0, t0
    for chunk in client.chat_stream(PROMPT, max_tokens=max_tokens, temperature=0.0):
        if chunk.get("delta"):
            n, last = n + 1, time.monotonic()
    return n / (last - t0)


def _detect_s(client: Any, frame: np.ndarray) -> float:
    t0 = time.perf_counter()
    client.detect(frame)
    return time.perf_counter() - t0


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@case("remote_model", transport="embagents", kind="model", needs="llama_cpp")
def remote_model(opts: BenchOptions) -> dict[str, Any]:
    from embagents.bench.cases_vision import _frame  # lazy: a cycle

    max_tokens, rounds, detections = (24, 2, 10) if opts.quick else (64, 5, 60)
    folder = tempfile.mkdtemp(prefix="embagents-bench-keys-")  # mode 0700
    try:
        server_pub, server_key = write_keypair(folder, "server")
        client_pub, client_key = write_keypair(folder, "client")
        llm_ep, det_ep = (f"tcp://127.0.0.1:{_free_port()}" for _ in range(2))
        allow = [client_pub.decode()]
        with ActorSystem() as asys:
            asys.spawn(RemoteModelActor, "bench_remote_llm", "llama", default_llm_path(), {}, True, None, [llm_ep],
                       server_key, allow, wait=300, heartbeat=None)
            asys.spawn(RemoteModelActor, "bench_remote_det", "detector", mtcnn_dir(),
                       {"family": "mtcnn", "threshold": 0.9}, True, None, [det_ep], server_key, allow,
                       wait=300, heartbeat=None)
            pair = {
                "llm": (LocalModelClient("bench_remote_llm"),
                        RemoteModelClient(llm_ep, server_key=server_pub.decode(), key=client_key)),
                "det": (LocalModelClient("bench_remote_det"),
                        RemoteModelClient(det_ep, server_key=server_pub.decode(), key=client_key)),
            }
            frame = _frame(640, 480)
            tps: dict[str, list[float]] = {"local": [], "remote": []}
            lat: dict[str, list[float]] = {"local": [], "remote": []}
            for idx in (0, 1):  # warm both paths (connections, first answers)
                _stream_tps(pair["llm"][idx], 4)
                _detect_s(pair["det"][idx], frame)
            for _ in range(rounds):  # interleaved: the machine's drifts hit both alike
                for side, idx in (("local", 0), ("remote", 1)):
                    tps[side].append(_stream_tps(pair["llm"][idx], max_tokens))
            for _ in range(detections):
                for side, idx in (("local", 0), ("remote", 1)):
                    lat[side].append(_detect_s(pair["det"][idx], frame))
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    local_tps, remote_tps = statistics.median(tps["local"]), statistics.median(tps["remote"])
    local_p50, remote_p50 = statistics.median(lat["local"]), statistics.median(lat["remote"])
    return {
        "p50_us": remote_p50 * 1e6,
        "p99_us": float(np.percentile(lat["remote"], 99)) * 1e6,
        "msgs_per_s": remote_tps,
        "llm_ratio": remote_tps / local_tps,
        "detect_ratio": remote_p50 / local_p50,
        "local_tokens_per_s": local_tps,
        "remote_tokens_per_s": remote_tps,
        "local_detect_p50_ms": local_p50 * 1e3,
        "remote_detect_p50_ms": remote_p50 * 1e3,
        "note": (f"loopback TCP + CURVE vs ipc, same actors: SmolLM2-135M {max_tokens} tokens (median of {rounds}), "
                 f"MTCNN 640x480 (p50 of {detections}); bars: llm_ratio >= 0.95, detect_ratio <= 1.5"),
    }
