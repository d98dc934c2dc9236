"""``embagents keys``: make a CURVE key pair for model actors on another machine.

The secret key file is written mode 0600 (never over an existing one) in a
folder the user names or in :func:`keys_dir`; both must be private (this
user's, mode 0700: checked as for run files). The public key is printed on
stdout, the files on stderr. Give the public key to the other end: a server
takes it with ``--allow``, a client as ``server_key``.

Keys are not kept in the run folder: ``$XDG_RUNTIME_DIR`` is emptied at logout.

Example::

    $ embagents keys --name robot
    Lh9w0... (the public key)
"""

from __future__ import annotations

import argparse
import os
import sys

from actors import UnsafeFolder, check_folder
from actors.curve import KeyFileError, write_keypair

__all__ = ["keys_arguments", "keys_dir", "run"]


def keys_dir() -> str:
    """``$XDG_CONFIG_HOME/embagents/keys`` (default ``~/.config``): this user's, mode 0700, checked."""
    config = os.environ.get("XDG_CONFIG_HOME") or os.path.join(os.path.expanduser("~"), ".config")
    parent = os.path.join(config, "embagents")
    os.makedirs(parent, exist_ok=True)
    return check_folder(os.path.join(parent, "keys"))


def keys_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dir", metavar="FOLDER", help="where to write the key files (default: ~/.config/embagents/keys)")
    parser.add_argument("--name", default="embagents",
                        help="file names NAME.key (public) and NAME.key_secret (default: embagents, the default key)")
    parser.add_argument("--tls", action="store_true",
                        help="instead: TLS certificates for the Zenoh bridge (a CA, made once, and --host's certificate)")
    parser.add_argument("--host", help="with --tls: the host the certificate is for (files HOST.pem, HOST.key)")
    parser.add_argument("--ip", action="append", default=[], help="with --tls: an address of that host (repeatable)")


def _tls(args: argparse.Namespace, folder: str) -> int:
    from embagents.zenoh.certs import make_ca, make_host

    if not args.host:
        print("error: --tls needs --host NAME (e.g. --host robot1): each host gets its own certificate",
              file=sys.stderr)
        return 1
    try:
        ca, made = make_ca(folder)
        cert, key = make_host(folder, args.host, args.ip)
    except (OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"{'made' if made else 'using'} CA {ca} (its key ca.key stays here)\n"
          f"certificate {cert}, key {key} (mode 600): copy ca.pem, {os.path.basename(cert)} and "
          f"{os.path.basename(key)} to {args.host}; there: ZenohBridge(..., tls=TlsFiles.of_host(FOLDER, "
          f"{args.host!r}))", file=sys.stderr)
    print(cert)
    return 0


def run(args: argparse.Namespace) -> int:
    """Write the pair; print the public key. Exit 1 with the fix when the folder or name cannot be used."""
    try:
        folder = check_folder(os.path.abspath(args.dir)) if args.dir else keys_dir()
        if getattr(args, "tls", False):
            return _tls(args, folder)
        public, secret_file = write_keypair(folder, args.name)
    except UnsafeFolder as exc:
        print(f"error: {exc}; or name a private folder of yours (`mkdir -m 700 DIR`, then --dir DIR)", file=sys.stderr)
        return 1
    except (KeyFileError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"secret key: {secret_file} (mode 600: keep it here)\npublic key: {secret_file[:-7]} "
          "(give it to the other end: --allow on a server, server_key= on a client)", file=sys.stderr)
    print(public.decode())
    return 0
