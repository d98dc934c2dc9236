"""Where this user's private run state lives, and the check that it is still private.

Everything a run writes (its run directory with sockets, registry, journals
and snapshots; the announcements ``embagents status`` finds runs by; helper
files such as DDS profiles) lives in one folder per user:

- ``$XDG_RUNTIME_DIR/<app>`` when ``XDG_RUNTIME_DIR`` is set (the
  login's runtime folder: the user's own, mode 0700, emptied at logout);
- else ``<tmp>/<app>-<uid>`` (``<tmp>`` is ``$TMPDIR`` or ``/tmp``).

``<app>`` is the application's name (:mod:`actors.app`; "embagents" sets it).

Every use checks the folder (and ``XDG_RUNTIME_DIR`` itself) as ssh and tmux
do: it must be a real directory, owned by this user, with no access for
group or others. Anything else raises :class:`UnsafeFolder`, whose message
names the folder and the fix; nothing is written there. Another user of a
shared machine could otherwise pre-create ``/tmp/embagents-<uid>``
world-writable and read, replace or delete what a run puts there.

Files are never made under predictable names in shared folders:
:func:`private_file` creates them with ``mkstemp`` (``O_EXCL``, mode 0600)
inside the run directory when this process belongs to a run (the run
directory is removed when the run ends, even after a crash: the fork server
removes it when the root dies), else inside the private folder, removed when
the process exits (files of processes that were killed are swept at the
next :func:`private_file`).

Example::

    >>> import os
    >>> folder = private_dir()
    >>> oct(os.stat(folder).st_mode & 0o777)
    '0o700'
    >>> path = private_file("doc", ".txt", b"hello")
    >>> os.path.dirname(path) in (folder, current_run_dir())
    True
"""

from __future__ import annotations

import atexit
import contextlib
import os
import pwd
import re
import stat
import tempfile

from actors.app import app_name
from actors.errors import ActorError

__all__ = ["UnsafeFolder", "check_folder", "current_run_dir", "pid_alive", "private_dir", "private_file"]

# mkstemp names: "<prefix>-<pid>-<8 random chars><suffix>"; the pid lets a later process sweep orphans.
_ORPHAN = re.compile(r"-(\d+)-[a-z0-9_]{8}(?:\.\w+)?$")


class UnsafeFolder(ActorError, PermissionError):
    """A folder for private run files is not private (another owner, or open to others)."""


def _who(uid: int) -> str:
    try:
        return f"uid {uid} ({pwd.getpwuid(uid).pw_name})"
    except KeyError:
        return f"uid {uid}"


def check_folder(path: str, *, create: bool = True, follow: bool = False) -> str:
    """``path`` if it is a directory of this user's with mode 0700 (created so if missing).

    Raises :class:`UnsafeFolder` naming the folder and the fix when it is a
    symbolic link (unless ``follow``), not a directory, owned by someone
    else, or open to group or others.
    """
    if create:
        with contextlib.suppress(FileExistsError):
            os.mkdir(path, 0o700)  # mkdir, not makedirs: the parent is checked by our caller
    try:
        st = os.stat(path) if follow else os.lstat(path)
    except FileNotFoundError:
        raise UnsafeFolder(f"{path} does not exist: create it with `mkdir -m 700 {path}`") from None
    uid = os.getuid()
    why = fix = ""
    if stat.S_ISLNK(st.st_mode):
        why, fix = "it is a symbolic link (to wherever its maker chose)", f"remove it (`rm {path}`) and run again"
    elif not stat.S_ISDIR(st.st_mode):
        why, fix = "it is not a directory", f"remove it (`rm {path}`) and run again"
    elif st.st_uid != uid:
        why = f"it belongs to {_who(st.st_uid)}, not to you ({_who(uid)})"
        fix = f"remove it as its owner or root (`rm -rf {path}`) and run again, or set XDG_RUNTIME_DIR to a folder of yours"
    elif st.st_mode & 0o077:
        access = "write to" if st.st_mode & 0o022 else "read"
        why = f"group or others may {access} it (mode {oct(st.st_mode & 0o777)[2:]})"
        fix = f"`chmod 700 {path}`"
    if why:
        raise UnsafeFolder(
            f"refusing to use {path} for private run files: {why}; another user could read or replace "
            f"what a run puts there. Fix: {fix}"
        )
    return path


def private_dir(*parts: str) -> str:
    """This user's private folder (see the module docs), or a checked subfolder of it."""
    xdg = os.environ.get("XDG_RUNTIME_DIR")
    if xdg:
        base = os.path.join(check_folder(xdg, create=False, follow=True), app_name())
    else:
        base = os.path.join(tempfile.gettempdir(), f"{app_name()}-{os.getuid()}")
    path = check_folder(base)
    for part in parts:
        path = check_folder(os.path.join(path, part))
    return path


def current_run_dir() -> str | None:
    """The run directory of this process's actor system, or None outside a run."""
    from actors.runtime import current  # late: runtime imports the whole transport

    try:
        rt = current()
    except RuntimeError:
        return None
    return None if rt.closed else rt.run_dir


def pid_alive(pid: int) -> bool:
    """True while process ``pid`` exists (someone else's counts: we may not signal it, but it is there)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _sweep_orphans(folder: str) -> None:
    """Remove files :func:`private_file` made for processes that are gone (killed before atexit)."""
    with os.scandir(folder) as entries:
        for e in entries:
            m = _ORPHAN.search(e.name)
            if m and e.is_file(follow_symlinks=False) and not pid_alive(int(m.group(1))):
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(e.path)


def _unlink(path: str, owner: int | None = None) -> None:
    if owner is not None and owner != os.getpid():
        return  # a forked child inherited the atexit hook: the file is its parent's
    with contextlib.suppress(FileNotFoundError):
        os.unlink(path)


def private_file(prefix: str, suffix: str, data: bytes) -> str:
    """Write ``data`` to a new file only this user can read; returns its path.

    The name is unpredictable (``mkstemp``: ``O_EXCL``, mode 0600). Inside a
    run it lives in the run directory and goes with it; outside one it lives
    in :func:`private_dir` and is removed when this process exits.
    """
    run_dir = current_run_dir()
    folder = run_dir if run_dir is not None else private_dir()
    if run_dir is None:
        _sweep_orphans(folder)
    fd, path = tempfile.mkstemp(prefix=f"{prefix}-{os.getpid()}-", suffix=suffix, dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
    except BaseException:
        _unlink(path)
        raise
    if run_dir is None:
        atexit.register(_unlink, path, os.getpid())
    return path
