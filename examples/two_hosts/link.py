"""Where the two example hosts meet: loopback by default; TLS between two machines when asked.

    EMBAGENTS_GPU_ADDR     the GPU box's address (default 127.0.0.1: both on this machine)
    EMBAGENTS_TLS_DIR      a folder with ca.pem and each host's HOST.pem / HOST.key
                           (`embagents keys --tls --host robot1 --dir DIR`, then --host gpu):
                           needed for any address other than loopback

The GPU box listens, the robot connects (one explicit endpoint each side; no multicast).
"""

from __future__ import annotations

import os

from embagents.zenoh import TlsFiles

PORT = int(os.environ.get("EMBAGENTS_ZENOH_PORT", "7447"))
ADDR = os.environ.get("EMBAGENTS_GPU_ADDR", "127.0.0.1")
TLS_DIR = os.environ.get("EMBAGENTS_TLS_DIR")


def tls(host: str) -> TlsFiles | None:
    return TlsFiles.of_host(TLS_DIR, host) if TLS_DIR else None


def endpoint(addr: str) -> str:
    return f"{'tls' if TLS_DIR else 'tcp'}/{addr}:{PORT}"


# The GPU box listens on its own address (0.0.0.0 would also do), the robot connects to it.
LISTEN = endpoint(ADDR if TLS_DIR else "127.0.0.1")
CONNECT = endpoint(ADDR)
