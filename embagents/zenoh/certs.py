"""``embagents keys --tls``: a small CA and per-host certificates for the Zenoh bridge's mutual TLS.

Made with ``cryptography`` (ECDSA P-256, SHA-256). In the folder: ``ca.pem``
(give it to every host), ``ca.key`` (keep it on the machine that signs, mode
0600), and per host ``HOST.pem`` + ``HOST.key`` (mode 0600; copy both to that
host). A certificate not signed by this CA is refused by every bridge.

Example::

    $ embagents keys --tls --host robot1 --dir ~/fleet-tls
    $ embagents keys --tls --host gpu --ip 192.168.1.20 --dir ~/fleet-tls
"""

from __future__ import annotations

import datetime
import ipaddress
import os
from collections.abc import Sequence

__all__ = ["make_ca", "make_host"]

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
