"""The package's imports run one way: down a fixed order of layers, with no circle between modules,
function-local imports included (they are read from the source, not from what Python loaded)."""

import ast
from collections import defaultdict
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "microg_env"
#: The package's layers, bottom first: a module may import its own layer and those below it. The
#: package itself (``microg_env/__init__.py``, which registers the environments) is above them all.
LAYERS = (
    ("validate", "compiled", "version", "workers", "retired"),
    ("files", "params"),
    ("rigs", "scenarios", "trajectory"),
    ("logs",),  # a rig's logs, in the schema of its scenarios
    ("sim",),
    ("imperfections",),
    ("interface", "task", "scores"),  # the env-controller contract, the task settings, the tasks' scores
    ("controllers",),
    ("envs",),
    ("analysis",),  # pure functions of a trajectory
    ("rollout",),  # everything that runs episodes
    ("paper",),
    ("experiments", "learning"),
    ("cli",),
)


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(path): path for path in PACKAGE.rglob("*.py")}


def _imports(module: str) -> dict[str, int]:
    """The package's modules ``module`` imports anywhere in its source, with a line of each."""
    found: dict[str, int] = {}
    for node in ast.walk(ast.parse(MODULES[module].read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"{module}:{node.lineno}: a relative import (write the package's name)"
            # `from a import b`: the module a.b where there is one, else a
            names = [
                f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in MODULES else node.module for a in node.names
            ]
        else:
            continue
        for name in names:
            if name.split(".")[0] != "microg_env":
                continue
            while name not in MODULES:  # an attribute path: its module
                name = name.rpartition(".")[0]
            if name != module:
                found.setdefault(name, node.lineno)
    return found


GRAPH = {module: _imports(module) for module in MODULES}


def _layer(module: str) -> int:
    if module == "microg_env":
        return len(LAYERS)
    top = module.split(".")[1]
    return next(i for i, names in enumerate(LAYERS) if top in names)


def test_every_module_has_a_layer():
    for module in MODULES:
        assert _layer(module) >= 0  # StopIteration (a failure) for a module of no layer


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_run_down_the_layers(module):
    upward = [
        f"{module}:{line} imports {other} (layer {_layer(other)} > {_layer(module)})"
        for other, line in GRAPH[module].items()
        if _layer(other) > _layer(module)
    ]
    assert not upward, "\n".join(upward)


def _cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
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

    for v in graph:
        if v not in index:
            visit(v)
    return found


def test_no_module_imports_another_that_imports_it_back():
    assert _cycles(GRAPH) == []


def test_the_cycle_finder_finds_a_circle_and_the_layer_check_an_upward_import():
    """Both checks can fail: a made-up circle through three modules, and a made-up upward import."""
    graph = defaultdict(dict, {"a": {"b": 1}, "b": {"c": 1}, "c": {"a": 1}, "d": {"a": 1}})
    assert _cycles(graph) == [["a", "b", "c"]]
    assert _layer("microg_env.sim.model") < _layer("microg_env.analysis.metrics")


RESEARCH = PACKAGE.parent / "research"


def _top_level_imports(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_the_product_never_imports_the_research_probes():
    """The package, the user's tools in training/, the benchmarks and the default suite import no
    module of research/ (the probes are the research record, not the product)."""
    probes = {path.stem for path in RESEARCH.glob("*.py")} - {"conftest"} | {"research"}
    assert {"partial_oracles", "finetune_probe", "plain_sb3"} <= probes
    product = [*PACKAGE.rglob("*.py"), *(PACKAGE.parent / "training").glob("*.py")]
    product += [*(PACKAGE.parent / "benchmarks").glob("*.py"), *(PACKAGE.parent / "tests").rglob("*.py")]
    offenders = {str(path): sorted(_top_level_imports(path) & probes) for path in product}
    assert not {path: names for path, names in offenders.items() if names}
    reaching = [path.name for path in (PACKAGE.parent / "tests").rglob("*.py") if '/ "research"' in path.read_text()]
    assert reaching == [Path(__file__).name]  # this test alone names the folder
