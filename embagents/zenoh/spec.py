"""Declarations of the Zenoh bridge, written in ``system.py`` (no zenoh needed).

One :class:`ZenohBridge` per host links this run's topics to other hosts:
``exports`` go out under the bridge's ``namespace`` (``robot1/camera/image``),
``imports`` come in from key expressions, wildcards allowed (``robot*/pose``:
a fleet view). Endpoints are explicit, written as Zenoh spells them
(``tcp/10.0.0.2:7447``, ``tls/...``, ``quic/...``); multicast scouting is off,
so a link that never comes up is an error in ``embagents status``, not silence.
Plain TCP is allowed on loopback only: beyond it, TLS with mutual
authentication (``embagents keys --tls``).

Example::

    >>> from embagents.zenoh import Export, Import, ZenohBridge
    >>> from embagents.msgs import Detections
    >>> bridge = ZenohBridge("robot1", exports=["camera/image"],
    ...                      imports=[Import("gpu/detections", Detections)],
    ...                      connect=["tcp/127.0.0.1:7447"])
    >>> bridge.key_of(bridge.exports[0]), bridge.imports[0].topic
    ('robot1/camera/image', 'detections')
    >>> ZenohBridge("robot1", connect=["tcp/10.0.0.2:7447"])
    Traceback (most recent call last):
    ...
    ValueError: endpoint 'tcp/10.0.0.2:7447': plain TCP beyond loopback is not allowed; use 'tls/10.0.0.2:7447' with tls=TlsFiles(...) from `embagents keys --tls` (mutual authentication)
"""

from __future__ import annotations

import ipaddress
import os
import re
from collections.abc import Sequence
from typing import Any

import attrs

from embagents.msgs import MESSAGE_TYPES
from embagents.topic import Topic

__all__ = [
    "BRIDGE_NAME",
    "Export",
    "Import",
    "TlsFiles",
    "ZENOH_EXTRA_HINT",
    "ZenohBridge",
    "check_endpoint",
    "zenoh_available",
    "zenoh_key",
]

#: The bridge actor's name in the run (``embagents status``, health, logs).
BRIDGE_NAME = "_zenoh_bridge"
ZENOH_EXTRA_HINT = "install the Zenoh extra: pip install 'embagents[zenoh]'"

_PROTOCOLS = ("tcp", "tls", "quic")
_ENDPOINT = re.compile(r"^(?P<proto>[a-z0-9]+)/(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(?P<port>[0-9]{1,5})$")
# A key expression chunk: no '#', '?', '$' (Zenoh's reserved), no empty chunk.
_KEY = re.compile(r"^[A-Za-z0-9_.*-]+(/[A-Za-z0-9_.*-]+)*$")
_NAME = re.compile(r"^[A-Za-z0-9_-]+$")


def _is_loopback(host: str) -> bool:
    host = host.strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a host name: it resolves elsewhere, so treat it as beyond loopback


def check_endpoint(endpoint: str, *, tls: bool) -> str:
    """Validate one endpoint (``proto/host:port``); return it. Raises ValueError naming the fix.

    >>> check_endpoint("tcp/127.0.0.1:7447", tls=False)
    'tcp/127.0.0.1:7447'
    >>> check_endpoint("127.0.0.1:7447", tls=False)
    Traceback (most recent call last):
    ...
    ValueError: malformed endpoint '127.0.0.1:7447': write PROTOCOL/HOST:PORT with PROTOCOL one of tcp, tls, quic, e.g. 'tcp/127.0.0.1:7447' or 'tls/192.168.1.20:7447'
    """
    example = "e.g. 'tcp/127.0.0.1:7447' or 'tls/192.168.1.20:7447'"
    if not isinstance(endpoint, str):
        raise TypeError(f"an endpoint must be a str like 'tcp/127.0.0.1:7447', got {endpoint!r}")
    m = _ENDPOINT.match(endpoint.strip())
    if m is None or m["proto"] not in _PROTOCOLS:
        raise ValueError(f"malformed endpoint {endpoint!r}: write PROTOCOL/HOST:PORT with PROTOCOL one of "
                         f"{', '.join(_PROTOCOLS)}, {example}")
    port = int(m["port"])
    if not 0 <= port <= 65535:
        raise ValueError(f"endpoint {endpoint!r}: port {port} is not in 0-65535; {example}")
    if m["proto"] == "tcp" and not _is_loopback(m["host"]):
        raise ValueError(f"endpoint {endpoint!r}: plain TCP beyond loopback is not allowed; use "
                         f"'tls/{m['host']}:{port}' with tls=TlsFiles(...) from `embagents keys --tls` "
                         "(mutual authentication)")
    if m["proto"] in ("tls", "quic") and not tls:
        raise ValueError(f"endpoint {endpoint!r} needs certificates: give the bridge tls=TlsFiles(ca=..., cert=..., "
                         "key=...) (make them with `embagents keys --tls`)")
    return endpoint.strip()


def zenoh_key(key: str) -> str:
    """Our key expression as Zenoh spells it: a wildcard inside a chunk is ``$*``.

    >>> zenoh_key("robot*/pose"), zenoh_key("*/camera/**")
    ('robot$*/pose', '*/camera/**')
    """
    return "/".join(c if c in ("*", "**") else c.replace("*", "$*") for c in key.split("/"))


def _key(what: str, value: str) -> str:
    if not isinstance(value, str) or not _KEY.match(value) or any(
            "**" in c and c != "**" for c in value.split("/")):
        raise ValueError(f"{what} {value!r} is not a key expression: chunks of letters, digits, '_', '-', '.' "
                         "or '*' separated by single '/', e.g. 'robot1/camera/image' or 'robot*/pose'")
    return value


def _keep(value: str) -> str:
    if value not in ("all", "latest"):
        raise ValueError(f"keep must be 'all' (nothing lost across a short link cut) or 'latest', got {value!r}")
    return value


def _compress(value: str | None) -> str | None:
    if value not in (None, "lz4", "jpeg"):
        raise ValueError(f"compress must be None, 'lz4' (any message) or 'jpeg' (an Image; lossy), got {value!r}")
    return value


def _window(value: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"window must be an int >= 1 (messages kept for replay after a link cut), got {value!r}")
    return value


@attrs.define(frozen=True)
class Export:
    """An internal ``topic`` going out as ``<namespace>/<key>`` (``key`` defaults to the topic's name).

    ``keep="all"``: reliable, the last ``window`` messages kept for replay after a
    link cut, a loss beyond it counted; ``"latest"``: resumes with what comes next.
    ``compress``: ``"lz4"`` (any message) or ``"jpeg"`` (an ``Image`` arrives as an
    ``Image`` again, lossy, quality ``jpeg_quality``) for links that need it.

    >>> Export("camera/image", keep="latest", compress="jpeg").key
    'camera/image'
    """

    topic: str = attrs.field(converter=lambda t: t.name if isinstance(t, Topic) else t)
    keep: str = attrs.field(default="all", validator=lambda _i, _a, v: _keep(v))
    window: int = attrs.field(default=5000, validator=lambda _i, _a, v: _window(v))
    key: str | None = None
    compress: str | None = attrs.field(default=None, validator=lambda _i, _a, v: _compress(v))
    jpeg_quality: int = 90

    def __attrs_post_init__(self) -> None:
        if not isinstance(self.topic, str) or not self.topic:
            raise ValueError(f"Export: topic must be a non-empty str or a Topic, got {self.topic!r}")
        object.__setattr__(self, "key", _key(f"Export({self.topic!r}) key", self.key or self.topic.strip("/")))


@attrs.define(frozen=True)
class Import:
    """Remote ``key`` (a key expression, wildcards allowed) published on internal ``topic``.

    ``topic`` defaults to the key without its first chunk (the remote namespace):
    ``"gpu/detections"`` -> ``"detections"``; ``"robot*/pose"`` -> ``"pose"``.

    >>> Import("robot*/pose", "Odometry").topic
    'pose'
    """

    key: str = attrs.field(validator=lambda _i, _a, v: _key("Import key", v))
    msg_type: Any = attrs.field(default=None, converter=lambda v: _msg_type(v))
    topic: str = attrs.field(default=None)  # None: the key without its first chunk (__attrs_post_init__)
    keep: str = attrs.field(default="all", validator=lambda _i, _a, v: _keep(v))

    def __attrs_post_init__(self) -> None:
        if self.topic is None:
            head, _, rest = self.key.partition("/")
            if not rest or "*" in rest:
                raise ValueError(f"Import({self.key!r}): give topic= (the internal topic it is published on)")
            object.__setattr__(self, "topic", rest)
        elif not isinstance(self.topic, str) or not self.topic:
            raise ValueError(f"Import({self.key!r}): topic must be a non-empty str, got {self.topic!r}")


def _msg_type(value: Any) -> Any:
    if isinstance(value, str):

        if value not in MESSAGE_TYPES:
            raise ValueError(f"Import msg_type {value!r} is not a message class; one of {', '.join(sorted(MESSAGE_TYPES))}")
        return MESSAGE_TYPES[value]
    return value


def _readable(what: str, path: str) -> str:
    path = os.path.abspath(os.path.expanduser(path))
    if not os.path.isfile(path):
        raise ValueError(f"TLS {what} {path!r} does not exist; make it with `embagents keys --tls --host NAME`")
    return path


@attrs.define(frozen=True)
class TlsFiles:
    """The CA certificate, this host's certificate and its private key (PEM), from ``embagents keys --tls``.

    Both sides present a certificate signed by the CA (mutual authentication).
    """

    ca: str = attrs.field(converter=lambda p: _readable("CA certificate", p))
    cert: str = attrs.field(converter=lambda p: _readable("certificate", p))
    key: str = attrs.field(converter=lambda p: _readable("private key", p))

    @classmethod
    def of_host(cls, folder: str, host: str) -> TlsFiles:
        """The files ``embagents keys --tls --host HOST --dir FOLDER`` wrote."""
        folder = os.path.expanduser(folder)
        return cls(os.path.join(folder, "ca.pem"), os.path.join(folder, f"{host}.pem"),
                   os.path.join(folder, f"{host}.key"))


def _endpoints(what: str, values: Sequence[str], tls: bool) -> list[str]:
    if isinstance(values, str):
        raise TypeError(f"{what} must be a list of endpoints, got the str {values!r}: write [{values!r}]")
    return [check_endpoint(v, tls=tls) for v in values]


class ZenohBridge:
    """This host's Zenoh bridge: a namespace, topics out and in, endpoints.

    - ``exports``: internal topics (names, :class:`Topic` or :class:`Export`) sent as ``namespace/topic``;
    - ``imports``: :class:`Import` (or a ``"ns/topic"`` str) brought in;
    - ``listen`` / ``connect``: endpoints (at least one); this side listens, the other connects;
    - ``tls``: :class:`TlsFiles`, needed for ``tls/`` and ``quic/`` endpoints;
    - ``link_down_s``: a link down (or never up) this long reports SYSTEM_FAILURE on the bridge's health;
    - ``peers``: access rules, ``{certificate name: [key expressions]}`` (needs ``tls``): only the
      peers named here may link, and with each only those key expressions flow, either way (publish
      and subscribe); without it any peer whose certificate the CA signed may use every key;
    - ``lease_s``: a peer silent this long (a pulled cable, a veth down) is a link down (Zenoh's lease;
      keep-alives go 4 times per lease).
    """

    def __init__(
        self,
        namespace: str,
        exports: Sequence[str | Topic | Export] = (),
        imports: Sequence[str | Import] = (),
        listen: Sequence[str] = (),
        connect: Sequence[str] = (),
        tls: TlsFiles | None = None,
        link_down_s: float = 5.0,
        lease_s: float = 3.0,
        peers: dict[str, Sequence[str]] | None = None,
    ) -> None:
        if not isinstance(namespace, str) or not _NAME.match(namespace):
            raise ValueError(f"ZenohBridge namespace must be one chunk of letters, digits, '_' or '-' "
                             f"(e.g. 'robot1'), got {namespace!r}")
        if tls is not None and not isinstance(tls, TlsFiles):
            raise TypeError(f"tls must be embagents.zenoh.TlsFiles, got {tls!r}")
        self.namespace = namespace
        self.tls = tls
        self.exports = [e if isinstance(e, Export) else Export(e) for e in exports]
        self.imports = [i if isinstance(i, Import) else Import(i) for i in imports]
        self.listen = _endpoints("listen", listen, tls is not None)
        self.connect = _endpoints("connect", connect, tls is not None)
        if not self.listen and not self.connect:
            raise ValueError("ZenohBridge needs an endpoint: listen=['tcp/127.0.0.1:7447'] on one host and "
                             "connect=['tcp/127.0.0.1:7447'] on the other (multicast discovery is off)")
        if isinstance(link_down_s, bool) or not isinstance(link_down_s, (int, float)) or link_down_s <= 0:
            raise ValueError(f"link_down_s must be seconds > 0, got {link_down_s!r}")
        self.link_down_s = float(link_down_s)
        if isinstance(lease_s, bool) or not isinstance(lease_s, (int, float)) or not 0.5 <= lease_s <= 600:
            raise ValueError(f"lease_s must be seconds in 0.5-600, got {lease_s!r}")
        self.lease_s = float(lease_s)
        if peers is not None:
            if tls is None:
                raise ValueError("peers= (access rules by certificate name) needs tls=TlsFiles(...): without TLS "
                                 "a peer has no proven name")
            if not isinstance(peers, dict) or not all(isinstance(k, str) and k for k in peers):
                raise TypeError(f"peers must be {{certificate name: [key expressions]}}, got {peers!r}")
            peers = {name: [_key(f"peers[{name!r}]", k) for k in keys] for name, keys in peers.items()}
        self.peers = peers
        seen: set[str] = set()
        for e in self.exports:
            if e.topic in seen:
                raise ValueError(f"topic {e.topic!r} is exported twice")
            seen.add(e.topic)
        for i in self.imports:
            if i.topic in seen:
                raise ValueError(f"topic {i.topic!r} is both exported and imported: each message would come back; "
                                 "rename one side with topic=")

    def key_of(self, export: Export) -> str:
        """The key expression ``export`` goes out as."""
        return f"{self.namespace}/{export.key}"

    def to_dict(self) -> dict[str, Any]:
        """Plain data (for the bridge actor outside a System: the bench)."""
        return {
            "namespace": self.namespace,
            "exports": [attrs.asdict(e) for e in self.exports],
            "imports": [{"key": i.key, "topic": i.topic, "keep": i.keep} for i in self.imports],
            "listen": self.listen, "connect": self.connect,
            "tls": None if self.tls is None else attrs.asdict(self.tls),
            "link_down_s": self.link_down_s, "lease_s": self.lease_s, "peers": self.peers,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ZenohBridge:
        return cls(d["namespace"], [Export(**e) for e in d["exports"]], [Import(**i) for i in d["imports"]],
                   d["listen"], d["connect"], None if d.get("tls") is None else TlsFiles(**d["tls"]),
                   d.get("link_down_s", 5.0), d.get("lease_s", 3.0), d.get("peers"))

    def __repr__(self) -> str:
        return (f"ZenohBridge({self.namespace!r}, exports={[e.topic for e in self.exports]}, "
                f"imports={[i.key for i in self.imports]}, listen={self.listen}, connect={self.connect})")


def zenoh_available() -> tuple[bool, str]:
    """Whether zenoh-python (with zenoh.ext) can be imported here."""
    try:
        import importlib

        importlib.import_module("zenoh")
        importlib.import_module("zenoh.ext")
    except Exception as e:  # noqa: BLE001
        return False, f"the Zenoh bridge needs eclipse-zenoh ({type(e).__name__}: {e}); {ZENOH_EXTRA_HINT}"
    return True, "zenoh imports"
