"""``embagents keys``: make a CURVE key pair for model actors on another machine (or, with
``--tls``, a CA and a host's certificate for the Zenoh bridge's mutual TLS).

The secret key file is written mode 0600 (never over an existing one) in a
folder the user names or in :func:`~embagents.models.remote.keys_dir`; both must be private (this
user's, mode 0700: checked as for run files). The public key is printed on
stdout, the files on stderr. Give the public key to the other end: a server
takes it with ``--allow``, a client as ``server_key``.

Keys are not kept in the run folder: ``$XDG_RUNTIME_DIR`` is emptied at logout.

Example::

    $ embagents keys --name robot
    Lh9w0... (the public key)
    $ embagents keys --tls --host robot1 --dir ~/fleet-tls    # CA once, then robot1.pem / robot1.key
"""

from __future__ import annotations

import argparse
import datetime
import ipaddress
import os
import sys
from collections.abc import Sequence

from actors import UnsafeFolder, check_folder
from actors.curve import KeyFileError, write_keypair
from embagents.models.remote import keys_dir

__all__ = ["arguments", "make_ca", "make_host", "run"]


# --- TLS for the Zenoh bridge (`embagents keys --tls`) ---
# A small CA and per-host certificates with `cryptography` (ECDSA P-256, SHA-256). In the folder:
# ca.pem (give it to every host), ca.key (stays where certificates are signed, mode 0600), and per host
# HOST.pem + HOST.key (mode 0600; copy both to that host). A certificate of another CA is refused.
_DAYS = 825  # the longest validity common TLS clients accept for a leaf certificate


def _write_private(path: str, data: bytes) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)  # never over an existing key
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def _key_pem(key: object) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,  # type: ignore[attr-defined]
                             serialization.NoEncryption())


def make_ca(folder: str, name: str = "embagents fleet CA") -> tuple[str, bool]:
    """``folder/ca.pem`` and ``ca.key``, made unless both exist; returns (ca.pem, made now)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    cert_path, key_path = os.path.join(folder, "ca.pem"), os.path.join(folder, "ca.key")
    if os.path.exists(cert_path) and os.path.exists(key_path):
        return cert_path, False
    if os.path.exists(cert_path) or os.path.exists(key_path):
        raise FileExistsError(f"{folder} has only one of ca.pem / ca.key; move it away or use another --dir")
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(subject).issuer_name(subject).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=3650))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                         content_commitment=False, key_encipherment=False, data_encipherment=False,
                                         key_agreement=False, encipher_only=False, decipher_only=False), critical=True)
            .sign(key, hashes.SHA256()))
    _write_private(key_path, _key_pem(key))
    with open(cert_path, "wb") as f:
        f.write(cert.public_bytes(serialization.Encoding.PEM))
    return cert_path, True


def make_host(folder: str, host: str, ips: Sequence[str] = ()) -> tuple[str, str]:
    """``folder/HOST.pem`` and ``HOST.key`` signed by the folder's CA (names ``host``, ``localhost``, ``ips``)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    if not host or "/" in host or host.startswith("."):
        raise ValueError(f"--host must be a plain name like 'robot1', got {host!r}")
    if host == "ca":
        raise ValueError("--host 'ca' would overwrite the CA's files; pick another name")
    cert_path, key_path = os.path.join(folder, f"{host}.pem"), os.path.join(folder, f"{host}.key")
    if os.path.exists(cert_path) or os.path.exists(key_path):
        raise FileExistsError(f"{cert_path} already exists; pick another --host or remove the old files")
    with open(os.path.join(folder, "ca.pem"), "rb") as f:
        ca_cert = x509.load_pem_x509_certificate(f.read())
    with open(os.path.join(folder, "ca.key"), "rb") as f:
        ca_key = serialization.load_pem_private_key(f.read(), None)
    addresses = [ipaddress.ip_address(a) for a in ["127.0.0.1", *ips]]
    key = ec.generate_private_key(ec.SECP256R1())
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, host)]))
            .issuer_name(ca_cert.subject).public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=_DAYS))
            .add_extension(x509.SubjectAlternativeName([x509.DNSName(host), x509.DNSName("localhost"),
                                                        *(x509.IPAddress(a) for a in addresses)]), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .sign(ca_key, hashes.SHA256()))  # type: ignore[arg-type]
    _write_private(key_path, _key_pem(key))
    with open(cert_path, "wb") as f:
        f.write(cert.public_bytes(serialization.Encoding.PEM))
    return cert_path, key_path


def arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dir", metavar="FOLDER", help="where to write the key files (default: ~/.config/embagents/keys)")
    parser.add_argument("--name", default="embagents",
                        help="file names NAME.key (public) and NAME.key_secret (default: embagents, the default key)")
    parser.add_argument("--tls", action="store_true",
                        help="instead: TLS certificates for the Zenoh bridge (a CA, made once, and --host's certificate)")
    parser.add_argument("--host", help="with --tls: the host the certificate is for (files HOST.pem, HOST.key)")
    parser.add_argument("--ip", action="append", default=[], help="with --tls: an address of that host (repeatable)")


def _tls(args: argparse.Namespace, folder: str) -> int:
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
