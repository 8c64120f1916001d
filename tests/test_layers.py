"""The package layering (README, "Layout"): every import, at module level or inside a
function, points down. The checker reads the source with `ast`, so a lazy import inside a
function counts as much as one at the top of a file.

    tessera_renderer            USD -> arrays -> Embree; no Redis, no HTTP
    tessera_base                job/tile schema, image codec, film, integrator registry view
    tessera_queue               Redis keys, hash fields, events, Lua (worker and service share it)
    tessera_tools               compare, bench, the Mitsuba peer
    tessera_worker              Redis + renderer
    tessera_service             HTTP + Redis + merging
    tessera                     the public Python API (render, compare, Client)
    tessera.cli, tessera.__main__   the only modules that import worker and service
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# package -> folder holding it
PACKAGES = {
    "tessera_renderer": REPO / "renderer" / "tessera_renderer",
    "tessera_base": REPO / "tessera" / "tessera_base",
    "tessera_queue": REPO / "tessera" / "tessera_queue",
    "tessera_tools": REPO / "tessera" / "tessera_tools",
    "tessera_worker": REPO / "worker" / "tessera_worker",
    "tessera_service": REPO / "service" / "tessera_service",
    "tessera": REPO / "tessera" / "tessera",
}
CLI = "tessera.cli"  # the layer above everything: tessera/tessera/cli.py and __main__.py

# Which of our packages each layer may import (besides itself). Everything not listed is
# forbidden, so a new upward import fails here.
ALLOWED = {
    "tessera_renderer": set(),
    "tessera_base": {"tessera_renderer"},
    "tessera_queue": {"tessera_base"},
    "tessera_tools": {"tessera_base", "tessera_renderer"},
    "tessera_worker": {"tessera_queue", "tessera_base", "tessera_renderer"},
    "tessera_service": {"tessera_queue", "tessera_tools", "tessera_base", "tessera_renderer"},
    # tessera.Client reads the farm's event stream through the queue layer's JobEvent model.
    "tessera": {"tessera_queue", "tessera_tools", "tessera_base", "tessera_renderer"},
    CLI: {"tessera", "tessera_worker", "tessera_service", "tessera_queue", "tessera_tools", "tessera_base",
          "tessera_renderer"},
}
# Third-party libraries a layer must not use: the renderer and the foundations know nothing
# of Redis or HTTP; the worker knows Redis but no HTTP.
NETWORK = {"redis", "fastapi", "starlette", "uvicorn", "httpx", "requests"}
FORBIDDEN_THIRD_PARTY = {
    "tessera_renderer": NETWORK,
    "tessera_base": NETWORK,
    "tessera_tools": NETWORK,
    "tessera_queue": NETWORK - {"redis"},
    "tessera_worker": NETWORK - {"redis"},
}


def imported_modules(source: str, module: str, is_package: bool) -> set[str]:
    """Absolute names of every module `source` imports (relative imports resolved against
    `module`, a dotted name; `is_package` when the source is an __init__.py)."""
    found = set()
    package = module if is_package else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                prefix = ".".join(base + ([node.module] if node.module else []))
            else:
                prefix = node.module
            if prefix:
                found.add(prefix)
            # `from tessera import cli` imports the module tessera.cli
            found.update(f"{prefix}.{alias.name}" if prefix else alias.name for alias in node.names)
    return found


def layer_of(module: str) -> str | None:
    """The layer a dotted module name belongs to, None for third-party and stdlib."""
    if module in ("tessera.cli", "tessera.__main__") or module.startswith("tessera.cli."):
        return CLI
    top = module.split(".")[0]
    return top if top in PACKAGES else None


def violations(package: str, root: Path) -> list[str]:
    found = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).with_suffix("")
        parts = [package] + [p for p in rel.parts if p != "__init__"]
        module = ".".join(parts)
        layer = layer_of(module)
        seen = set()  # one report per file and imported layer (or library)
        for imported in sorted(imported_modules(path.read_text(), module, path.name == "__init__.py")):
            target = layer_of(imported)
            if target is None:
                lib = imported.split(".")[0]
                if lib in FORBIDDEN_THIRD_PARTY.get(layer, ()) and lib not in seen:
                    seen.add(lib)
                    found.append(f"{path.relative_to(REPO)}: {layer} imports {imported}")
                continue
            # `from tessera import x` names the package itself: only x decides the layer
            if target == layer or (target == "tessera" and imported == "tessera" and layer == CLI):
                continue
            if target not in ALLOWED[layer] and target not in seen:
                seen.add(target)
                found.append(f"{path.relative_to(REPO)}: {layer} imports {imported} ({target})")
    return found


@pytest.mark.parametrize("package", sorted(PACKAGES))
def test_imports_point_down(package):
    root = PACKAGES[package]
    assert (root / "__init__.py").is_file(), f"{root} is not a package"
    assert violations(package, root) == []


def test_every_python_package_has_a_layer():
    """A new package must be placed in the layering before it can be imported."""
    roots = {p.parent for p in REPO.glob("*/*/__init__.py")} | {p.parent for p in REPO.glob("*/__init__.py")}
    roots = {r for r in roots if r.parts[len(REPO.parts)] not in ("tests", "build", ".venv", "docs")}
    assert roots == set(PACKAGES.values())


def test_the_checker_sees_an_upward_import(tmp_path):
    """Negative control: the same checker on a foundation module that imports the worker
    lazily (inside a function), or Redis, reports both."""
    root = tmp_path / "tessera_base"
    root.mkdir()
    (root / "__init__.py").write_text("")
    (root / "film.py").write_text("def f():\n    from tessera_worker.worker import run_worker\n")
    (root / "codec.py").write_text("import redis\nfrom .film import f\n")
    (root / "sub").mkdir()
    (root / "sub" / "__init__.py").write_text("from .. import film\nimport tessera_service.app\n")
    global REPO
    saved, REPO = REPO, tmp_path
    try:
        found = violations("tessera_base", root)
    finally:
        REPO = saved
    assert any("tessera_worker.worker" in v for v in found)
    assert any("imports redis" in v for v in found)
    assert any("tessera_service" in v for v in found)
    assert len(found) == 3  # the relative import of a sibling is not one
    # And the CLI is the only place allowed to import the worker:
    assert "tessera_worker" in ALLOWED[CLI] and not any("tessera_worker" in ALLOWED[k] for k in ALLOWED if k != CLI)
