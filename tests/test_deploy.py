"""The deployment files agree with the code and with each other: docker-compose.yml, deploy/, Dockerfile and the
deployment section of docs/guide.md.

No container runs here (CI has no Docker engine): the files are parsed and every command in them is checked
against the parser that will run it (``rba.cli.build_parser()``, Ray's own ``ray`` CLI, ``sh -n``), every
``RBA_*`` variable against ``server.common.app_settings.Settings``, and ports, volumes, upstreams and paths against
each other. Break a file and a test here fails.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shlex
import subprocess
import tomllib
from importlib import metadata
from pathlib import Path

import pytest
import yaml
from sqlalchemy.engine import make_url

from rba.cli import build_parser
from server.common.app_settings import Settings

ROOT = Path(__file__).resolve().parents[1]
COMPOSE = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
SERVICES: dict[str, dict] = COMPOSE["services"]
NGINX_CONF = ROOT / "deploy" / "nginx.conf"
ENTRYPOINT = ROOT / "deploy" / "entrypoint.sh"
README = (ROOT / "docs" / "guide.md").read_text()  # the user guide: its deployment section
RBA_IMAGE = "rba-studio:latest"
NGINX_RESOLVE_SINCE = (1, 27, 3)  # `server ... resolve` in an upstream: open-source nginx since 1.27.3

# Names the lead's compute work adds; until they exist, the checks that use them are strict xfails.
PENDING_FLAGS = {"--ray": "lead adds --ray"}
PENDING_FIELDS = {"ray_address": "lead adds ray_address"}


# -- reading the files ------------------------------------------------------------------------------

def interpolate(value: str) -> str:
    """What compose makes of ``value`` with no .env and nothing exported: ``${VAR:-default}`` -> default."""
    value = re.sub(r"\$\{(\w+):?-([^}]*)\}", lambda m: m.group(2), value)
    return value.replace("$$", "$")


def command(service: dict) -> list[str]:
    cmd = service.get("command", [])
    return [interpolate(a) for a in (shlex.split(cmd) if isinstance(cmd, str) else cmd)]


def environment(service: dict) -> dict[str, str]:
    env = service.get("environment", {})
    if isinstance(env, list):
        env = dict(item.split("=", 1) for item in env)
    return {k: interpolate(str(v)) for k, v in env.items()}


def mounts(service: dict) -> list[tuple[str, str]]:
    """(source, target) of each volume; a source starting with . is a path in the repository."""
    out = []
    for v in service.get("volumes", []):
        source, target = v.split(":")[:2]
        out.append((source, target))
    return out


def uses_rba_image(service: dict) -> bool:
    return service.get("image") == RBA_IMAGE


def dockerfile() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) of the Dockerfile, continuation lines joined, comments dropped."""
    text = re.sub(r"\\\n\s*", " ", (ROOT / "Dockerfile").read_text())
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.strip().startswith("#")]
    return [(ln.split(None, 1)[0].upper(), ln.split(None, 1)[1] if " " in ln else "") for ln in lines]


def docker_env() -> dict[str, str]:
    env: dict[str, str] = {}
    for op, args in dockerfile():
        if op == "ENV":
            env.update(item.split("=", 1) for item in shlex.split(args))
    return env


def docker_json(op: str) -> list[str]:
    [args] = [a for o, a in dockerfile() if o == op]
    return json.loads(args)


def nginx(text: str) -> list:
    """nginx config as a tree: [(directive, [args], children or None)]."""
    text = re.sub(r"(?m)#.*$", "", text)
    tokens = re.findall(r'"[^"]*"|\'[^\']*\'|[{};]|[^\s{};]+', text)
    pos = 0

    def block() -> list:
        nonlocal pos
        out, words = [], []
        while pos < len(tokens):
            tok = tokens[pos]
            pos += 1
            if tok == ";":
                out.append((words[0], words[1:], None))
                words = []
            elif tok == "{":
                out.append((words[0], words[1:], block()))
                words = []
            elif tok == "}":
                return out
            else:
                words.append(tok.strip("\"'"))
        assert not words, f"nginx config ends inside a directive: {words}"
        return out

    return block()


def directives(tree: list, name: str) -> list[tuple[str, list, list | None]]:
    """Every ``name`` directive at any depth."""
    found = []
    for d in tree:
        if d[0] == name:
            found.append(d)
        if d[2]:
            found += directives(d[2], name)
    return found


NGINX = nginx(NGINX_CONF.read_text())


def api_port() -> int:
    return int(environment(SERVICES["api"]).get("RBA_PORT", docker_env()["RBA_PORT"]))


# -- commands ---------------------------------------------------------------------------------------

def _rba_has(flag: str) -> bool:
    try:
        build_parser().parse_args(["serve", flag, "x"])
    except SystemExit:
        return False
    return True


def _command_cases():
    cases = [(name, command(s)) for name, s in SERVICES.items() if s.get("command")]
    cases.append(("Dockerfile CMD", docker_json("CMD")))
    for name, s in SERVICES.items():
        test = (s.get("healthcheck") or {}).get("test")
        if test and test[0] == "CMD":
            cases.append((f"{name} healthcheck", [interpolate(a) for a in test[1:]]))
    for name, args in cases:
        missing = [f for f in PENDING_FLAGS if args[:1] == ["rba"] and f in args and not _rba_has(f)]
        marks = [pytest.mark.xfail(strict=True, reason=PENDING_FLAGS[missing[0]])] if missing else []
        yield pytest.param(args, id=name, marks=marks)


def check_invocation(args: list[str]) -> None:
    """Fail unless ``args`` is a command line its program accepts (parsed, never run)."""
    program = args[0]
    if program == "rba":
        try:
            build_parser().parse_args(args[1:])
        except SystemExit as exc:
            pytest.fail(f"`{shlex.join(args)}` is not a valid rba command line (exit {exc.code})")
    elif program == "ray":
        scripts = pytest.importorskip("ray.scripts.scripts")
        assert args[1] in scripts.cli.commands, f"`ray {args[1]}` is no ray command"
        sub = scripts.cli.commands[args[1]]
        sub.make_context(args[1], list(args[2:]))  # click raises on an unknown option or a bad value
    elif program == "sh":
        assert args[1] == "-c", args
        r = subprocess.run(["sh", "-n", "-c", args[2]], capture_output=True, text=True)
        assert r.returncode == 0, f"sh syntax error in {args[2]!r}: {r.stderr}"
    else:
        pytest.fail(f"no check for the program {program!r}: add one here")


@pytest.mark.parametrize("args", _command_cases())
def test_every_command_is_a_valid_invocation(args):
    check_invocation(args)


def test_the_entrypoint_joins_the_cluster_with_a_valid_ray_command_then_runs_the_command():
    entry = docker_json("ENTRYPOINT")
    assert entry == [f"/app/{ENTRYPOINT.relative_to(ROOT)}"]
    copies = [a.split() for o, a in dockerfile() if o == "COPY"]
    assert [str(ENTRYPOINT.relative_to(ROOT)), f"./{ENTRYPOINT.relative_to(ROOT)}"] in copies
    assert os.access(ENTRYPOINT, os.X_OK), "deploy/entrypoint.sh must be executable"
    r = subprocess.run(["sh", "-n", str(ENTRYPOINT)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    args = entrypoint_args()
    check_invocation(args)
    assert "--num-cpus=0" in args and "--block" not in args  # a driver's node: no tasks, and the command follows
    assert ENTRYPOINT.read_text().rstrip().endswith('exec "$@"')


# -- settings ---------------------------------------------------------------------------------------

def _env_cases():
    seen = [(name, var) for name, s in SERVICES.items() for var in environment(s) if var.startswith("RBA_")]
    seen += [("Dockerfile", var) for var in docker_env() if var.startswith("RBA_")]
    for where, var in seen:
        field = var.removeprefix("RBA_").lower()
        pending = field in PENDING_FIELDS and field not in Settings.model_fields
        marks = [pytest.mark.xfail(strict=True, reason=PENDING_FIELDS[field])] if pending else []
        yield pytest.param(var, id=f"{where}:{var}", marks=marks)


@pytest.mark.parametrize("var", _env_cases())
def test_every_rba_variable_is_a_setting(var):
    assert var.removeprefix("RBA_").lower() in Settings.model_fields, f"{var} names no field of Settings"


def test_compose_values_are_valid_settings(tmp_path):
    """The API's environment, as compose gives it, makes valid Settings (types, ranges, the heartbeat rule)."""
    env = {k: v for k, v in environment(SERVICES["api"]).items()
           if k.startswith("RBA_") and k.removeprefix("RBA_").lower() in Settings.model_fields}
    settings = Settings(**{k.removeprefix("RBA_").lower(): v for k, v in env.items()})
    assert settings.port == api_port() and settings.host == "0.0.0.0"


def test_one_service_builds_the_image_the_others_use():
    builders = [name for name, s in SERVICES.items() if "build" in s]
    assert builders == ["api"], builders
    assert SERVICES["api"]["build"] == "." and (ROOT / "Dockerfile").exists()
    users = [name for name, s in SERVICES.items() if uses_rba_image(s)]
    assert {"api", "ray-head", "ray-worker", "ray-auth", "clip-cache"} <= set(users)
    for name in users:  # never pulled from a registry: it exists only once built here
        assert SERVICES[name]["pull_policy"] == "never", name


def test_compose_up_needs_no_arguments():
    """Every ${VAR} has a default, so `docker compose up` with no .env runs; no core service hides in a profile."""
    raw = (ROOT / "docker-compose.yml").read_text()
    no_default = [m for m in re.findall(r"\$\{[^}]*\}", raw) if ":-" not in m]
    assert no_default == [], f"these need a default (${{VAR:-value}}): {no_default}"
    for name in ("lb", "api", "postgres", "ray-head", "ray-worker"):
        assert "profiles" not in SERVICES[name], f"{name} must run on a plain `docker compose up`"
    assert SERVICES["api"]["deploy"]["replicas"] >= 2


# -- ports, upstreams, volumes ----------------------------------------------------------------------

def test_only_the_load_balancer_publishes_a_port_and_nginx_listens_on_it():
    published = {name: s["ports"] for name, s in SERVICES.items() if s.get("ports")}
    assert published == {"lb": ["127.0.0.1:8000:80"]}, published
    host_ip, host_port, container_port = published["lb"][0].split(":")
    assert [d[1] for d in directives(NGINX, "listen")] == [[container_port]]
    assert f"http://{host_ip}:{host_port}" in README


def test_nginx_upstreams_name_the_api_service_and_its_port():
    upstreams = {d[1][0]: d[2] for d in directives(NGINX, "upstream")}
    assert upstreams
    for name, body in upstreams.items():
        servers = [d[1] for d in body if d[0] == "server"]
        assert servers, f"upstream {name} has no server"
        for args in servers:
            host, port = args[0].split(":")
            assert host in SERVICES and host == "api" and int(port) == api_port(), (name, args)
            if "resolve" in args[1:]:
                assert any(d[0] == "zone" for d in body), f"upstream {name}: `resolve` needs a zone"
                assert directives(NGINX, "resolver"), "`resolve` needs a resolver"
    assert api_port() == int(docker_env()["RBA_PORT"])
    assert [a for o, a in dockerfile() if o == "EXPOSE"] == [docker_env()["RBA_PORT"]]


def test_nginx_image_supports_the_config():
    image = SERVICES["lb"]["image"]
    version = tuple(int(x) for x in re.match(r"nginx:(\d+)\.(\d+)", image).groups())
    if any("resolve" in d[1] for d in directives(NGINX, "server") if d[2] is None):
        assert version >= NGINX_RESOLVE_SINCE[:2], f"{image}: upstream `resolve` needs nginx >= 1.27.3"
    assert (ROOT / "deploy" / "nginx.conf").resolve() == NGINX_CONF.resolve()
    assert ("./deploy/nginx.conf", "/etc/nginx/conf.d/default.conf") in mounts(SERVICES["lb"])


def test_nginx_routes_every_request_to_an_upstream():
    upstreams = {d[1][0] for d in directives(NGINX, "upstream")}
    maps = {d[1][1]: [args[0] for _, args, _ in d[2]] for d in directives(NGINX, "map")}
    targets = [d[1][0] for d in directives(NGINX, "proxy_pass")]
    assert targets
    for target in targets:
        name = target.removeprefix("http://")
        names = maps[name] if name.startswith("$") else [name]
        assert set(names) <= upstreams, f"proxy_pass {target} reaches {names}, not all upstreams {upstreams}"
    for _, args, _ in directives(NGINX, "location"):
        # `location /x/ { proxy_pass ... }` answers a request for /x with a 301 (POST /api/sessions would break)
        assert args in (["/"],) or not args[-1].endswith("/"), f"prefix location {args} redirects its bare path"


def test_nginx_streams_clips_and_uploads():
    [server] = [d[2] for d in directives(NGINX, "server") if d[2] is not None]
    flat = {d[0]: d[1] for d in server if d[2] is None}
    size = flat["client_max_body_size"][0]
    factor = {"k": 2**10, "m": 2**20, "g": 2**30}.get(size[-1].lower(), 1)
    assert int(size.rstrip("kKmMgG")) * factor >= Settings().upload_max_bytes  # the app's limit answers first
    assert flat["proxy_request_buffering"] == ["off"] and flat["proxy_buffering"] == ["off"]
    assert flat.get("gzip", ["off"]) == ["off"]  # gzip would drop the clips' ETag
    assert "Range" not in str(directives(NGINX, "proxy_set_header"))  # Range and If-None-Match pass untouched


def test_nginx_includes_only_files_that_exist():
    lb_files = {target: ROOT / source for source, target in mounts(SERVICES["lb"]) if source.startswith(".")}
    for _, args, _ in directives(NGINX, "include"):
        assert args[0] in lb_files and lb_files[args[0]].exists(), f"nginx includes {args[0]}, not mounted from repo"


def test_volumes_exist_and_the_api_replicas_share_their_folders():
    declared = set(COMPOSE.get("volumes") or {})
    for name, s in SERVICES.items():
        for source, _target in mounts(s):
            if source.startswith("."):
                assert (ROOT / source).exists(), f"{name} mounts {source}, which is not in the repository"
            else:
                assert source in declared, f"{name} mounts volume {source}, not declared under volumes:"
    for name in ("api", "clip-cache"):
        env, targets = environment(SERVICES[name]), [t for _, t in mounts(SERVICES[name])]
        for var in ("RBA_DATA_DIR", "RBA_MODELS_DIR", "RBA_CACHE_DIR"):
            assert any(env[var] == t or env[var].startswith(t + "/") for t in targets), f"{name}: {var} is not mounted"
    data_mounts = [sorted(m for m in mounts(SERVICES[n]) if m[0].startswith(".")) for n in ("api", "clip-cache")]
    assert data_mounts[0] == data_mounts[1], "the API and the rba commands must see the same folders"


def test_the_api_uses_the_postgres_service():
    url = make_url(environment(SERVICES["api"])["RBA_DATABASE_URL"])
    pg = environment(SERVICES["postgres"])
    assert url.drivername == "postgresql+psycopg" and url.host == "postgres" and url.port == 5432
    assert (url.username, url.password, url.database) == (pg["POSTGRES_USER"], pg["POSTGRES_PASSWORD"],
                                                          pg["POSTGRES_DB"])
    assert SERVICES["postgres"]["healthcheck"]["test"]


def test_depends_on_names_services_whose_conditions_can_hold():
    for name, s in SERVICES.items():
        for target, spec in (s.get("depends_on") or {}).items():
            assert target in SERVICES, f"{name} depends on unknown {target}"
            other, condition = SERVICES[target], spec["condition"]
            if condition == "service_healthy":
                check = other.get("healthcheck", {})
                image_check = uses_rba_image(other) and any(o == "HEALTHCHECK" for o, _ in dockerfile())
                assert not check.get("disable") and (check.get("test") or image_check), f"{target} has no healthcheck"
            elif condition == "service_completed_successfully":
                assert other.get("restart") == "no", f"{target} must run once"


# -- the Ray cluster ----------------------------------------------------------------------------------

def _options(args: list[str]) -> dict[str, str]:
    return dict([*a.split("=", 1), ""][:2] for a in args)


def ray_start(name: str) -> dict[str, str]:
    args = command(SERVICES[name])
    assert args[:2] == ["ray", "start"], args
    return _options(args[2:])


def entrypoint_args() -> list[str]:
    """The entrypoint's `ray start` line (a driver's container joining the cluster), its address filled in."""
    [start] = [ln.strip() for ln in ENTRYPOINT.read_text().splitlines() if ln.strip().startswith("ray start")]
    return shlex.split(start.replace('"$RAY_HEAD_ADDRESS"', "ray-head:6379"))


def entrypoint_ray_start() -> dict[str, str]:
    return _options(entrypoint_args()[2:])


def test_ray_head_and_workers():
    head, worker = ray_start("ray-head"), ray_start("ray-worker")
    address = f"ray-head:{head['--port']}"
    assert "--head" in head and "--block" in head and "--num-cpus" in head
    assert worker["--address"] == address and "--block" in worker and "--num-cpus" in worker
    for name in ("ray-worker", "api"):  # scaled with --scale: no fixed names, no host ports
        assert "container_name" not in SERVICES[name] and "ports" not in SERVICES[name]
    drivers = [n for n, s in SERVICES.items() if "RAY_HEAD_ADDRESS" in environment(s)]
    assert "api" in drivers
    for name in drivers:
        env = environment(SERVICES[name])
        assert env["RAY_HEAD_ADDRESS"] == address and env["RBA_RAY_ADDRESS"] == address, name
    assert "--scale ray-worker=" in README


def _shm_bytes(value: str) -> int:
    return int(value[:-2]) * {"mb": 2**20, "gb": 2**30}[value[-2:].lower()]


def test_every_ray_process_has_telemetry_off_an_explicit_auth_mode_and_room_for_its_object_store():
    ray_services = [n for n, s in SERVICES.items()
                    if command(s)[:2] == ["ray", "start"] or "RAY_HEAD_ADDRESS" in environment(s)]
    assert {"ray-head", "ray-worker", "api"} <= set(ray_services)
    token_writer = command(SERVICES["ray-auth"])[2]
    for name in ray_services:
        s, env = SERVICES[name], environment(SERVICES[name])
        assert env["RAY_USAGE_STATS_ENABLED"] == "0", name
        assert env["RAY_AUTH_MODE"] in ("token", "disabled"), name
        if env["RAY_AUTH_MODE"] == "token":
            path = env["RAY_AUTH_TOKEN_PATH"]
            volume = [src for src, target in mounts(s) if path.startswith(target + "/")]
            assert volume, f"{name}: the token {path} is on no mounted volume"
            assert (volume[0], str(Path(path).parent)) in mounts(SERVICES["ray-auth"]), name
            assert f"> {path}" in token_writer, f"ray-auth does not write {path}"
        start = ray_start(name) if command(s)[:2] == ["ray", "start"] else entrypoint_ray_start()
        assert int(start["--object-store-memory"]) < _shm_bytes(s["shm_size"]), f"{name}: object store > /dev/shm"
    assert "ray-auth" in SERVICES["ray-head"]["depends_on"]


# -- the Dockerfile ---------------------------------------------------------------------------------

def test_dockerfile_agrees_with_the_readme_and_the_project():
    assert docker_json("CMD") == ["rba", "serve"] and "The image's command is `rba serve`" in README
    for var, value in docker_env().items():
        if var.startswith("RBA_"):
            assert f"`{var}={value}`" in README, f"docs/guide.md should say the image sets `{var}={value}`"
    health = " ".join(a for o, a in dockerfile() if o == "HEALTHCHECK")
    assert f"127.0.0.1:{docker_env()['RBA_PORT']}/healthz" in health
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    runs = " ".join(a for o, a in dockerfile() if o == "RUN")
    for package in ("torch", "ray"):
        [pin] = re.findall(rf'"{package}==([\w.]+)"', runs)
        declared = [d for d in deps if re.match(rf"{package}\b", d)]
        if declared:  # the image installs what the project pins, before the code (a cached layer)
            assert f"{package}=={pin}" in declared[0], (package, pin, declared)
        else:  # not a declared dependency (yet): then what this machine runs the tests with
            with contextlib.suppress(metadata.PackageNotFoundError):
                assert metadata.version(package) == pin, (package, pin, metadata.version(package))


def test_the_api_trusts_the_load_balancers_client_address():
    """Behind lb every request comes from lb: uvicorn must take X-Forwarded-For (nginx sets it), or the admin-token
    failure limit would slow down every client at once. Safe only because lb alone reaches the API and nginx
    overwrites the header: appending to it ($proxy_add_x_forwarded_for) would let a client pick the address
    uvicorn counts (it takes the leftmost) and so guess tokens without limit or lock another client out."""
    assert environment(SERVICES["api"])["FORWARDED_ALLOW_IPS"] == "*"
    assert "ports" not in SERVICES["api"]
    nginx = (ROOT / "deploy" / "nginx.conf").read_text()
    assert "proxy_set_header X-Forwarded-For $remote_addr;" in nginx
    assert "$proxy_add_x_forwarded_for" not in nginx
