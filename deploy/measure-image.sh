#!/usr/bin/env bash
# Builds the production image (deploy/Dockerfile, `runtime` target) and the one-stage image it
# replaced (deploy/Dockerfile before commit cda7afb), measures both, and proves the runtime
# image works: it renders the Cornell box bit for bit like the local development install,
# and its `serve` and `worker` render a submitted job against a Redis on this host's loopback.
# deploy/README.md, "Image size", holds the numbers this printed. Not part of the test suite:
# it compiles the C++ core twice in containers (tens of minutes on 2 cores).
#
#   sudo bash deploy/measure-image.sh            # everything; steps whose product exists are skipped
#   sudo bash deploy/measure-image.sh clean      # remove the images and the container storage
#
# Needs root on Debian 12 with Debian's and PyPI's package servers reachable, and the development
# install of the same commit (`scripts/setup.sh`; TESSERA_VENV, default .venv) for the
# comparison. It installs podman, buildah and debootstrap with apt. Docker Hub is not needed:
# the two base images are made here with debootstrap, as the official ones are (debuerreotype:
# `--variant=minbase` for both, and for `-slim` the same dpkg path excludes of documentation,
# manual pages and locales), and imported as debian:12 and debian:12-slim. They differ from
# the official images in date (those pin a snapshot of the archive, these take today's
# packages) and so a little in size (here 128 and 82 MB, the official ones about 117 and 75).
# The images are built from `git archive HEAD` (a clean checkout of the commit, so uncommitted
# changes are not measured). Storage: the vfs driver (no overlay needed). Commands in the images
# run with `buildah run --isolation chroot`, as the builds' RUN steps do: `podman run` needs
# crun to set resource limits, which a machine without CAP_SYS_RESOURCE (a container, like
# this one) refuses.
#   TESSERA_MEASURE_DIR   scratch folder (default /var/tmp/tessera-measure)
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
WORK=${TESSERA_MEASURE_DIR:-/var/tmp/tessera-measure}
VENV=${TESSERA_VENV:-$ROOT/.venv}
MIRROR=http://deb.debian.org/debian
ONE_STAGE_COMMIT=cda7afb^  # the last one-stage deploy/Dockerfile
RUNTIME=localhost/tessera:runtime
ONE_STAGE=localhost/tessera:one-stage
# The storage flag on every call (`nice` runs programs, not these functions: it is given it below).
podman() { command podman --storage-driver=vfs "$@"; }
buildah() { command buildah --storage-driver=vfs "$@"; }
say() { echo "[measure] $*" >&2; }

[ "$(id -u)" -eq 0 ] || { echo "measure-image.sh: run as root (podman, debootstrap)" >&2; exit 2; }

if [ "${1:-}" = clean ]; then
  podman rmi -f "$RUNTIME" "$ONE_STAGE" debian:12 debian:12-slim 2>/dev/null || true
  podman system reset --force
  rm -rf "$WORK"
  exit 0
fi

missing=()
for tool in podman buildah debootstrap; do command -v "$tool" > /dev/null || missing+=("$tool"); done
if [ ${#missing[@]} -gt 0 ]; then
  say "installing ${missing[*]}"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}"
fi
mkdir -p "$WORK"

# ---------------------------------------------------------------- base images
# debuerreotype's container settings: no services started by package scripts, no .deb files or
# package caches kept after an install (so `apt-get install` layers carry no archives), no
# translations. A Dockerfile written for the official images relies on them.
minimize() {
  local rootfs=$1
  printf '#!/bin/sh\nexit 101\n' > "$rootfs/usr/sbin/policy-rc.d"
  chmod 755 "$rootfs/usr/sbin/policy-rc.d"
  echo force-unsafe-io > "$rootfs/etc/dpkg/dpkg.cfg.d/docker-apt-speedup"
  local clean='"rm -f /var/cache/apt/archives/*.deb /var/cache/apt/archives/partial/*.deb /var/cache/apt/*.bin || true";'
  cat > "$rootfs/etc/apt/apt.conf.d/docker-clean" <<EOF
DPkg::Post-Invoke { $clean };
APT::Update::Post-Invoke { $clean };
Dir::Cache::pkgcache "";
Dir::Cache::srcpkgcache "";
EOF
  echo 'Acquire::GzipIndexes "true";' > "$rootfs/etc/apt/apt.conf.d/docker-gzip-indexes"
  echo 'Acquire::Languages "none";' > "$rootfs/etc/apt/apt.conf.d/docker-no-languages"
  echo 'Apt::AutoRemove::SuggestsImportant "false";' > "$rootfs/etc/apt/apt.conf.d/docker-autoremove-suggests"
  printf 'Types: deb\nURIs: %s\nSuites: bookworm bookworm-updates\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n\nTypes: deb\nURIs: http://deb.debian.org/debian-security\nSuites: bookworm-security\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n' \
    "$MIRROR" > "$rootfs/etc/apt/sources.list.d/debian.sources"
  rm -f "$rootfs/etc/apt/sources.list"
  rm -rf "$rootfs"/var/lib/apt/lists/* "$rootfs"/var/cache/apt/*.bin "$rootfs"/var/cache/apt/archives/*.deb \
    "$rootfs"/var/log/* "$rootfs/debootstrap"
  echo 'nameserver 1.1.1.1' > "$rootfs/etc/resolv.conf"
}

# The slim variant: dpkg leaves out documentation (but copyright files), manual pages, info
# pages and locales from every package installed later, and they are removed from the base.
slimify() {
  local rootfs=$1
  cat > "$rootfs/etc/dpkg/dpkg.cfg.d/docker" <<'EOF'
path-exclude /usr/share/doc/*
path-exclude /usr/share/groff/*
path-exclude /usr/share/info/*
path-exclude /usr/share/linda/*
path-exclude /usr/share/lintian/overrides/*
path-exclude /usr/share/locale/*
path-exclude /usr/share/man/*
path-include /usr/share/doc/*/copyright
path-include /usr/share/locale/locale.alias
EOF
  find "$rootfs/usr/share/doc" -mindepth 1 -not -name copyright -not -type d -delete
  find "$rootfs/usr/share/doc" -mindepth 1 -type d -empty -delete
  rm -rf "$rootfs"/usr/share/{groff,info,linda,man}/* "$rootfs"/usr/share/lintian/overrides/*
  find "$rootfs/usr/share/locale" -mindepth 1 -maxdepth 1 -not -name locale.alias -exec rm -rf {} +
}

base_image() {  # NAME SLIM
  local name=$1 slim=$2 rootfs="$WORK/rootfs-$1"
  podman image exists "docker.io/library/$name" && return 0
  if [ ! -s "$WORK/minbase.tar" ]; then
    say "debootstrap --variant=minbase bookworm"
    rm -rf "$WORK/minbase"
    debootstrap --variant=minbase --merged-usr bookworm "$WORK/minbase" "$MIRROR" > "$WORK/debootstrap.log" 2>&1
    tar --numeric-owner --xattrs -C "$WORK/minbase" -cf "$WORK/minbase.tar" .
    rm -rf "$WORK/minbase"
  fi
  say "making $name"
  rm -rf "$rootfs" && mkdir -p "$rootfs"
  tar --numeric-owner --xattrs -C "$rootfs" -xf "$WORK/minbase.tar"
  minimize "$rootfs"
  [ "$slim" = slim ] && slimify "$rootfs"
  tar --numeric-owner --xattrs -C "$rootfs" -c . \
    | podman import --change 'CMD ["bash"]' - "docker.io/library/$name" > /dev/null
  rm -rf "$rootfs"
}
base_image debian:12 full
base_image debian:12-slim slim
rm -f "$WORK/minbase.tar"

# ---------------------------------------------------------------- the two images
context="$WORK/context"
rm -rf "$context" && mkdir -p "$context"
git -C "$ROOT" archive HEAD | tar -x -C "$context"
git -C "$ROOT" show "$ONE_STAGE_COMMIT:deploy/Dockerfile" > "$WORK/Dockerfile.one-stage"

# Where HTTPS leaves through a proxy with its own certificate authority (pip's `cert` setting
# or PIP_CERT on this host), the builds' pip gets that authority too: mounted for the RUN
# steps only, so the images keep neither (but two empty files where they were mounted).
build_mounts=()
ca=${PIP_CERT:-$(sed -n 's/^cert *= *//p' /etc/pip.conf 2> /dev/null | head -1)}
if [ -n "$ca" ] && [ -f "$ca" ]; then
  printf '[global]\ncert = /etc/ssl/host-proxy-ca.crt\n' > "$WORK/pip.conf"
  build_mounts=(-v "$ca:/etc/ssl/host-proxy-ca.crt:ro" -v "$WORK/pip.conf:/etc/pip.conf:ro")
fi
build() {  # TAG DOCKERFILE [ARGS...]
  local tag=$1 file=$2; shift 2
  podman image exists "$tag" && return 0
  say "building $tag (log: $WORK/build-${tag##*:}.log)"
  local start=$SECONDS
  local log="$WORK/build-${tag##*:}.log"
  nice -n 10 buildah --storage-driver=vfs bud --layers --isolation chroot --pull=never "${build_mounts[@]}" \
    -f "$file" -t "$tag" "$@" "$context" < /dev/null > "$log" 2>&1 &
  local pid=$!
  # Buildah 1.28 (Debian 12) can stay alive, idle, after tagging the image: the tag is the end.
  while kill -0 "$pid" 2> /dev/null && ! grep -q "^Successfully tagged $tag" "$log"; do sleep 5; done
  sleep 10
  kill "$pid" 2> /dev/null || true
  wait "$pid" || true
  podman image exists "$tag" || { tail -30 "$log" >&2; exit 1; }
  echo "$((SECONDS - start))" > "$WORK/build-${tag##*:}.seconds"
}
build "$RUNTIME" "$context/deploy/Dockerfile" --target runtime
build "$ONE_STAGE" "$WORK/Dockerfile.one-stage"

# ---------------------------------------------------------------- sizes
# `sh -c SCRIPT` as root in a fresh working container of IMAGE: in_image IMAGE SCRIPT
in_image() {
  local ctr
  ctr=$(buildah from --pull=never "$1")
  buildah run --isolation chroot --user 0:0 "$ctr" -- sh -c "$2" || true
  buildah rm "$ctr" > /dev/null
}
report="$WORK/report.txt"
{
  echo "commit $(git -C "$ROOT" rev-parse --short HEAD), measured $(date -u +%FT%TZ)"
  podman images --format '{{.Repository}}:{{.Tag}}  {{.Size}}' \
    | grep -E 'tessera|debian'
  for image in debian:12 debian:12-slim "$RUNTIME" "$ONE_STAGE"; do
    bytes=$(podman image inspect --format '{{.Size}}' "$image")
    gz=$WORK/gz-${image##*:}
    [ -s "$gz" ] || podman save "$image" 2>/dev/null | gzip -6 -c | wc -c > "$gz"
    echo "$image: $bytes bytes uncompressed, $(cat "$gz") bytes as gzip of podman save"
  done
  for tag in runtime one-stage; do
    [ -f "$WORK/build-$tag.seconds" ] && echo "build time $tag: $(cat "$WORK/build-$tag.seconds") s"
  done
  echo "--- layers of the runtime image"
  podman history --format '{{.Size}}  {{.CreatedBy}}' "$RUNTIME" | cut -c1-150
  echo "--- layers of the one-stage image"
  podman history --format '{{.Size}}  {{.CreatedBy}}' "$ONE_STAGE" | cut -c1-150
  # One du per level: du counts a folder once, so a folder inside another it already
  # measured would show as nothing.
  echo "--- the runtime's largest parts (du -sm)"
  in_image "$RUNTIME" \
    'du -sm /usr/lib/x86_64-linux-gnu /usr/lib/python3* /usr/share /opt/tessera/venv | sort -rn;
     du -sm /opt/tessera/venv/lib/python3*/site-packages/* | sort -rn | head -12'
  echo "--- the one-stage image's largest parts (du -sm)"
  in_image "$ONE_STAGE" \
    'du -sm /usr/lib/x86_64-linux-gnu /usr/lib/chromium /usr/lib/llvm-* /usr/lib/gcc /usr/include \
       /usr/share /opt/tessera/.venv /opt/tessera/build 2>/dev/null | sort -rn;
     du -sm /usr/lib/x86_64-linux-gnu/* | sort -rn | head -8;
     du -sm /opt/tessera/.venv/lib/python3*/site-packages/* | sort -rn | head -12'
} > "$report"

# ---------------------------------------------------------------- the runtime image works
# A render inside the image against the development install of this commit, bit for bit.
out="$WORK/check"
rm -rf "$out" && mkdir -p "$out/data"
cp "$ROOT/examples/cornell/cornell.usda" "$out/"
chown -R 10001:10001 "$out"
args=(--spp 4 --res 64x64 -q)
# Two working containers of the image (the API's, the worker's), commands run in them as the
# image's user with its environment (PATH to the venv, TESSERA_DATA_DIR).
api=$(buildah from --pull=never "$RUNTIME") worker=$(buildah from --pull=never "$RUNTIME")
pids=()
cleanup() {
  # Each background process leads its own process group (setsid): end the group.
  for pid in "${pids[@]}"; do kill -- "-$pid" 2> /dev/null || true; done
  sleep 2
  buildah rm "$api" "$worker" > /dev/null 2>&1 || true
}
trap cleanup EXIT
as_tessera=(command buildah --storage-driver=vfs run --isolation chroot --user 10001:10001)
"${as_tessera[@]}" -v "$out:/work" "$api" -- tessera render /work/cornell.usda "${args[@]}" -o /work/image.exr
"$VENV/bin/tessera" render "$out/cornell.usda" "${args[@]}" -o "$out/local.exr"

# `serve` and `worker` from the image against a Redis with the farm's ACL users on this host's
# loopback, sharing one data directory, and a job submitted by the local CLI.
port=$((20000 + RANDOM % 20000)) api_port=$((40000 + RANDOM % 20000))
api_password=$(openssl rand -hex 16) worker_password=$(openssl rand -hex 16) token=$(openssl rand -hex 16)
sed -e "s/CHANGE-ME-api-password/$api_password/" -e "s/CHANGE-ME-worker-password/$worker_password/" \
  "$ROOT/deploy/users.acl" > "$out/users.acl"
mkdir -p "$out/redis"
# Redis changes to `dir` as it reads the file, before the command line's settings: a copy.
sed -e "s|^dir .*|dir $out/redis|" -e "s|^aclfile .*|aclfile $out/users.acl|" "$ROOT/deploy/redis.conf" \
  > "$out/redis.conf"
setsid redis-server "$out/redis.conf" --port "$port" --bind 127.0.0.1 --appendfsync no \
  --daemonize no > "$out/redis.log" 2>&1 &
pids+=($!)
volume=(-v "$out/data:/var/lib/tessera/data" --network host)
setsid "${as_tessera[@]:1}" "${volume[@]}" \
  --env "REDIS_URL=redis://tessera-api:$api_password@127.0.0.1:$port/0" --env "TESSERA_API_TOKENS=measure:$token" \
  "$api" -- tessera serve --host 127.0.0.1 --port "$api_port" > "$out/serve.log" 2>&1 &
pids+=($!)
setsid "${as_tessera[@]:1}" "${volume[@]}" \
  --env "REDIS_URL=redis://tessera-worker:$worker_password@127.0.0.1:$port/0" --env TESSERA_WORKER_THREADS=2 \
  "$worker" -- tessera worker > "$out/worker.log" 2>&1 &
pids+=($!)
for _ in $(seq 60); do
  curl -fs "http://127.0.0.1:$api_port/healthz" > /dev/null && break
  sleep 1
done
"$VENV/bin/tessera" submit "$out/cornell.usda" --server "http://127.0.0.1:$api_port" --token "$token" \
  --wait -q "${args[@]:0:4}" -o "$out/farm.exr"

status=0
"$VENV/bin/python" - "$out" >> "$report" <<'EOF' || status=$?
import sys
from pathlib import Path

import numpy as np
from tessera_base import images

out = Path(sys.argv[1])
local = images.read_exr(out / "local.exr")
print(f"--- pixels: local render {local.shape}, mean {float(local[..., :3].mean()):.4f}")
failed = False
for name in ("image.exr", "farm.exr"):
    other = images.read_exr(out / name)
    same = other.shape == local.shape and np.array_equal(other.view(np.uint32), local.view(np.uint32))
    failed |= not same
    print(f"{name}: {'bit for bit equal to' if same else 'DIFFERS from'} the local render")
sys.exit(1 if failed else 0)
EOF
cat "$report"
say "report: $report; remove the images and their storage with: bash $0 clean"
exit $status
