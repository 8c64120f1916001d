#!/usr/bin/env python3
"""Regenerates the monitor page's screenshots in docs/monitor/ (docs/farm.md, "The monitor
page"): runs the browser test (tests/farm/test_monitor_browser.py: a real farm, headless
chromium) with its screenshots going to a scratch folder, and only when it passes stores
them in docs/monitor as 256-colour PNGs (tens of KB each rather than hundreds).

    .venv/bin/python scripts/monitor-screenshots.py
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
TARGET = ROOT / "docs" / "monitor"


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="tessera-monitor-shots-") as scratch:
        env = {**os.environ, "TESSERA_MONITOR_SCREENSHOTS": scratch}
        test = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                               str(ROOT / "tests" / "farm" / "test_monitor_browser.py")], cwd=ROOT, env=env)
        if test.returncode != 0:
            print("the browser test failed: docs/monitor is left as it was", file=sys.stderr)
            return test.returncode
        shots = sorted(Path(scratch).glob("*.png"))
        TARGET.mkdir(parents=True, exist_ok=True)
        for old in TARGET.glob("*.png"):
            old.unlink()
        for shot in shots:
            out = TARGET / shot.name
            Image.open(shot).convert("RGB").quantize(colors=256).save(out, optimize=True)
            print(f"{out.relative_to(ROOT)}: {out.stat().st_size // 1024} KiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
