"""A TLS identity made at start for a server that only our own process talks to on loopback.

The Foxglove SDK's server sits behind :mod:`app.service.foxglove_gate` on a loopback port of its
own. Speaking TLS there with a certificate that exists only in this process's memory keeps a
browser page from opening that port directly (a browser refuses a WebSocket to a certificate
it does not know, with no prompt), so the gate's Origin and token checks cannot be skipped
from a web page. The gate trusts exactly this certificate (:meth:`LoopbackTls.client_context`).
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import ssl
from dataclasses import dataclass

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

LOOPBACK = "127.0.0.1"


@dataclass(frozen=True)
class LoopbackTls:
    """A self-signed certificate for ``127.0.0.1`` and its key (PEM; the key PKCS#8)."""

    cert_pem: bytes
    key_pem: bytes

    def client_context(self) -> ssl.SSLContext:
        """A client context that trusts this certificate only (host name ``127.0.0.1``)."""
        ctx = ssl.create_default_context(ssl.Purpose.SERVER_AUTH, cadata=self.cert_pem.decode())
        ctx.minimum_version = ssl.TLSVersion.TLSv1_2
        return ctx


def make_loopback_tls(valid_days: int = 3650) -> LoopbackTls:
    """A new P-256 key and a self-signed certificate for ``127.0.0.1``, valid ``valid_days``."""
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "aar-dock loopback")])
    now = dt.datetime.now(dt.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(days=1))
        .not_valid_after(now + dt.timedelta(days=valid_days))
        .add_extension(
            x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address(LOOPBACK))]),
            critical=False,
        )
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .sign(key, hashes.SHA256())
    )
    return LoopbackTls(
        cert_pem=cert.public_bytes(serialization.Encoding.PEM),
        key_pem=key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        ),
    )
