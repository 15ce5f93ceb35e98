"""The architecture's layering, checked on the source: excite's subpackages import only the
layers below them (docs/architecture.md), envs never imports agents, and nothing in excite/
imports envs or agents at module level."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: excite's layers, lowest first: a module may import its own layer and the ones before it.
#: commands and cli, the composition root, may import any layer (the heavy ones lazily).
LAYERS = ("errors", "plugins", "signals", "processes", "core", "contracts", "stats", "logs",
          "validation", "calibration", "stopping", "estimators", "registration", "live",
          "commands", "cli")


def _imports(path: Path, top_level_only: bool = False) -> list[str]:
    tree = ast.parse(path.read_text())
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    names = [a.name for n in nodes if isinstance(n, ast.Import) for a in n.names]
    names += [n.module for n in nodes if isinstance(n, ast.ImportFrom) and n.module]
    return names


def _layer(path: Path) -> str:
    parts = path.relative_to(ROOT / "excite").with_suffix("").parts
    return parts[0]


@pytest.mark.parametrize("path", sorted((ROOT / "excite").rglob("*.py")), ids=str)
def test_excite_imports_only_the_layers_below(path):
    layer = _layer(path)
    if layer == "__init__":
        return  # the public API gathers names from every layer
    for module in _imports(path):
        if not module.startswith("excite."):
            continue
        target = module.split(".")[1]
        assert LAYERS.index(target) <= LAYERS.index(layer), (path.name, module)


@pytest.mark.parametrize("path", sorted((ROOT / "excite").rglob("*.py")), ids=str)
def test_excite_never_imports_envs_or_agents_at_module_level(path):
    for module in _imports(path, top_level_only=True):
        assert module.split(".")[0] not in {"envs", "agents", "gymnasium", "pymunk", "torch"}, (
            path.name, module)


@pytest.mark.parametrize("path", sorted((ROOT / "envs").rglob("*.py")), ids=str)
def test_envs_never_imports_agents(path):
    for module in _imports(path):
        assert module.split(".")[0] != "agents", (path.name, module)
