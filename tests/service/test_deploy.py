"""Docker cannot run here, so check what can be checked: every manifest and the compose file
parse, and every command and setting they name exists (shsas subcommands and their options,
SHSAS_* settings), and the wiring (ports, volumes, GPU requests) is consistent."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest
import yaml

from jobs.settings import Settings
from shsas_core.cli import COMMANDS, build_parser

REPO = Path(__file__).resolve().parents[2]
MANIFESTS = sorted((REPO / "deploy").rglob("*.yaml"))
SETTING_ENV = {f"SHSAS_{name.upper()}" for name in Settings.model_fields}


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def check_shsas_command(argv: list[str]) -> None:
    """Parse a container command with the real CLI parser: unknown subcommands/options fail."""
    assert argv[0] == "shsas", argv
    assert argv[1] in COMMANDS, f"unknown subcommand in {argv}"
    try:
        build_parser().parse_args(argv[1:])
    except SystemExit as exc:  # argparse exits on unknown options
        raise AssertionError(f"`{' '.join(argv)}` does not parse: exit {exc.code}") from None


def walk(obj, found: list) -> None:
    """Collect every command list and every env mapping/list in a parsed YAML document."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            if k in ("command", "args") and isinstance(v, list) and v and v[0] == "shsas":
                found.append(("cmd", v))
            if k in ("environment", "data", "stringData") and isinstance(v, dict):
                found.extend(("env", name) for name in v)
            if k == "env" and isinstance(v, list):
                found.extend(("env", e["name"]) for e in v if isinstance(e, dict) and "name" in e)
            walk(v, found)
    elif isinstance(obj, list):
        for v in obj:
            walk(v, found)


def check_refs(found: list) -> None:
    for kind, value in found:
        if kind == "cmd":
            check_shsas_command(value)
        elif kind == "env" and value.startswith("SHSAS_"):
            assert value in SETTING_ENV, f"{value} is not a setting (known: {sorted(SETTING_ENV)})"


def test_manifests_exist_and_parse() -> None:
    names = {p.name for p in MANIFESTS}
    assert {"api.yaml", "worker-gpu.yaml", "redis.yaml", "postgres.yaml", "storage.yaml"} <= names
    kinds = []
    for path in MANIFESTS:
        docs = [d for d in yaml.safe_load_all(path.read_text()) if d]
        assert docs, path
        for d in docs:
            assert "apiVersion" in d and "kind" in d, path
            kinds.append(d["kind"])
    for kind in ("Deployment", "Service", "StatefulSet", "PersistentVolumeClaim", "ConfigMap", "Kustomization"):
        assert kind in kinds


def test_kustomization_lists_every_manifest() -> None:
    kust = yaml.safe_load((REPO / "deploy/k8s/kustomization.yaml").read_text())
    on_disk = {p.name for p in (REPO / "deploy/k8s").glob("*.yaml")} - {"kustomization.yaml"}
    assert set(kust["resources"]) == on_disk


@pytest.mark.parametrize("path", MANIFESTS, ids=lambda p: p.name)
def test_manifest_commands_and_settings_exist(path: Path) -> None:
    found: list = []
    for doc in yaml.safe_load_all(path.read_text()):
        walk(doc, found)
    check_refs(found)


def test_k8s_wiring() -> None:
    docs = {}
    for path in MANIFESTS:
        for d in yaml.safe_load_all(path.read_text()):
            if d and "metadata" in d:
                docs[(d["kind"], d["metadata"]["name"])] = d
    worker = docs[("Deployment", "shsas-worker-gpu")]["spec"]["template"]["spec"]
    res = worker["containers"][0]["resources"]
    assert res["limits"]["nvidia.com/gpu"] == 1
    api = docs[("Deployment", "shsas-api")]["spec"]["template"]["spec"]
    assert api["containers"][0]["readinessProbe"]["httpGet"]["path"] == "/readyz"
    port = api["containers"][0]["ports"][0]
    cmd = api["containers"][0]["command"]
    assert cmd[cmd.index("--port") + 1] == str(port["containerPort"])
    assert docs[("Service", "shsas-api")]["spec"]["ports"][0]["targetPort"] == port["name"]
    # API and workers share one RWX volume mounted where SHSAS_DATA_DIR points.
    config = docs[("ConfigMap", "shsas-config")]["data"]
    assert config["SHSAS_BROKER_URL"].startswith("redis://shsas-redis:")
    for spec in (api, worker):
        assert spec["volumes"][0]["persistentVolumeClaim"]["claimName"] == "shsas-data"
        assert spec["containers"][0]["volumeMounts"][0]["mountPath"] == config["SHSAS_DATA_DIR"]
    assert docs[("PersistentVolumeClaim", "shsas-data")]["spec"]["accessModes"] == ["ReadWriteMany"]


def test_compose_file() -> None:
    compose = yaml.safe_load((REPO / "docker-compose.yml").read_text())
    services = compose["services"]
    assert {"api", "worker", "redis", "postgres"} <= set(services)
    found: list = []
    walk(compose, found)
    check_refs(found)
    assert any(k == "cmd" and v[1] == "worker" for k, v in found)
    gpu = services["worker"]["deploy"]["resources"]["reservations"]["devices"][0]
    assert gpu["driver"] == "nvidia" and "gpu" in gpu["capabilities"]
    for name in ("api", "worker"):
        assert "shsas-data:/data" in services[name]["volumes"]
        assert services[name]["environment"]["SHSAS_DATA_DIR"] == "/data"
        assert services[name]["environment"]["SHSAS_BROKER_URL"].startswith("redis://redis:")
        if "build" in services[name]:
            assert (REPO / services[name]["build"]["context"] / services[name]["build"]["dockerfile"]).is_file()
    assert set(compose["volumes"]) >= {"shsas-data"}


def _redis_persists(args: list[str], volumes: list[str], where: str) -> None:
    assert "--appendonly" in args and args[args.index("--appendonly") + 1] == "yes", where
    data_dir = args[args.index("--dir") + 1] if "--dir" in args else "/data"
    assert data_dir in volumes, f"{where}: the AOF directory {data_dir} is not on a persistent volume"


def test_redis_keeps_its_messages_on_a_persistent_volume() -> None:
    compose = yaml.safe_load((REPO / "docker-compose.yml").read_text())
    redis = compose["services"]["redis"]
    named = [v.split(":")[1] for v in redis["volumes"] if v.split(":")[0] in compose["volumes"]]
    _redis_persists(redis["command"], named, "docker-compose.yml")
    docs = [d for d in yaml.safe_load_all((REPO / "deploy/k8s/redis.yaml").read_text()) if d]
    sts = next(d for d in docs if d["metadata"]["name"] == "shsas-redis" and d["kind"] != "Service")
    pod = sts["spec"]["template"]["spec"]
    assert not any("emptyDir" in v for v in pod.get("volumes", [])), "redis data on emptyDir is lost on restart"
    claims = {t["metadata"]["name"] for t in sts["spec"].get("volumeClaimTemplates", [])}
    claims |= {v["name"] for v in pod.get("volumes", []) if "persistentVolumeClaim" in v}
    container = pod["containers"][0]
    mounts = [m["mountPath"] for m in container["volumeMounts"] if m["name"] in claims]
    _redis_persists(container["args"], mounts, "deploy/k8s/redis.yaml")


def test_dockerfile_references() -> None:
    text = (REPO / "Dockerfile").read_text()
    cmd = re.search(r"^CMD (\[.*\])$", text, re.M)
    assert cmd is not None
    check_shsas_command(yaml.safe_load(cmd.group(1)))
    # service settings, or the variables the core library reads itself (kernel cache / switch)
    core_env = set(re.findall(r'"(SHSAS_[A-Z_]+)"', (REPO / "shsas_core/neural/fields/native.py").read_text()))
    assert core_env == {"SHSAS_CACHE_DIR", "SHSAS_NATIVE"}
    for name in re.findall(r"\bSHSAS_[A-Z_]+", text):
        assert name in SETTING_ENV | core_env, name
    for src in re.findall(r"^COPY (?!--from=)(\S+) ", text, re.M):
        assert (REPO / src).exists(), src
    # every package the wheel ships is in the image's build context, else `pip install .` fails
    packages = re.search(r'^packages = (\[.*\])$', (REPO / "pyproject.toml").read_text(), re.M)
    assert packages is not None
    copied = set(re.findall(r"^COPY (\S+) \./\1$", text, re.M))
    assert set(yaml.safe_load(packages.group(1))) <= copied, copied
    # the console is built in its own stage and only its bundle is copied into the image
    assert re.search(r"^COPY --from=console \S+ \./service/console/static$", text, re.M)
    assert 'ARG VARIANT=cpu' in text and '"$VARIANT" = "cuda"' in text
    # The service extra the image installs exists in pyproject.
    assert re.search(r"^service = \[", (REPO / "pyproject.toml").read_text(), re.M)


def test_docs_name_only_real_settings() -> None:
    for doc in (REPO / "docs/service.md", REPO / "deploy/README.md"):
        for name in set(re.findall(r"\bSHSAS_[A-Z_]+[A-Z]", doc.read_text())):
            assert name in SETTING_ENV | {"SHSAS_TEST_PG_URL", "SHSAS_TEST_REDIS_URL", "SHSAS_SHARED",
                                         "SHSAS_REQUIRE_BROWSER", "SHSAS_UPDATE_SCREENSHOTS"}, (doc, name)


def test_cli_commands_have_subparsers() -> None:
    subs = _subparsers()
    for name in ("serve", "worker", "keys"):
        assert name in subs


def test_every_setting_is_documented() -> None:
    text = (REPO / "docs/service.md").read_text()
    missing = sorted(n for n in SETTING_ENV if f"`{n}`" not in text)
    assert not missing, missing
