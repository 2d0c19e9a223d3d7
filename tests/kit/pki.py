"""Certificates for the tests of TLS, made by ``openssl`` (an independent issuer, as a
user's or cert-manager's would be): a CA, a handler's certificate for the name the
chart's carries, and an impostor's from another CA."""

from __future__ import annotations

import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

NAME = "edgerv-handler.test.svc"  # as the chart's: <release>-handler.<namespace>.svc


@dataclass(frozen=True)
class Pki:
    ca: Path  # the CA the handlers' certificates are signed by
    crt: Path  # a handler's certificate (NAME, 127.0.0.1) and its key
    key: Path
    stranger: Path  # another CA
    other_crt: Path  # a certificate for the same name and address, by the other CA
    other_key: Path


def openssl(*args: str) -> None:
    subprocess.run(["openssl", *args], check=True, capture_output=True)


def make_ca(d: Path, name: str) -> tuple[Path, Path]:
    key, crt = d / f"{name}.key", d / f"{name}.crt"
    openssl("genrsa", "-out", str(key), "2048")
    openssl(
        "req", "-x509", "-new", "-key", str(key), "-days", "2", "-subj", f"/CN={name}",
        "-out", str(crt),
    )  # fmt: skip
    return crt, key


def make_cert(d: Path, ca: tuple[Path, Path], name: str, sans: str) -> tuple[Path, Path]:
    key, csr, crt, ext = (d / f"{name}.{x}" for x in ("key", "csr", "crt", "ext"))
    openssl("genrsa", "-out", str(key), "2048")
    openssl("req", "-new", "-key", str(key), "-subj", f"/CN={name}", "-out", str(csr))
    ext.write_text(f"subjectAltName={sans}\nextendedKeyUsage=serverAuth\n")
    openssl(
        "x509", "-req", "-in", str(csr), "-CA", str(ca[0]), "-CAkey", str(ca[1]),
        "-CAcreateserial", "-days", "2", "-extfile", str(ext), "-out", str(crt),
    )  # fmt: skip
    return crt, key


def make_pki(d: Path) -> Pki:
    ca, stranger = make_ca(d, "edgerv-ca"), make_ca(d, "stranger-ca")
    crt, key = make_cert(d, ca, "handler", f"DNS:{NAME},IP:127.0.0.1")
    other_crt, other_key = make_cert(d, stranger, "impostor", f"DNS:{NAME},IP:127.0.0.1")
    return Pki(ca[0], crt, key, stranger[0], other_crt, other_key)


_made: list[Pki] = []


def shared_pki() -> Pki:
    """One PKI for this test process (made on first use, in a directory of its own)."""
    if not _made:
        _made.append(make_pki(Path(tempfile.mkdtemp(prefix="edgerv-pki-"))))
    return _made[0]
