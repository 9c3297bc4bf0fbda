"""The import arrows of DESIGN section 2, checked on the source (AST), not at run time.

Layers, each importing only from the layers below it:

1. ``envs`` (the world): imports nothing from ``sb3_coma``. Fusion wrappers that live on the
   algorithm side (SenDFuse) reach ``envs.make_vec_env`` through the ``uav_ipp.fusion`` entry
   point, looked up when an env is wrapped.
2. the library of ``sb3_coma``: every module that is not in :data:`APPLICATION` - the algorithm
   (``coma/``: COMA, policies, buffer, targets), ``extractors``, ``sendfuse/``, ``baselines/``
   and the learned baselines (``marl_baselines``), ``evaluation``, ``protocols``, ``paired``,
   ``costs``, ``ag_weighting``, ``callbacks``, ``checkpoints``, ``pretrained``, ``export``, the
   config format (``config``) and run folders (``runs``), and the package's ``__init__``. A new
   module is library unless it is added to :data:`APPLICATION`.
3. the application: training runs, the CLI, the rl-zoo entry, reproduce and its reports, plots,
   and the experiments built on top of the library (:data:`APPLICATION`).

Every ``import`` / ``from ... import`` counts, wherever it sits (module level, inside functions,
under ``if TYPE_CHECKING``), and so does ``importlib.import_module("...")`` with a literal name.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: Application modules of ``sb3_coma`` (dotted names; a name ending in ``.`` is a whole package).
APPLICATION = (
    "sb3_coma.__main__",
    "sb3_coma.ablation",
    "sb3_coma.cli",
    "sb3_coma.commands.",
    "sb3_coma.noise_sweep",
    "sb3_coma.plots",
    "sb3_coma.report",
    "sb3_coma.reproduce",
    "sb3_coma.training",
    "sb3_coma.zoo",
    "sb3_coma.zoo_sampler",
)


@dataclass(frozen=True)
class Import:
    module: str  # the importing module
    target: str  # the imported module
    where: str  # file:line

    def __str__(self) -> str:
        return f"{self.where}: {self.module} imports {self.target}"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_module(dotted: str) -> bool:
    base = ROOT.joinpath(*dotted.split("."))
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


def _is_application(module: str) -> bool:
    return any(
        module.startswith(a) if a.endswith(".") else module == a or module.startswith(a + ".") for a in APPLICATION
    )


def _all_imports(package: str) -> list[Import]:
    return [imp for path in _sources(package) for imp in imports_of(path)]


def test_the_walker_sees_imports_everywhere(tmp_path: Path) -> None:
    """Imports inside functions, under TYPE_CHECKING and through importlib all count."""
    sample = ROOT / "sb3_coma" / "commands" / "train.py"
    targets = {imp.target for imp in imports_of(sample)}
    assert {"sb3_coma.training", "sb3_coma.cli", "yaml"} <= targets
    cli = {imp.target for imp in imports_of(ROOT / "sb3_coma" / "cli.py")}
    assert "sb3_coma.commands" in cli  # ``from sb3_coma import commands`` is the subpackage
    probe = tmp_path / "probe.py"
    probe.write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import sb3_coma.training\n"
        "def f():\n    from .. import zoo\n    import importlib\n    importlib.import_module('sb3_coma.cli')\n"
    )
    got = {imp.target for imp in imports_of(probe, module="sb3_coma.baselines.probe")}
    assert {"sb3_coma.training", "sb3_coma.zoo", "sb3_coma.cli"} <= got


def test_envs_imports_nothing_from_sb3_coma() -> None:
    bad = [imp for imp in _all_imports("envs") if imp.target == "sb3_coma" or imp.target.startswith("sb3_coma.")]
    assert not bad, "envs must not import sb3_coma (DESIGN section 2):\n" + "\n".join(map(str, bad))


def test_library_imports_nothing_from_the_application() -> None:
    imports = _all_imports("sb3_coma")
    library = [imp for imp in imports if not _is_application(imp.module)]
    assert library, "no library modules found"
    bad = [imp for imp in library if _is_application(imp.target)]
    assert not bad, (
        "library modules of sb3_coma import application modules (DESIGN section 2; move the "
        "shared code into the library, or list the importer in APPLICATION if it is an application "
        "module):\n" + "\n".join(map(str, bad))
    )


@pytest.mark.parametrize(
    "module",
    [
        "sb3_coma.training",
        "sb3_coma.zoo",
        "sb3_coma.cli",
        "sb3_coma.commands.train",
        "sb3_coma.reproduce",
        "sb3_coma.plots",
        "sb3_coma.ablation",
    ],
)
def test_application_list_names_real_modules(module: str) -> None:
    assert _is_application(module) and _is_module(module), module


def test_library_list_in_the_docstring_names_real_modules() -> None:
    for name in (
        "coma",
        "coma.policies",
        "extractors",
        "sendfuse",
        "baselines",
        "evaluation",
        "paired",
        "callbacks",
        "checkpoints",
        "pretrained",
        "export",
        "config",
        "runs",
    ):
        module = f"sb3_coma.{name}"
        assert _is_module(module) and not _is_application(module), module
