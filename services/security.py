"""A secured site: its certificate authority, one certificate per identity, and the zenoh configs that make
every link mutual TLS and let the router's access control decide who may write which key.

Security is zenoh's own (TLS, mTLS, access control by certificate common name); nothing here authenticates.
What this module writes is the policy (docs/security.md):

* every identity with a certificate from the site CA may subscribe, query and watch liveliness on the
  whole key space;
* each service may write (put, answer queries, assert liveliness) only its own keys: the assembler
  `map/cloud` and `map/pose`, features `fields`, inference `affordance/*` and `next-views`, each its
  `status/` and `error/`;
* sensors (listed clients) may put `scan/**`; mappers (listed clients) may put a finished `map/cloud`;
  operators (listed clients) may put `control/**`: a reset of a robot's map and state (no one else may);
* one identity per robot: a sensor or mapper named `NAME@ROBOT`, and the services of a robot given with
  `robots` (`assembler@ROBOT`, ...), write only under `afford/@v1/<ROBOT>/`; a plain `NAME` (and the plain
  `assembler`, `features`, `inference`) writes under every robot's name, as a single-robot site needs;
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
    "inference": ("affordance/*", "next-views"),
}
ROUTER = "router"
CA = "ca"
_WRITE = ["put", "delete", "declare_queryable", "reply", "liveliness_token"]
_READ = ["declare_subscriber", "query", "declare_liveliness_subscriber", "liveliness_query"]
_ALL = sorted({*_WRITE, *_READ})


def bound(identity: str) -> tuple[str, str | None]:
    """An identity's name and the robot it is bound to: `NAME@ROBOT` writes only that robot's keys, a plain
    `NAME` every robot's (`@` is in no identity or robot name, so the split is unambiguous)."""
    name, at, robot = identity.partition("@")
    return name, robot if at else None


def _check_name(what: str, name: str) -> None:
    # names become file names and certificate common names: keep them to a portable alphabet
    if not name or not all(c.isalnum() or c in "-_." for c in name):
        raise ValueError(f"{what} {name!r}: use letters, digits, '-', '_' or '.'")


@dataclass
class Site:
    """Who is in a secured site: the services, the sensors that may publish scans, the mappers that may
    publish a finished room, the operators that may reset a robot (`afford reset`), and read-only viewers
    (`afford watch`).

    A sensor, mapper or operator `NAME@ROBOT` is bound to ROBOT; each robot in `robots`, and each a sensor or
    mapper is bound to, also gets its own service identities (`assembler@ROBOT`, ...) bound likewise."""

    sensors: list[str] = field(default_factory=lambda: ["robot"])
    mappers: list[str] = field(default_factory=list)
    viewers: list[str] = field(default_factory=lambda: ["viewer"])
    operators: list[str] = field(default_factory=lambda: ["operator"])
    router_names: list[str] = field(default_factory=lambda: ["localhost", "127.0.0.1"])
    router_endpoint: str = "tls/localhost:7447"
    listen: str = "tls/0.0.0.0:7447"
    robots: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        for identity in self.viewers:
            if "@" in identity:
                raise ValueError(
                    f"viewer {identity!r}: a viewer reads every robot and writes nothing, so it is bound to "
                    "none (NAME@ROBOT is for sensors and mappers)"
                )
        for robot in self.robots:
            _check_name("robot name", robot)
        for identity in [*self.sensors, *self.mappers, *self.operators, *self.viewers]:
            name, robot = bound(identity)
            _check_name(f"identity {identity!r}: name" if robot is not None else "identity name", name)
            if robot is not None:
                _check_name(f"identity {identity!r}: robot", robot)
        names = self.clients()
        taken = {n for n in names if names.count(n) > 1} | ({ROUTER, CA} & set(names))
        if taken:
            raise ValueError(f"identity names must be unique and not 'router' or 'ca': {sorted(taken)}")

    def robot_names(self) -> list[str]:
        """The robots with identities of their own: those given, then those a sensor or mapper names."""
        named = [bound(identity)[1] for identity in [*self.sensors, *self.mappers]]
        return list(dict.fromkeys([*self.robots, *(robot for robot in named if robot)]))

    def clients(self) -> list[str]:
        services = [f"{service}@{robot}" for robot in self.robot_names() for service in SERVICES]
        return [*SERVICES, *services, *self.sensors, *self.mappers, *self.operators, *self.viewers]

    def writes(self) -> dict[str, list[str]]:
        """{identity: key expressions it alone may write}."""

        def under(robot: str | None, key: str) -> str:
            return f"{PREFIX}/{robot or '*'}/{key}"

        writes = {}
        for robot in [None, *self.robot_names()]:
            for service in SERVICES:
                identity = f"{service}@{robot}" if robot else service
                owned = [*OWNED[service], f"status/{service}", f"error/{service}"]
                writes[identity] = [under(robot, key) for key in owned]
        for identity in self.sensors:
            writes[identity] = [under(bound(identity)[1], "scan/**")]
        for identity in self.mappers:
            writes.setdefault(identity, []).append(under(bound(identity)[1], "map/cloud"))
        for identity in self.operators:
            writes.setdefault(identity, []).append(under(bound(identity)[1], "control/**"))
        # sharded inference workers (docs/deploy.md), which serve many robots and so run as the site-wide
        # `inference`: refusals on error/inference-<worker>, their tokens and status under `@workers`
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
