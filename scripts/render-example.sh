#!/usr/bin/env bash
# Sets everything up (scripts/setup.sh) and renders the bundled Cornell box locally:
# no Redis, no server. Extra arguments go to `tessera render` (e.g. --spp 256).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$ROOT/scripts/setup.sh"
VENV=${TESSERA_VENV:-$ROOT/.venv}
"$VENV/bin/tessera" render "$ROOT/examples/cornell/cornell.usda" -o "$ROOT/out/cornell.exr" "$@"
