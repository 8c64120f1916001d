"""The package layering (README, "Layout"): every import, at module level, inside a
function or under `if TYPE_CHECKING:`, points down, and no modules import each other in a
circle. The checker reads the source with `ast`, so a lazy import counts as much as one at
the top of a file. Every Python file outside tests/ is checked: the packages, and the
scripts in benchmarks/, scripts/, examples/ and renderer/tools/.

    tessera_renderer            USD -> arrays -> Embree; no Redis, no HTTP
    tessera_base                job/tile schema, image codec, film, integrator registry view
    tessera_queue               Redis keys, hash fields, events, Lua (worker and service share it)
    tessera_tools               compare, bench, the Mitsuba peer
    tessera_worker              Redis + renderer
    tessera_service             HTTP + Redis + merging
    tessera                     the public Python API (render, compare, Client)
    tessera_cli                 the `tessera` command and the embedded farm: the only package
                                that imports worker and service (and tessera/__main__.py,
                                which `python -m tessera` runs and nothing imports)
    scripts                     benchmarks/, scripts/, examples/, renderer/tools/: anything
                                but the worker and the service, which they reach through
                                tessera_cli (its embedded farm) or as processes
"""
from __future__ import annotations

import ast
import re
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
    "tessera_cli": REPO / "tessera" / "tessera_cli",
}
CLI = "tessera_cli"
SCRIPTS = "scripts"
# Folders of stand-alone scripts (run as files, importing siblings by bare name at most).
SCRIPT_FOLDERS = [REPO / "benchmarks", REPO / "scripts", REPO / "examples", REPO / "renderer" / "tools"]
# `python -m tessera` runs this module; the package never imports it, so it sits with the CLI.
ENTRY_MODULES = {"tessera.__main__": CLI}


def extension_modules() -> set[str]:
    """The core's compiled modules (renderer/CMakeLists.txt's nanobind_add_module targets,
    installed into tessera_renderer): `from .. import _subdivision` imports one of them, not
    the package's __init__."""
    cmake = (REPO / "renderer" / "CMakeLists.txt").read_text()
    return {f"tessera_renderer.{name}" for name in re.findall(r"nanobind_add_module\((\w+)", cmake)}

BELOW_THE_FARM = {"tessera", "tessera_queue", "tessera_tools", "tessera_base", "tessera_renderer"}
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
    CLI: BELOW_THE_FARM | {"tessera_worker", "tessera_service"},
    SCRIPTS: BELOW_THE_FARM | {CLI},
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
    return {target for target, _ in imports(source, module, is_package)}


def imports(source: str, module: str, is_package: bool) -> list[tuple[str, str | None]]:
    """(module, name) for every import in `source`: `import a.b` gives ("a.b", None),
    `from a import b` gives ("a", "b") (b may be a submodule or an attribute of a)."""
    found = []
    package = module if is_package else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found.extend((alias.name, None) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                prefix = ".".join(base + ([node.module] if node.module else []))
            else:
                prefix = node.module
            found.extend((prefix, alias.name) for alias in node.names)
    return found


def module_files() -> dict[str, tuple[Path, str]]:
    """Every checked module: dotted name -> (file, layer). Scripts are named by their path."""
    modules = {}
    for package, root in PACKAGES.items():
        for path in sorted(root.rglob("*.py")):
            rel = path.relative_to(root).with_suffix("")
            name = ".".join([package] + [p for p in rel.parts if p != "__init__"])
            modules[name] = (path, ENTRY_MODULES.get(name, package))
    for folder in SCRIPT_FOLDERS:
        for path in sorted(folder.rglob("*.py")):
            modules[str(path.relative_to(REPO))] = (path, SCRIPTS)
    return modules


def layer_of(module: str) -> str | None:
    """The layer a dotted module name belongs to, None for third-party and stdlib."""
    if module in ENTRY_MODULES:
        return ENTRY_MODULES[module]
    top = module.split(".")[0]
    return top if top in PACKAGES else None


def edges(modules: dict[str, tuple[Path, str]]) -> dict[str, set[str]]:
    """module -> the checked modules it imports. `from a import b` is an edge to a.b when
    that is a module, else to a; a script's bare `import common` to its sibling file."""
    graph = {}
    known = set(modules) | extension_modules()
    for name, (path, _) in modules.items():
        is_script = name.endswith(".py")
        targets = set()
        for target, attr in imports(path.read_text(), "" if is_script else name, path.name == "__init__.py"):
            candidates = [f"{target}.{attr}", target] if attr and target else [target or attr]
            if is_script:
                candidates += [str((path.parent / f"{c}.py").relative_to(REPO)) for c in candidates if c]
            hit = next((c for c in candidates if c in known and c != name), None)
            if hit:
                targets.add(hit)
        graph[name] = targets
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), sorted."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


def violations(modules: dict[str, tuple[Path, str]]) -> list[str]:
    found = []
    for name, (path, layer) in modules.items():
        seen = set()  # one report per file and imported layer (or library)
        is_script = name.endswith(".py")
        for imported in sorted(imported_modules(path.read_text(), "" if is_script else name,
                                                path.name == "__init__.py")):
            target = layer_of(imported)
            if target is None:
                lib = imported.split(".")[0]
                if lib in FORBIDDEN_THIRD_PARTY.get(layer, ()) and lib not in seen:
                    seen.add(lib)
                    found.append(f"{path.relative_to(REPO)}: {layer} imports {imported}")
                continue
            if target == layer:
                continue
            # `from tessera import x` in the CLI names the package; the x decides the layer
            # (tessera.__main__ would be the only upward one, and nothing imports it)
            if target not in ALLOWED[layer] and target not in seen:
                seen.add(target)
                found.append(f"{path.relative_to(REPO)}: {layer} imports {imported} ({target})")
    return found


def test_imports_point_down():
    assert all((root / "__init__.py").is_file() for root in PACKAGES.values())
    assert violations(module_files()) == []


def test_no_import_cycles():
    """No circle of imports, lazy or under TYPE_CHECKING: a shared piece moves down."""
    assert cycles(edges(module_files())) == []


def test_every_python_file_has_a_layer():
    """A new package or script folder must be placed in the layering: every .py file outside
    tests/ (and build output) is one the checks above read."""
    skip = {"tests", "build", ".venv", ".git", "out"}
    on_disk = {p for p in REPO.rglob("*.py")
               if p.relative_to(REPO).parts[0] not in skip and not any(s.startswith(".") for s in p.relative_to(REPO).parts)}
    checked = {path for path, _ in module_files().values()}
    assert on_disk - checked == set()
    assert len(checked) > 100  # the walk found the tree, not an empty folder


def _checked_tree(tmp_path, files: dict[str, str]):
    """The checks run on a made-up tree laid out like the repository."""
    global REPO, PACKAGES, SCRIPT_FOLDERS
    files = {"renderer/CMakeLists.txt": "nanobind_add_module(_core NB_STATIC python/module.cpp)\n", **files}
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    saved = REPO, PACKAGES, SCRIPT_FOLDERS
    REPO = tmp_path
    PACKAGES = {name: tmp_path / root.relative_to(saved[0]) for name, root in saved[1].items()}
    SCRIPT_FOLDERS = [tmp_path / f.relative_to(saved[0]) for f in saved[2]]
    try:
        modules = {n: v for n, v in module_files().items()}
        return violations(modules), cycles(edges(modules))
    finally:
        REPO, PACKAGES, SCRIPT_FOLDERS = saved


def test_the_checker_sees_an_upward_import(tmp_path):
    """Negative control: the same checker on a foundation module that imports the worker
    lazily (inside a function), or Redis; a public-API module and a benchmark that import
    the service; reports each, and not a relative import of a sibling."""
    found, _ = _checked_tree(tmp_path, {
        "tessera/tessera_base/__init__.py": "",
        "tessera/tessera_base/film.py": "def f():\n    from tessera_worker.worker import run_worker\n",
        "tessera/tessera_base/codec.py": "import redis\nfrom .film import f\n",
        "tessera/tessera_base/sub/__init__.py": "from .. import film\nimport tessera_service.app\n",
        "tessera/tessera/__init__.py": "",
        "tessera/tessera/cli.py": "from tessera_service.embedded import serve\n",
        "tessera/tessera/__main__.py": "from tessera_cli.cli import main\n",
        "tessera/tessera_cli/__init__.py": "from tessera_worker import worker\nimport tessera_service\n",
        "benchmarks/farm.py": "from common import x\nfrom tessera_cli.embedded import redis_server\n",
        "benchmarks/footprint.py": "import tessera_service.embedded\n",
    })
    assert any("tessera_worker.worker" in v for v in found)
    assert any("imports redis" in v for v in found)
    assert any("tessera_base/sub" in v and "tessera_service" in v for v in found)
    assert any("tessera/tessera/cli.py" in v for v in found)
    assert any("benchmarks/footprint.py" in v for v in found)
    assert len(found) == 5, found  # the CLI package, tessera.__main__ and farm.py are allowed
    # And the CLI is the only package allowed to import the worker:
    assert [k for k in ALLOWED if "tessera_worker" in ALLOWED[k]] == [CLI]


def test_the_checker_sees_a_hidden_cycle(tmp_path):
    """Negative control: a cycle through a lazy import, one through TYPE_CHECKING, one
    through `from package import module` and one between scripts are each found; a
    package's __init__ importing its modules, which import a sibling, is no cycle, nor is a
    module's import of the core's compiled module (`from .. import _core`)."""
    _, found = _checked_tree(tmp_path, {
        "renderer/tessera_renderer/__init__.py": "from .usd.stage import Stage\n",
        "renderer/tessera_renderer/usd/__init__.py": "from . import stage, lights\n",
        "renderer/tessera_renderer/usd/stage.py": "from .lights import read\nfrom . import subdivision\n",
        "renderer/tessera_renderer/usd/subdivision.py": "def f():\n    from .. import _core\n",
        "renderer/tessera_renderer/usd/lights.py": "def read():\n    from .stage import Stage\n",
        "renderer/tessera_renderer/usd/materials.py": "from typing import TYPE_CHECKING\n"
                                                     "if TYPE_CHECKING:\n    from .mtlx import M\n",
        "renderer/tessera_renderer/usd/mtlx.py": "from tessera_renderer.usd import materials\n",
        "renderer/tessera_renderer/usd/errors.py": "",
        "renderer/tessera_renderer/usd/camera.py": "from . import errors\nfrom tessera_renderer import usd\n",
        "benchmarks/common.py": "import farm\n",
        "benchmarks/farm.py": "from common import x\n",
    })
    assert found == [["benchmarks/common.py", "benchmarks/farm.py"],
                     ["tessera_renderer.usd.lights", "tessera_renderer.usd.stage"],
                     ["tessera_renderer.usd.materials", "tessera_renderer.usd.mtlx"]]
