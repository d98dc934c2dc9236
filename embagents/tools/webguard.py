"""Who may use a run's web fronts (the dashboard, ``embagents view``): Host, Origin and token checks.

A browser lets any page open a WebSocket to ``127.0.0.1`` (no CORS on the
handshake) and, after a DNS rebinding, send plain HTTP requests to it under
a name of its own. So a front checks the ``Host`` a request names (a
rebinding page sends its own name), the ``Origin`` a browser puts on each
WebSocket handshake, and a per-run token that only the user who started
the run was shown.

Example::

    >>> token = new_token()
    >>> same_token(token, token), same_token("guess", token)
    (True, False)
    >>> host_allowed("localhost:8420", "127.0.0.1", 8420), host_allowed("evil.example:8420", "127.0.0.1", 8420)
    (True, False)
    >>> is_loopback("127.0.0.1"), is_loopback("0.0.0.0")
    (True, False)
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets
import socket
from urllib.parse import urlsplit

__all__ = ["exposed_warning", "host_allowed", "is_loopback", "new_token", "same_token", "split_host"]

_WILDCARDS = ("", "0.0.0.0", "::")


def new_token() -> str:
    """A fresh random token for one run of a front."""
    return secrets.token_urlsafe(24)


def same_token(given: str | None, token: str) -> bool:
    """Whether ``given`` is ``token`` (constant time: a wrong guess says nothing about the right one)."""
    return given is not None and hmac.compare_digest(given.encode(), token.encode())


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address to bind) keeps a server on this machine."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False  # a name: it may resolve to anything


def split_host(header: str) -> tuple[str, int | None]:
    """``"name:port"`` (or ``"[::1]:port"``) as ``(name, port)``; the port is None when absent or not a number."""
    url = urlsplit(f"//{header.strip()}")
    try:
        port = url.port
    except ValueError:
        port = -1  # "name:junk": no port matches it
    return (url.hostname or "").rstrip("."), port


def host_allowed(header: str | None, bound: str, port: int) -> bool:
    """Whether a request's ``Host`` names this server: its bound host, ``localhost`` or ``127.0.0.1``, with its port.

    A server bound to every address (``0.0.0.0``) also answers to any IP
    address and to this machine's host name: a rebinding page can only send
    a DNS name of its own, never an IP literal.
    """
    if not header:
        return False
    name, given = split_host(header)
    if given != port:
        return False
    names = {bound.lower().strip("[]"), "localhost", "127.0.0.1", "::1"}
    if bound in _WILDCARDS:
        names |= {socket.gethostname().lower(), f"{socket.gethostname().lower()}.local"}
        try:
            ipaddress.ip_address(name)
            return True
        except ValueError:
            pass
    return name.lower() in names


def exposed_warning(what: str, host: str, flag: str, risk: str) -> str | None:
    """The one-line warning for a front bound beyond this machine (None for a loopback address)."""
    if is_loopback(host):
        return None
    return f"warning: {what} listens on {host or 'every address'}, beyond this machine: {risk}; {flag} 127.0.0.1 keeps it here"
