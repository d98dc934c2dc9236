"""The tests; like the embagents package, they name the application "embagents" (actors.app).

Set here, not in a conftest: subprocesses started as ``python -m tests...``
(a supervision root that imports only ``supervisor``) import this package too.
"""

from actors.app import set_app_name

set_app_name("embagents")
