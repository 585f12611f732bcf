"""The certificate and key files of a Zenoh config, checked before any connection (``check_tls_files``).

Zenoh reports a missing, corrupted or mismatched certificate only as a failure to connect, the
same words as a dead router. So every process with a config file checks its
``transport/link/tls`` files first and names the file and what is wrong with it: not readable,
not PEM, not a certificate or key, a key that is not the certificate's, a certificate not valid
now.
"""

from __future__ import annotations

import datetime
import json
import os
from typing import TYPE_CHECKING

import zenoh

from runtime.errors import SwarmInputError

if TYPE_CHECKING:
    from cryptography import x509
    from cryptography.hazmat.primitives.asymmetric.types import PrivateKeyTypes

CERTIFICATES = ("root_ca_certificate", "listen_certificate", "connect_certificate")
KEY_OF = {"listen_private_key": "listen_certificate", "connect_private_key": "connect_certificate"}  # key -> its certificate


def _read(path: object, where: str) -> bytes:
    if not isinstance(path, str) or not os.path.isfile(path) or not os.access(path, os.R_OK):
        raise SwarmInputError(f"{where} {path!r} is not a readable file")
    with open(path, "rb") as f:
        data = f.read()
    if not data.strip():
        raise SwarmInputError(f"{where} {path}: the file is empty")
    return data


def _certificates(data: bytes, where: str, path: str) -> list[x509.Certificate]:
    from cryptography import x509  # noqa: PLC0415 - only for processes with TLS files

    if b"-----BEGIN CERTIFICATE-----" not in data:
        raise SwarmInputError(f"{where} {path}: no PEM certificate in it (expected '-----BEGIN CERTIFICATE-----'; a key or "
                              f"another file given by mistake?)")
    try:
        certs = x509.load_pem_x509_certificates(data)
    except ValueError as exc:
        raise SwarmInputError(f"{where} {path}: the certificate is corrupted or truncated ({exc})") from None
    now = datetime.datetime.now(datetime.UTC)
    for cert in certs:
        if now > cert.not_valid_after_utc:
            raise SwarmInputError(f"{where} {path}: the certificate {cert.subject.rfc4514_string()} expired on "
                                  f"{cert.not_valid_after_utc:%Y-%m-%d %H:%M} UTC")
        if now < cert.not_valid_before_utc:
            raise SwarmInputError(f"{where} {path}: the certificate {cert.subject.rfc4514_string()} is valid only from "
                                  f"{cert.not_valid_before_utc:%Y-%m-%d %H:%M} UTC (is this machine's clock right?)")
    return certs


def _key(data: bytes, where: str, path: str) -> PrivateKeyTypes:
    from cryptography.hazmat.primitives import serialization  # noqa: PLC0415

    if b"PRIVATE KEY-----" not in data:
        raise SwarmInputError(f"{where} {path}: no PEM private key in it (expected '-----BEGIN ... PRIVATE KEY-----'; a "
                              f"certificate given by mistake?)")
    try:
        return serialization.load_pem_private_key(data, password=None)
    except TypeError:
        raise SwarmInputError(f"{where} {path}: the private key is encrypted (Zenoh needs it without a passphrase)") from None
    except Exception as exc:  # noqa: BLE001 - cryptography raises several kinds for a broken key
        raise SwarmInputError(f"{where} {path}: the private key is corrupted or truncated ({exc})") from None


def check_tls_files(config: zenoh.Config, source: str) -> None:
    """``SwarmInputError`` naming the field, the file and what is wrong, for the certificates and keys of
    ``transport/link/tls`` in ``config`` (from ``source``, e.g. ``--zenoh-config gw.json5``)."""
    from cryptography.hazmat.primitives import serialization  # noqa: PLC0415

    tls = json.loads(config.get_json("transport/link/tls"))
    certs = {}
    for field in CERTIFICATES:
        if tls.get(field) is not None:
            where = f"{source}: transport/link/tls/{field}"
            certs[field] = _certificates(_read(tls[field], where), where, tls[field])
    for field, cert_field in KEY_OF.items():
        if tls.get(field) is None:
            continue
        where = f"{source}: transport/link/tls/{field}"
        key = _key(_read(tls[field], where), where, tls[field])
        if cert_field in certs:
            raw = serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo
            if key.public_key().public_bytes(*raw) != certs[cert_field][0].public_key().public_bytes(*raw):
                raise SwarmInputError(f"{where} {tls[field]} is not the key of {cert_field} {tls[cert_field]} "
                                      f"(a key and certificate of different hosts?)")
