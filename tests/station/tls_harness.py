"""Throwaway TLS files for the quic/ and tls/ shard tests, made at test time
with ``trustme`` (a CA in memory, certificates it signs, written as PEM)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import trustme

from gcs_swarm.runtime.zbus import TlsFiles


@dataclass(frozen=True)
class Pki:
    """One CA's files: the controller's side (a certificate for 127.0.0.1,
    the address the shards connect to) and a shard's (its own certificate)."""

    controller: TlsFiles
    shard: TlsFiles


def make_pki(folder: Path) -> Pki:
    """A new CA and its two certificates, as PEM files in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    ca = trustme.CA()
    ca_path = folder / "ca.pem"
    ca.cert_pem.write_to_path(str(ca_path))
    sides = {}
    for side, identity in (("controller", "127.0.0.1"), ("shard", "shard.gcs-swarm.test")):
        issued = ca.issue_cert(identity)
        cert, key = folder / f"{side}.pem", folder / f"{side}.key"
        issued.cert_chain_pems[0].write_to_path(str(cert))
        issued.private_key_pem.write_to_path(str(key))
        sides[side] = TlsFiles(ca=ca_path, cert=cert, key=key)
    return Pki(controller=sides["controller"], shard=sides["shard"])


def cli_options(files: TlsFiles) -> list[str]:
    """``files`` as the command line's ``--tls-ca/--tls-cert/--tls-key``."""
    return ["--tls-ca", str(files.ca), "--tls-cert", str(files.cert), "--tls-key", str(files.key)]
