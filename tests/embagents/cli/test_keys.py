"""`embagents keys`: a key pair in a private folder, the public key on stdout."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from actors.curve import is_public_key, load_secret_key


def keys(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "embagents.cli", "keys", *args], capture_output=True, text=True,
                          timeout=60, env={**os.environ, **(env or {})})


def test_keys_go_to_the_private_config_folder_and_the_public_key_is_printed(tmp_path: Path) -> None:
    out = keys(env={"XDG_CONFIG_HOME": str(tmp_path)})
    assert out.returncode == 0, out.stderr
    public = out.stdout.strip()
    folder = tmp_path / "embagents" / "keys"
    assert is_public_key(public) and os.stat(folder).st_mode & 0o777 == 0o700
    secret = folder / "embagents.key_secret"
    assert os.stat(secret).st_mode & 0o777 == 0o600
    assert load_secret_key(str(secret))[0].decode() == public
    again = keys(env={"XDG_CONFIG_HOME": str(tmp_path)})
    assert again.returncode == 1 and "never overwritten" in again.stderr
    assert load_secret_key(str(secret))[0].decode() == public  # the first pair is untouched


def test_keys_refuse_a_folder_others_can_write_naming_the_fix(tmp_path: Path) -> None:
    shared = tmp_path / "shared"
    shared.mkdir(mode=0o777)
    shared.chmod(0o777)
    out = keys("--dir", str(shared), "--name", "robot")
    assert out.returncode == 1 and f"chmod 700 {shared}" in out.stderr and "--dir DIR" in out.stderr
    assert not list(shared.iterdir())
