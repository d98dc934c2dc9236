"""supervisor: OTP-style supervision trees over actor processes and external commands.

Example::

    from actors import ActorSystem
    from supervisor import ChildSpec, SupervisorSpec, start_supervisor
    system = ActorSystem()
    sup = start_supervisor(system, SupervisorSpec(strategy="one_for_one", children=[
        ChildSpec("echo", Echo, heartbeat=2.0, max_rss_mb=500)]))
    sup.which_children()
    # [ChildInfo(id='echo', pid=4242, type='worker', module='demo:Echo')]
"""

from supervisor.backoff import Backoff, backoff_delay
from supervisor.errors import StartError, SupervisorError
from supervisor.events import TOPIC as EVENTS_TOPIC
from supervisor.exits import Exit, Reason
from supervisor.spec import ChildSpec, Command, Restart, Strategy, SupervisorSpec
from supervisor.states import ChildStatus, SupervisorState
from supervisor.supervisor import ChildInfo, Supervisor, start_supervisor
from supervisor.tree import Tree

__all__ = [
    "EVENTS_TOPIC",
    "Backoff",
    "ChildInfo",
    "ChildSpec",
    "ChildStatus",
    "Command",
    "Exit",
    "Reason",
    "Restart",
    "StartError",
    "Strategy",
    "Supervisor",
    "SupervisorError",
    "SupervisorSpec",
    "SupervisorState",
    "Tree",
    "backoff_delay",
    "start_supervisor",
]
