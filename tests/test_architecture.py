"""The import arrows of docs/design.md, checked on the source (AST), not at run time.

Layers, by folder; each imports only from its own layer and the layers below it:

0. ``uav_ipp`` (the world, source folder ``envs/``): imports nothing from ``sb3_coma``. Fusion wrappers that live on the
   algorithm side (SenDFuse) reach ``uav_ipp.make_vec_env`` through the ``uav_ipp.fusion`` entry
   point, looked up when an env is wrapped.
1. the library: ``sb3_coma/coma/`` (the algorithm), ``sb3_coma/mappo/`` (IPPO/MAPPO),
   ``sb3_coma/sendfuse/``, ``sb3_coma/baselines/``, ``sb3_coma/common/`` (what the algorithms
   share: the multi-agent vec env and its contract, masking, extractors, callbacks, checkpoint
   files, evaluation of objects), ``sb3_coma/stats/`` (paired statistics, tables),
   ``sb3_coma/uav/`` and the package's ``__init__`` (whose two front doors load the application
   lazily, by a name held in data, never by an import statement). Inside the library the folders
   stand on floors of their own (``LIBRARY_FLOORS``): ``common`` imports no algorithm, the
   algorithms and ``stats`` import nothing of one another nor of ``uav``.
2. the application: ``sb3_coma/app/`` (training runs, config, zoo, pretrained, export, the
   evaluation front door) and the top-level shims that keep public names (``sb3_coma/training.py``,
   ``sb3_coma/zoo.py``).
3. the experiments: ``sb3_coma/experiments/`` (reproduce, report, plots, ablation, noise sweep,
   AG weighting, protocols, costs).
4. the command line: ``sb3_coma/cli/`` and ``sb3_coma/__main__.py``, which names every command.

Every ``import`` / ``from ... import`` counts, wherever it sits (module level, inside functions,
under ``if TYPE_CHECKING``), and so does ``importlib.import_module("...")`` with a literal name.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: Layer of each folder (or top-level module) of ``sb3_coma``; a module outside these fails the test.
LAYERS: dict[str, int] = {
    "sb3_coma": 1,  # the package __init__
    "sb3_coma.coma": 1,
    "sb3_coma.sendfuse": 1,
    "sb3_coma.baselines": 1,
    "sb3_coma.common": 1,
    "sb3_coma.mappo": 1,
    "sb3_coma.stats": 1,
    "sb3_coma.uav": 1,
    "sb3_coma.app": 2,
    "sb3_coma.training": 2,
    "sb3_coma.zoo": 2,
    "sb3_coma.experiments": 3,
    "sb3_coma.cli": 4,
    "sb3_coma.__main__": 4,
}
LAYER_NAMES = {0: "uav_ipp", 1: "library", 2: "application", 3: "experiments", 4: "cli"}

#: Floors of the library's folders (docs/design.md §2): a folder imports from itself and from the
#: floors below it only, never from a folder beside it on its own floor.
LIBRARY_FLOORS: dict[str, int] = {
    "sb3_coma.baselines": 0,  # planners: the world only
    "sb3_coma.sendfuse": 0,
    "sb3_coma.common": 1,  # what the algorithms share
    "sb3_coma.coma": 2,  # the two algorithms, side by side
    "sb3_coma.mappo": 2,
    "sb3_coma.stats": 2,  # reads evaluation results
    "sb3_coma.uav": 3,  # the UAV world's COMA policies and DAgger warm start
    "sb3_coma": 4,  # the package __init__
}


def layer_of(module: str) -> int | None:
    """The layer of a module of this repository (``None``: not ours, e.g. numpy)."""
    if module == WORLD or module.startswith(WORLD + "."):
        return 0
    if module == "sb3_coma":
        return LAYERS["sb3_coma"]
    parts = module.split(".")
    if parts[0] != "sb3_coma":
        return None
    return LAYERS.get(".".join(parts[:2]))


@dataclass(frozen=True)
class Import:
    module: str  # the importing module
    target: str  # the imported module
    where: str  # file:line

    def __str__(self) -> str:
        return f"{self.where}: {self.module} imports {self.target}"


#: The world installs as ``uav_ipp`` from the source folder ``envs/`` (setup.cfg ``package_dir``).
WORLD, WORLD_SOURCE = "uav_ipp", "envs"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[0] == WORLD_SOURCE:
        parts[0] = WORLD
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_module(dotted: str) -> bool:
    parts = dotted.split(".")
    if parts[0] == WORLD:
        parts[0] = WORLD_SOURCE
    base = ROOT.joinpath(*parts)
    return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    """The absolute module of a ``from X import ...`` in ``module`` (relative levels resolved)."""
    if not node.level:
        return node.module or ""
    package = module.split(".")
    if not is_package:
        package = package[:-1]
    package = package[: len(package) - (node.level - 1)]
    return ".".join(package + ([node.module] if node.module else []))


def _literal_import(node: ast.Call) -> str | None:
    """``importlib.import_module("x")`` / ``import_module("x")`` / ``__import__("x")`` with a literal."""
    func = node.func
    name = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else None
    if name in ("import_module", "__import__") and node.args and isinstance(node.args[0], ast.Constant):
        value = node.args[0].value
        return value if isinstance(value, str) and not value.startswith(".") else None
    return None


def imports_of(path: Path, module: str | None = None) -> list[Import]:
    """Every module ``path`` (module ``module``, default: its name under the repository) imports,
    from any statement anywhere in the file."""
    module = module or _module_name(path)
    shown = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
    found: list[Import] = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        where = f"{shown}:{getattr(node, 'lineno', 0)}"
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(module, path.name == "__init__.py", node)
            # ``from pkg import sub`` imports the submodule ``pkg.sub`` when there is one
            targets = [f"{base}.{a.name}" if _is_module(f"{base}.{a.name}") else base for a in node.names]
        elif isinstance(node, ast.Call):
            literal = _literal_import(node)
            targets = [literal] if literal else []
        found.extend(Import(module, t, where) for t in dict.fromkeys(targets))
    return found


def _sources(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


def _all_imports(package: str) -> list[Import]:
    return [imp for path in _sources(package) for imp in imports_of(path)]


def test_the_walker_sees_imports_everywhere(tmp_path: Path) -> None:
    """Imports inside functions, under TYPE_CHECKING and through importlib all count."""
    sample = ROOT / "sb3_coma" / "cli" / "commands" / "train.py"
    targets = {imp.target for imp in imports_of(sample)}
    assert {"sb3_coma.app.training", "sb3_coma.app.arguments"} <= targets
    assert "yaml" in {imp.target for imp in imports_of(ROOT / "sb3_coma" / "app" / "arguments.py")}
    cli = {imp.target for imp in imports_of(ROOT / "sb3_coma" / "cli" / "__init__.py")}
    assert "sb3_coma.cli.commands" in cli  # ``from sb3_coma.cli import commands`` is the subpackage
    probe = tmp_path / "probe.py"
    probe.write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import sb3_coma.app.training\n"
        "def f():\n    from ..app import zoo\n    import importlib\n    importlib.import_module('sb3_coma.cli')\n"
    )
    got = {imp.target for imp in imports_of(probe, module="sb3_coma.baselines.probe")}
    assert {"sb3_coma.app.training", "sb3_coma.app.zoo", "sb3_coma.cli"} <= got


def test_the_world_imports_nothing_from_sb3_coma() -> None:
    bad = [imp for imp in _all_imports(WORLD_SOURCE) if imp.target == "sb3_coma" or imp.target.startswith("sb3_coma.")]
    assert not bad, "uav_ipp must not import sb3_coma (docs/design.md):\n" + "\n".join(map(str, bad))


def test_every_module_sits_in_a_layer_folder() -> None:
    """A new module must go into a layer's folder (or be added to LAYERS on purpose)."""
    modules = {_module_name(path) for path in _sources("sb3_coma")}
    homeless = sorted(m for m in modules if layer_of(m) is None)
    assert not homeless, f"modules outside the layer folders: {homeless}"


def test_imports_point_only_down_the_layers() -> None:
    imports = _all_imports("sb3_coma")
    assert {layer_of(imp.module) for imp in imports} >= {1, 2, 3, 4}, "a layer has no modules"
    bad = []
    for imp in imports:
        own, target = layer_of(imp.module), layer_of(imp.target)
        if own is not None and target is not None and target > own:
            bad.append(f"{imp} ({LAYER_NAMES[own]} -> {LAYER_NAMES[target]})")
    assert not bad, "imports that point up the layers (docs/design.md):\n" + "\n".join(bad)


def _library_folder(module: str) -> str:
    return ".".join(module.split(".")[:2])


def test_every_library_folder_stands_on_a_floor() -> None:
    assert set(LIBRARY_FLOORS) == {folder for folder, layer in LAYERS.items() if layer == 1}


def test_library_folders_import_only_down_their_floors() -> None:
    """``common`` imports nothing of ``coma``, ``mappo``, ``stats`` or ``uav``; ``coma``, ``mappo``
    and ``stats`` nothing of one another nor of ``uav`` (the layers above: the test before)."""
    bad = []
    for imp in _all_imports("sb3_coma"):
        if layer_of(imp.module) != 1 or layer_of(imp.target) != 1:
            continue
        own, target = _library_folder(imp.module), _library_folder(imp.target)
        if own != target and LIBRARY_FLOORS[target] >= LIBRARY_FLOORS[own]:
            bad.append(f"{imp} (floor {LIBRARY_FLOORS[own]} -> {LIBRARY_FLOORS[target]})")
    assert not bad, "library imports that point up or sideways (docs/design.md §2):\n" + "\n".join(bad)


@pytest.mark.parametrize(
    ("module", "layer"),
    [
        ("sb3_coma.coma.coma", 1),
        ("sb3_coma.common.evaluation", 1),
        ("sb3_coma.stats.paired", 1),
        ("sb3_coma.mappo.mappo", 1),
        ("sb3_coma.common.joint", 1),
        ("sb3_coma.app.training", 2),
        ("sb3_coma.app.evaluation", 2),
        ("sb3_coma.experiments.reproduce", 3),
        ("sb3_coma.cli.commands.train", 4),
    ],
)
def test_layer_table_names_real_modules(module: str, layer: int) -> None:
    assert _is_module(module) and layer_of(module) == layer, module


def _module_level_graph() -> dict[str, set[str]]:
    """module -> sb3_coma modules it imports at module level (what runs at import time)."""
    graph: dict[str, set[str]] = {}
    for path in _sources("sb3_coma"):
        module = _module_name(path)
        tree = ast.parse(path.read_text(encoding="utf-8"))
        found: set[str] = set()
        for node in tree.body:
            if isinstance(node, ast.ImportFrom):
                base = _resolve(module, path.name == "__init__.py", node)
                found |= {f"{base}.{a.name}" if _is_module(f"{base}.{a.name}") else base for a in node.names}
            elif isinstance(node, ast.Import):
                found |= {a.name for a in node.names}
        graph[module] = {m for m in found if m.startswith("sb3_coma") and m != module}
    return graph


def test_no_import_cycles_between_modules() -> None:
    graph = _module_level_graph()
    # a package's __init__ importing its own submodules is how packages export names, not a cycle
    edges = {m: {t for t in ts if not t.startswith(m + ".")} for m, ts in graph.items()}
    state: dict[str, int] = {}
    cycles: list[str] = []

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(edges.get(node, ())):
            if state.get(nxt) == 1:
                cycles.append(" -> ".join([*stack[stack.index(nxt) :], nxt]) if nxt in stack else f"{node} -> {nxt}")
            elif nxt in edges and not state.get(nxt):
                visit(nxt, [*stack, nxt])
        state[node] = 2

    for module in sorted(edges):
        if not state.get(module):
            visit(module, [module])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_import_sb3_coma_loads_neither_rl_zoo3_nor_the_application() -> None:
    code = (
        "import sys, sb3_coma\n"
        "bad = [m for m in sys.modules if m == 'rl_zoo3' or m.startswith(('rl_zoo3.', 'sb3_coma.app', "
        "'sb3_coma.experiments', 'sb3_coma.cli'))]\n"
        "print(bad)\n"
        "from sb3_coma import evaluate, load_pretrained\n"
        "print(evaluate.__module__, load_pretrained.__module__)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    lines = out.stdout.strip().splitlines()
    assert lines[0] == "[]", lines[0]
    assert lines[1] == "sb3_coma.app.evaluation sb3_coma.app.pretrained"


def test_importing_the_world_is_cheap_and_its_names_resolve() -> None:
    """``import uav_ipp`` registers the gymnasium ids only (docs/design.md, "Packaging"); every
    public name is served, lazily, from the submodule ``_LAZY`` names, and ``__all__`` lists them."""
    code = (
        "import sys, uav_ipp, gymnasium\n"
        "heavy = [m for m in ('numba', 'supersuit', 'uav_ipp.kernels', 'uav_ipp.maps') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
        "assert 'UavIpp-Env3-v0' in gymnasium.registry\n"
        "assert sorted(uav_ipp.__all__) == sorted([*uav_ipp._LAZY, 'ENV_IDS', 'map_name_of']), uav_ipp.__all__\n"
        "assert all(getattr(uav_ipp, name) is not None for name in uav_ipp.__all__)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT.parent, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-2000:]


def test_the_source_folder_is_not_importable_as_envs() -> None:
    """In a checkout, ``import envs`` would load a second copy of the world: it fails with one line."""
    result = subprocess.run([sys.executable, "-c", "import envs"], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode != 0 and "import uav_ipp" in result.stderr.strip().splitlines()[-1]
