"""The `tessera` command (`cli.py`) and the farm `tessera serve` starts on one machine
(`embedded.py`): the top layer, the only package that imports the worker and the service.
The public Python API stays in `tessera`; nothing below imports this package."""
