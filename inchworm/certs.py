"""A lab certificate authority and one TLS certificate per host, for mutual TLS (``swarm certs``).

``make_certs(out, hosts)`` writes into ``out`` (created if missing; files are PEM):

* ``ca.pem`` / ``ca.key``: the lab CA (EC P-256, self-signed, ``ca_days`` valid, default
  3650). An existing pair in ``out`` is reused, so hosts added later are signed by the
  same CA; a lone ``ca.pem`` or ``ca.key``, or a pair that does not match, is an error.
* ``<name>.pem`` / ``<name>.key`` per host (default hosts: router, coordinator,
  gateway, estop), re-issued on every call: EC P-256, signed by the CA, ``days`` valid
  (default 825), common name = ``<name>`` (the subject the router's access control
  matches, see ``deploy/zenoh-router-tls-acl.json5``), subject alternative names =
  ``DNS:<name>``, the extra SANs of the host (IP addresses become ``IP:``,
  anything else ``DNS:``) and always ``IP:127.0.0.1`` (so loopback works), usable as
  TLS server and client (extended key usage serverAuth + clientAuth).

Private keys are created with mode 0600, certificates 0644. Uses the ``openssl`` command-line tool (OpenSSL
1.1.1 or 3.x). Bad input (bad names, missing openssl, unwritable directory) is a ``SwarmInputError``.
"""

from __future__ import annotations

import ipaddress
import os
import re
import secrets
import shutil
import subprocess
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from runtime.errors import OptionError, SwarmInputError

DEFAULT_HOSTS = ("router", "coordinator", "gateway", "estop")
LOOPBACK_SAN = "IP:127.0.0.1"
CA_SUBJECT = "/O=inchworm-swarm/CN=inchworm-swarm lab CA"
_NAME = re.compile(r"[A-Za-z0-9]([A-Za-z0-9.-]{0,61}[A-Za-z0-9])?")
_DNS = re.compile(r"[A-Za-z0-9*]([A-Za-z0-9.-]{0,251}[A-Za-z0-9])?")
_EC_KEY = ("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes")
FLAGS = {"hosts": "--host"}  # the flags of the options whose flag is not their name (``OptionError``)


@dataclass(frozen=True)
class HostSpec:
    """One certificate to issue: common name ``name`` and subject alternative names ``sans`` (``DNS:x`` / ``IP:x``)."""

    name: str
    sans: tuple[str, ...]


def parse_host(text: str) -> HostSpec:
    """``NAME`` or ``NAME=SAN,SAN,...`` (SAN: an IP address or a DNS name) as a ``HostSpec``."""
    name, _, extra = text.partition("=")
    name = name.strip()
    if not _NAME.fullmatch(name) or name.lower() == "ca":
        raise OptionError("hosts", f"{text!r}: the name must be 1-63 characters of A-Z a-z 0-9 . - "
                                   "starting and ending with a letter or digit, and not 'ca'", FLAGS)
    sans = [f"DNS:{name}"]
    for item in (s.strip() for s in extra.split(",")):
        if not item:
            continue
        try:
            sans.append(f"IP:{ipaddress.ip_address(item.strip('[]'))}")
        except ValueError:
            if not _DNS.fullmatch(item):
                raise OptionError("hosts", f"{text!r}: {item!r} is neither an IP address nor a DNS name", FLAGS) from None
            sans.append(f"DNS:{item}")
    sans.append(LOOPBACK_SAN)
    return HostSpec(name, tuple(dict.fromkeys(sans)))  # de-duplicated, order kept


def _openssl() -> str:
    exe = shutil.which("openssl")
    if exe is None:
        raise SwarmInputError("the openssl command was not found on PATH: install it (e.g. apt-get install openssl)")
    return exe


def _run(openssl: str, *args: str) -> str:
    """Run ``openssl args...`` with umask 077 (keys are never readable by others); its stdout."""
    proc = subprocess.run([openssl, *args], capture_output=True, text=True, umask=0o077, check=False)
    if proc.returncode != 0:
        detail = (proc.stderr or proc.stdout).strip().splitlines()
        raise SwarmInputError(f"openssl {args[0]} failed: {detail[-1] if detail else f'exit {proc.returncode}'}")
    return proc.stdout


def ensure_ca(openssl: str, out: Path, days: int) -> bool:
    """Create ``out/ca.pem`` + ``out/ca.key`` unless both exist and match; True if reused."""
    cert, key = out / "ca.pem", out / "ca.key"
    if cert.exists() or key.exists():
        if not (cert.is_file() and key.is_file()):
            raise SwarmInputError(f"{out} holds only one of ca.pem and ca.key: remove it or restore the other")
        cert_pub = _run(openssl, "x509", "-in", str(cert), "-noout", "-pubkey")
        key_pub = _run(openssl, "pkey", "-in", str(key), "-pubout")
        if cert_pub.strip() != key_pub.strip():
            raise SwarmInputError(f"{cert} and {key} do not belong together (different public keys)")
        return True
    _run(openssl, "req", "-x509", *_EC_KEY, "-keyout", str(key), "-out", str(cert), "-days", str(days),
         "-subj", CA_SUBJECT, "-addext", "basicConstraints=critical,CA:TRUE",
         "-addext", "keyUsage=critical,keyCertSign,cRLSign")
    os.chmod(key, 0o600)
    os.chmod(cert, 0o644)
    return False


def issue(openssl: str, out: Path, host: HostSpec, days: int) -> tuple[Path, Path]:
    """Write ``out/<name>.pem`` and ``out/<name>.key`` signed by the CA in ``out``; their paths."""
    cert, key = out / f"{host.name}.pem", out / f"{host.name}.key"
    with tempfile.TemporaryDirectory(prefix="swarm-certs-") as tmp:
        csr, ext = Path(tmp) / "host.csr", Path(tmp) / "host.ext"
        ext.write_text(
            f"subjectAltName={','.join(host.sans)}\n"
            "basicConstraints=critical,CA:FALSE\n"
            "keyUsage=critical,digitalSignature\n"  # EC keys sign, never encipher
            "extendedKeyUsage=serverAuth,clientAuth\n"
            "subjectKeyIdentifier=hash\n"
            "authorityKeyIdentifier=keyid,issuer\n"
        )
        key.unlink(missing_ok=True)  # a fresh file gets the umask's 0600
        _run(openssl, "req", "-new", *_EC_KEY, "-keyout", str(key), "-out", str(csr), "-subj", f"/CN={host.name}")
        _run(openssl, "x509", "-req", "-in", str(csr), "-CA", str(out / "ca.pem"), "-CAkey", str(out / "ca.key"),
             "-set_serial", f"0x{secrets.token_hex(16)}", "-days", str(days), "-sha256",
             "-extfile", str(ext), "-out", str(cert))
    os.chmod(key, 0o600)
    os.chmod(cert, 0o644)
    return cert, key


_DEFAULT_SPECS = tuple(HostSpec(h, ()) for h in DEFAULT_HOSTS)


def make_certs(out: Path, hosts: Sequence[HostSpec] = _DEFAULT_SPECS, days: int = 825, ca_days: int = 3650,
               say: Callable[[str], None] | None = None) -> dict[str, Any]:
    """The CA (reused if ``out`` has one) and a certificate per host in ``out``; ``say`` gets a line per file written.

    Returns ``{"out": DIR, "ca": {"cert", "key", "reused"}, "hosts": {name: {"cert", "key", "sans"}}}``.
    """
    names = [h.name for h in hosts]
    if len(set(names)) != len(names):
        raise OptionError("hosts", f"must have distinct names, got {names}", FLAGS)
    for name, value in (("days", days), ("ca_days", ca_days)):
        if value < 1:
            raise OptionError(name, f"must be at least 1, got {value}")
    openssl = _openssl()
    if out.exists() and not out.is_dir():
        raise OptionError("out", f"{out} exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    reused = ensure_ca(openssl, out, ca_days)
    if say:
        say(f"{'reused' if reused else 'wrote'} CA {out / 'ca.pem'} (key {out / 'ca.key'})")
    result: dict[str, Any] = {"out": str(out), "ca": {"cert": str(out / "ca.pem"), "key": str(out / "ca.key"), "reused": reused}, "hosts": {}}
    for host in hosts:
        cert, key = issue(openssl, out, host, days)
        if say:
            say(f"wrote {cert} and {key} (CN {host.name}; {', '.join(host.sans)})")
        result["hosts"][host.name] = {"cert": str(cert), "key": str(key), "sans": list(host.sans)}
    return result
