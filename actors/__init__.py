"""actors: processes with mailboxes, topics and shared memory over ZeroMQ."""

from actors import errors
from actors.codec import Codec, message, register
from actors.errors import *  # noqa: F403 - every error class is public

__all__ = ["Codec", "message", "register", *errors.__all__]

from actors.actor import Actor, ActorContext  # noqa: E402
from actors.app import app_name, set_app_name  # noqa: E402
from actors.extension import HostExtension, extension_spec, load_extension  # noqa: E402
from actors.host import ActorHost  # noqa: E402
from actors.journal import Journal  # noqa: E402
from actors.mailbox import Deferred  # noqa: E402
from actors.pdeathsig import die_with_parent  # noqa: E402
from actors.private import UnsafeFolder, check_folder, pid_alive, private_dir, private_file  # noqa: E402
from actors.ref import ActorRef  # noqa: E402
from actors.system import ActorSystem, ProcessInfo  # noqa: E402

__all__ += ["Actor", "ActorContext", "ActorRef", "Deferred", "ActorSystem", "UnsafeFolder", "check_folder", "pid_alive", "private_dir", "private_file"]
__all__ += ["ActorHost", "HostExtension", "Journal", "ProcessInfo", "die_with_parent", "extension_spec", "load_extension"]
__all__ += ["app_name", "set_app_name"]
