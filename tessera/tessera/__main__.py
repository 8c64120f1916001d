"""`python -m tessera ...`: the same command as `tessera ...` (tessera_cli). This file is
run, never imported by the package, so it belongs to the CLI's layer (tests/test_layers.py)."""
import sys

from tessera_cli.cli import main

sys.exit(main())
