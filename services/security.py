"""A secured site: its certificate authority, one certificate per identity, and the zenoh configs that make
every link mutual TLS and let the router's access control decide who may write which key.

Security is zenoh's own (TLS, mTLS, access control by certificate common name); nothing here authenticates.
What this module writes is the policy (docs/security.md):

* every identity with a certificate from the site CA may subscribe, query and watch liveliness on the
  whole key space;
* each service may write (put, answer queries, assert liveliness) only its own keys: the assembler
  `map/cloud` and `map/pose`, features `fields`, inference `affordance/*`, each its `status/` and `error/`;
* sensors (listed clients) may put `scan/**`; mappers (listed clients) may put a finished `map/cloud`;
* anything else is denied, and the router is the only place links meet: services and clients run in client
  mode, listen on nothing and neither scout nor gossip, so no direct link bypasses the router.
"""

from __future__ import annotations

import datetime
import json
from dataclasses import dataclass, field
from pathlib import Path

from .transport import PREFIX, WORKERS

SERVICES = ("assembler", "features", "inference")
# the keys each service alone may write, under afford/@v1/<robot>/
OWNED = {
    "assembler": ("map/cloud", "map/pose"),
    "features": ("fields",),
    "inference": ("affordance/*",),
}
ROUTER = "router"
CA = "ca"
_WRITE = ["put", "delete", "declare_queryable", "reply", "liveliness_token"]
_READ = ["declare_subscriber", "query", "declare_liveliness_subscriber", "liveliness_query"]
_ALL = sorted({*_WRITE, *_READ})


@dataclass
class Site:
    """Who is in a secured site: the services, the sensors that may publish scans, the mappers that may
    publish a finished room, and read-only viewers (`afford watch`)."""

    sensors: list[str] = field(default_factory=lambda: ["robot"])
    mappers: list[str] = field(default_factory=list)
    viewers: list[str] = field(default_factory=lambda: ["viewer"])
    router_names: list[str] = field(default_factory=lambda: ["localhost", "127.0.0.1"])
    router_endpoint: str = "tls/localhost:7447"
    listen: str = "tls/0.0.0.0:7447"

    def __post_init__(self) -> None:
        names = self.clients()
        taken = {n for n in names if names.count(n) > 1} | ({ROUTER, CA} & set(names))
        if taken:
            raise ValueError(f"identity names must be unique and not 'router' or 'ca': {sorted(taken)}")
        for name in names:
            if not name or not all(c.isalnum() or c in "-_." for c in name):
                raise ValueError(f"identity name {name!r}: use letters, digits, '-', '_' or '.'")

    def clients(self) -> list[str]:
        return [*SERVICES, *self.sensors, *self.mappers, *self.viewers]

    def writes(self) -> dict[str, list[str]]:
        """{identity: key expressions it alone may write}."""
        keys = {name: [*OWNED[name], f"status/{name}", f"error/{name}"] for name in SERVICES}
        keys.update({name: ["scan/**"] for name in self.sensors})
        for name in self.mappers:
            keys.setdefault(name, []).append("map/cloud")
        writes = {name: [f"{PREFIX}/*/{key}" for key in ks] for name, ks in keys.items()}
        # sharded inference workers (docs/deploy.md): refusals on error/inference-<worker>, and their own
        # tokens and status under the workers' verbatim chunk
        writes["inference"] += [f"{PREFIX}/*/error/inference-$*", f"{WORKERS}/inference-$*/**"]
        return writes


def access_control(site: Site) -> dict:
    """The router's access_control section: deny by default; every TLS link (the router accepts no other,
    and only with a certificate from the site CA) reads everything; each identity writes only its keys."""
    everything = [f"{PREFIX}/**"]  # "**" does not match the verbatim chunk "@v1": it is spelled out
    rules = [
        {
            "id": "read",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": _READ,
            "key_exprs": everything,
        },
        {
            "id": "deliver",
            "permission": "allow",
            "flows": ["egress"],
            "messages": _ALL,
            "key_exprs": everything,
        },
    ]
    workers = [f"{WORKERS}/**"]  # a verbatim chunk too: the sharded workers' tokens and status (deploy.md)
    rules += [
        {**rules[0], "id": "read-workers", "key_exprs": workers},
        {**rules[1], "id": "deliver-workers", "key_exprs": workers},
    ]
    subjects = [{"id": "site", "link_protocols": ["tls"]}]
    policies = [
        {"id": "site", "subjects": ["site"], "rules": ["read", "deliver", "read-workers", "deliver-workers"]}
    ]
    for name, keys in site.writes().items():
        rules.append(
            {
                "id": f"write-{name}",
                "permission": "allow",
                "flows": ["ingress"],
                "messages": _WRITE,
                "key_exprs": keys,
            }
        )
        subjects.append({"id": name, "cert_common_names": [name]})
        policies.append({"id": name, "subjects": [name], "rules": [f"write-{name}"]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def _tls(folder: Path | None, name: str, router: bool) -> dict:
    """TLS settings with files in `folder`, or named relative to the config file (None: afford's sessions
    read them beside it, `services.transport`)."""

    def file(name: str) -> str:
        return str(folder / name) if folder else name

    own = {"certificate": file(f"{name}.pem"), "private_key": file(f"{name}.key")}
    tls = {
        "root_ca_certificate": file(f"{CA}.pem"),
        "enable_mtls": True,  # a client sends its certificate only when this is set on its side too
        "verify_name_on_connect": True,
        "connect_certificate": own["certificate"],
        "connect_private_key": own["private_key"],
    }
    if router:
        tls |= {"listen_certificate": own["certificate"], "listen_private_key": own["private_key"]}
    return {"protocols": ["tls"], "tls": tls}


def router_config(site: Site, folder: Path) -> dict:
    """The router's zenoh config: TLS only, mutual, on `site.listen`, with the site's access control."""
    return {
        "mode": "router",
        "listen": {"endpoints": [site.listen]},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"link": _tls(folder, ROUTER, router=True)},
        "adminspace": {"enabled": False},
        "access_control": access_control(site),
    }


def client_config(site: Site, folder: Path | None, name: str) -> dict:
    """One identity's zenoh config: a client of the router over mutual TLS that listens on nothing; its
    files in `folder`, or beside the config (None)."""
    return {
        "mode": "client",
        "connect": {"endpoints": [site.router_endpoint]},
        "listen": {"endpoints": []},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"link": _tls(folder, name, router=False)},
    }


def write_site(site: Site, out: Path, mount: Path | None = None, days: int = 825) -> list[Path]:
    """The site's CA (reused when `out` holds one), a certificate and key per identity, `router.json5` (its
    files named where the router finds the folder: `mount`, default `out`; zenohd reads them from there) and
    one `<name>.json5` per client (files named beside it, wherever the folder is copied). Returns what it
    wrote."""
    out.mkdir(parents=True, exist_ok=True)
    mount = (mount or out).absolute()
    ca_cert, ca_key = _site_ca(out, days)
    written = []
    for name in [ROUTER, *site.clients()]:
        hosts = site.router_names if name == ROUTER else []
        written += _issue(out, name, ca_cert, ca_key, hosts, server=name == ROUTER, days=days)
    configs = {ROUTER: router_config(site, mount)} | {n: client_config(site, None, n) for n in site.clients()}
    for name, config in configs.items():
        path = out / f"{name}.json5"
        path.write_text(json.dumps(config, indent=2) + "\n")  # JSON is JSON5
        written.append(path)
    return written


# -- certificates ------------------------------------------------------------------------------------------


def _site_ca(out: Path, days: int):
    """The site CA's certificate and key: read from `out` when there, made otherwise."""
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    cert_path, key_path = out / f"{CA}.pem", out / f"{CA}.key"
    if cert_path.exists() and key_path.exists():
        cert = x509.load_pem_x509_certificate(cert_path.read_bytes())
        return cert, serialization.load_pem_private_key(key_path.read_bytes(), password=None)
    key = _new_key()
    name = _name("affordmap site CA")
    cert = (
        _builder(name, name, key.public_key(), days)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(_key_usage(cert_sign=True), critical=True)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, _sha256())
    )
    _write_pair(cert_path, key_path, cert, key)
    return cert, key


def _issue(out: Path, name: str, ca_cert, ca_key, hosts: list[str], server: bool, days: int) -> list[Path]:
    """A leaf certificate with common name `name` signed by the site CA; the router's also names `hosts`."""
    import ipaddress

    from cryptography import x509
    from cryptography.x509.oid import ExtendedKeyUsageOID

    key = _new_key()
    usages = [ExtendedKeyUsageOID.CLIENT_AUTH] + ([ExtendedKeyUsageOID.SERVER_AUTH] if server else [])
    alt_names = []
    for host in hosts or [name]:
        try:
            alt_names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            alt_names.append(x509.DNSName(host))
    cert = (
        _builder(_name(name), ca_cert.subject, key.public_key(), days)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(_key_usage(cert_sign=False), critical=True)
        .add_extension(x509.ExtendedKeyUsage(usages), critical=False)
        .add_extension(x509.SubjectAlternativeName(alt_names), critical=False)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False
        )
        .sign(ca_key, _sha256())
    )
    cert_path, key_path = out / f"{name}.pem", out / f"{name}.key"
    _write_pair(cert_path, key_path, cert, key)
    return [cert_path, key_path]


def _new_key():
    from cryptography.hazmat.primitives.asymmetric import ec

    return ec.generate_private_key(ec.SECP256R1())


def _name(common_name: str):
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    return x509.Name(
        [
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, "affordmap site"),
            x509.NameAttribute(NameOID.COMMON_NAME, common_name),
        ]
    )


def _builder(subject, issuer, public_key, days: int):
    from cryptography import x509

    now = datetime.datetime.now(datetime.UTC)
    return (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(issuer)
        .public_key(public_key)
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))  # clocks on a robot network drift
        .not_valid_after(now + datetime.timedelta(days=days))
    )


def _key_usage(cert_sign: bool):
    from cryptography import x509

    return x509.KeyUsage(
        digital_signature=not cert_sign,
        content_commitment=False,
        key_encipherment=False,
        data_encipherment=False,
        key_agreement=False,
        key_cert_sign=cert_sign,
        crl_sign=cert_sign,
        encipher_only=False,
        decipher_only=False,
    )


def _sha256():
    from cryptography.hazmat.primitives import hashes

    return hashes.SHA256()


def _write_pair(cert_path: Path, key_path: Path, cert, key) -> None:
    from cryptography.hazmat.primitives import serialization

    key_path.touch(mode=0o600, exist_ok=True)
    key_path.chmod(0o600)  # a private key is readable by its owner only
    key_path.write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        )
    )
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
