#!/usr/bin/env bash
# Makes the two example reports of docs/accuracy.md from the committed reference set
# examples/refs (its Cornell entry): pass/ checks the scene as it is, fail/ the same scene
# with the red wall's albedo 2 % higher. Each folder gets index.html, its PNGs and junit.xml.
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
VENV=${TESSERA_VENV:-$ROOT/.venv}
OUT="$ROOT/docs/refs-example"
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT

"$VENV/bin/python" - "$ROOT" "$WORK" <<'PY'
import json, shutil, sys
from pathlib import Path
root, work = Path(sys.argv[1]), Path(sys.argv[2])
cornell = root / "examples/cornell/cornell.usda"
text = cornell.read_text()
red = "(0.63, 0.065, 0.05)"
assert text.count(red) == 1
manifest = json.loads((root / "examples/refs/refs.json").read_text())
manifest["references"] = [r for r in manifest["references"] if r["name"] == "cornell"]
manifest["references"][0]["scene"] = "scene/cornell.usda"
for variant, scene_text in (("pass", text), ("fail", text.replace(red, "(0.6426, 0.0663, 0.051)"))):
    folder = work / variant
    (folder / "scene").mkdir(parents=True)
    (folder / "scene/cornell.usda").write_text(scene_text)
    shutil.copy(root / "examples/refs/cornell.exr", folder)
    (folder / "refs.json").write_text(json.dumps(manifest, indent=2))
PY

for variant in pass fail; do
  rm -rf "$OUT/$variant"
  "$VENV/bin/tessera" refs check "$WORK/$variant" --report "$OUT/$variant" --junit "$OUT/$variant/junit.xml"
  echo "[refs-example] $variant: exit $? (report $OUT/$variant/index.html)"
done
