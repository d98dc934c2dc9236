"""Topics between hosts on Zenoh: declarations here, zenoh only in :mod:`embagents.zenoh.bridge_actor`.

``system.py`` declares one :class:`ZenohBridge` per host (``System(..., zenoh=ZenohBridge(...))``);
the run starts one supervised bridge actor for it, the only process that imports zenoh.

Example::

    >>> from embagents.zenoh import Import, ZenohBridge
    >>> ZenohBridge("gpu", exports=["detections"], imports=[Import("robot1/camera/image", topic="image")],
    ...             listen=["tcp/127.0.0.1:7447"]).listen
    ['tcp/127.0.0.1:7447']
"""

from embagents.zenoh.spec import (
    BRIDGE_NAME,
    ZENOH_EXTRA_HINT,
    Export,
    Import,
    TlsFiles,
    ZenohBridge,
    check_endpoint,
    zenoh_available,
)

__all__ = ["BRIDGE_NAME", "Export", "Import", "TlsFiles", "ZENOH_EXTRA_HINT", "ZenohBridge", "check_endpoint",
           "zenoh_available"]
