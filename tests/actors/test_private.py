"""Private run files: the folder check (as ssh and tmux do), XDG_RUNTIME_DIR, mkstemp names, cleanup."""

from __future__ import annotations

import os
import pwd
import re
import signal
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from actors import ActorSystem, UnsafeFolder, private_dir, private_file
from actors.app import app_name

NOBODY = pwd.getpwnam("nobody").pw_uid
# mkstemp: "<prefix>-<pid>-<8 random chars><suffix>"
MKSTEMP_NAME = re.compile(r"^note-(\d+)-[a-z0-9_]{8}\.txt$")


@pytest.fixture
def tmp_base(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A stand-in for /tmp, with XDG_RUNTIME_DIR unset: the private folder is <tmp_path>/embagents-<uid>."""
    monkeypatch.delenv("XDG_RUNTIME_DIR", raising=False)
    monkeypatch.delenv("EMBAGENTS_RUN_BASE", raising=False)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    return tmp_path


def test_the_private_folder_is_made_0700_and_holds_the_run_directory(tmp_base: Path) -> None:
    folder = tmp_base / f"{app_name()}-{os.getuid()}"
    assert private_dir() == str(folder)
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    with ActorSystem() as system:
        assert os.path.dirname(system.run_dir) == str(folder)
        assert stat.S_IMODE(os.stat(system.run_dir).st_mode) == 0o700
    assert os.listdir(folder) == []


def test_a_folder_another_user_made_is_refused_and_left_untouched(tmp_base: Path) -> None:
    folder = tmp_base / f"{app_name()}-{os.getuid()}"
    folder.mkdir(mode=0o777)
    os.chmod(folder, 0o777)
    os.chown(folder, NOBODY, NOBODY)  # what another user of the machine can do in /tmp
    with pytest.raises(UnsafeFolder) as err:
        private_dir()
    msg = str(err.value)
    assert str(folder) in msg and "belongs to uid" in msg and "nobody" in msg and f"rm -rf {folder}" in msg
    with pytest.raises(UnsafeFolder, match=re.escape(str(folder))):
        ActorSystem()
    assert os.listdir(folder) == []


def test_a_folder_of_ours_open_to_others_is_refused_with_the_chmod_that_fixes_it(tmp_base: Path) -> None:
    folder = tmp_base / f"{app_name()}-{os.getuid()}"
    folder.mkdir()
    os.chmod(folder, 0o777)
    with pytest.raises(UnsafeFolder, match=r"group or others may write to it \(mode 777\).*chmod 700 " + re.escape(str(folder))):
        private_dir()
    os.chmod(folder, 0o750)
    with pytest.raises(UnsafeFolder, match=r"may read it \(mode 750\)"):
        private_dir()
    os.chmod(folder, 0o700)  # the fix the message gives
    assert private_dir() == str(folder)


def test_a_symlink_in_place_of_the_folder_is_refused(tmp_base: Path) -> None:
    elsewhere = tmp_base / "elsewhere"
    elsewhere.mkdir(mode=0o700)
    (tmp_base / f"{app_name()}-{os.getuid()}").symlink_to(elsewhere)
    with pytest.raises(UnsafeFolder, match="symbolic link"):
        private_dir()


def test_xdg_runtime_dir_is_used_when_set_and_checked(tmp_base: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    xdg = tmp_base / "xdg"
    xdg.mkdir(mode=0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(xdg))
    assert private_dir("runs") == str(xdg / app_name() / "runs")
    with ActorSystem() as system:
        assert os.path.dirname(system.run_dir) == str(xdg / app_name())
    assert not (tmp_base / f"{app_name()}-{os.getuid()}").exists()  # nothing in the shared temp folder
    os.chmod(xdg, 0o777)
    with pytest.raises(UnsafeFolder, match=re.escape(str(xdg))):
        private_dir()
    os.chmod(xdg, 0o700)
    os.chown(xdg, NOBODY, NOBODY)
    with pytest.raises(UnsafeFolder, match="belongs to uid"):
        private_dir()


def test_the_run_base_override_is_checked_too(tmp_base: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    base = tmp_base / "base"
    base.mkdir(mode=0o700)
    os.chown(base, NOBODY, NOBODY)
    monkeypatch.setenv("EMBAGENTS_RUN_BASE", str(base))
    with pytest.raises(UnsafeFolder, match=re.escape(str(base))):
        ActorSystem()


def test_private_files_get_mkstemp_names_in_the_run_directory_and_go_with_the_run(tmp_base: Path) -> None:
    with ActorSystem() as system:
        a, b = private_file("note", ".txt", b"a"), private_file("note", ".txt", b"b")
        assert a != b and {os.path.dirname(a), os.path.dirname(b)} == {system.run_dir}
        m = MKSTEMP_NAME.match(os.path.basename(a))
        assert m and int(m.group(1)) == os.getpid()
        assert stat.S_IMODE(os.stat(a).st_mode) == 0o600
        assert Path(a).read_bytes() == b"a"
    assert not os.path.exists(a) and not os.path.exists(b)


WRITER = """
import os, sys, tempfile
tempfile.tempdir = sys.argv[1]
from actors import private_file, set_app_name
set_app_name(sys.argv[3])  # as the application does at import
print(private_file("note", ".txt", b"x"), flush=True)
if sys.argv[2] == "hang":
    sys.stdin.read()
"""


def test_outside_a_run_a_private_file_is_removed_at_exit_or_swept_after_a_kill(tmp_base: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k != "XDG_RUNTIME_DIR"}
    out = subprocess.run([sys.executable, "-c", WRITER, str(tmp_base), "exit", app_name()], env=env,
                         capture_output=True, text=True, timeout=60, check=True).stdout.strip()
    assert os.path.dirname(out) == private_dir() and MKSTEMP_NAME.match(os.path.basename(out))
    assert not os.path.exists(out)  # removed when the process exited
    killed = subprocess.Popen([sys.executable, "-c", WRITER, str(tmp_base), "hang", app_name()], env=env,
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        path = killed.stdout.readline().strip()
        assert os.path.exists(path)
    finally:
        killed.send_signal(signal.SIGKILL)
        killed.wait(10)
    assert os.path.exists(path)  # a SIGKILL leaves no time for atexit ...
    mine = private_file("note", ".txt", b"y")
    assert not os.path.exists(path) and os.path.exists(mine)  # ... the next private_file sweeps it
