"""The package's shape: every module imports, imports inside coopsumo form no cycle, and the layers point
one way (studies -> agents -> sim; report used by studies; envs on agents and sim; sim and report never
import torch). No SUMO run."""

from __future__ import annotations

import ast
import importlib
import pkgutil
from pathlib import Path

import pytest

import coopsumo

PACKAGE_DIR = Path(coopsumo.__file__).parent
# what each layer may import from the others (the top-level modules config, dqn_config, paths, runio, validation,
# record_schemas, study_tables, pool_workers and the rest of SHARED are shared by all)
SHARED = {"coopsumo", "coopsumo.config", "coopsumo.dqn_config", "coopsumo.paths", "coopsumo.policy_spec",
          "coopsumo.runio", "coopsumo.validation", "coopsumo.errors", "coopsumo.provenance", "coopsumo.files",
          "coopsumo.run_dirs", "coopsumo.run_markers", "coopsumo.owners", "coopsumo.lock_files",
          "coopsumo.record_schemas", "coopsumo.study_tables", "coopsumo.field_rules", "coopsumo.pool_workers"}
GROUND = {"coopsumo.errors", "coopsumo.provenance", "coopsumo.files", "coopsumo.paths"}
"""the ground floor: errors, provenance, files and output paths, which import nothing else of coopsumo"""
ALLOWED = {
    "coopsumo.sim": {"coopsumo.sim"},
    "coopsumo.agents": {"coopsumo.agents", "coopsumo.sim"},
    "coopsumo.report": {"coopsumo.report"},
    "coopsumo.studies": {"coopsumo.studies", "coopsumo.agents", "coopsumo.sim", "coopsumo.report"},
    "coopsumo.envs": {"coopsumo.envs", "coopsumo.agents", "coopsumo.sim"},  # Gymnasium / PettingZoo interfaces
    "coopsumo.bench": {"coopsumo.bench", "coopsumo.studies", "coopsumo.agents", "coopsumo.sim", "coopsumo.report"},
}


def module_files() -> dict[str, Path]:
    """Every module of the package by its dotted name (packages by their own name)."""
    out = {}
    for path in PACKAGE_DIR.rglob("*.py"):
        parts = ("coopsumo", *path.relative_to(PACKAGE_DIR).with_suffix("").parts)
        name = ".".join(parts).removesuffix(".__init__")
        out[name] = path
    return out


def import_graph(files: dict[str, Path]) -> dict[str, set[str]]:
    """Static graph of every import of a coopsumo module, at module level or inside functions alike."""
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("coopsumo"):
                assert node.module is not None
                for alias in node.names:  # `from coopsumo.sim import world` imports the module coopsumo.sim.world
                    full = f"{node.module}.{alias.name}"
                    deps.add(full if full in files else node.module)
            elif isinstance(node, ast.Import):
                deps |= {alias.name for alias in node.names if alias.name.startswith("coopsumo")}
        graph[name] = {d for d in deps if d != name}
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle as a list of modules (first == last), or None. Depth-first search with colours."""
    state: dict[str, int] = {}  # 1: on the current path, 2: finished
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for dep in sorted(graph.get(node, ())):
            if state.get(dep) == 1:
                return [*path[path.index(dep) :], dep]
            if dep not in state and (cycle := visit(dep)) is not None:
                return cycle
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)) is not None:
            return cycle
    return None


def layer(name: str) -> str | None:
    """The subpackage a module belongs to (coopsumo.sim, ...), None for the top-level and entry modules."""
    parts = name.split(".")
    return ".".join(parts[:2]) if len(parts) >= 3 or name in ALLOWED else None


def test_find_cycle_sees_a_cycle_and_its_absence() -> None:
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


@pytest.mark.parametrize("name", sorted(n for n in module_files() if n != "coopsumo.__main__"))
def test_every_module_imports(name: str) -> None:
    importlib.import_module(name)


def test_walk_packages_finds_the_same_modules() -> None:
    walked = {m.name for m in pkgutil.walk_packages(coopsumo.__path__, "coopsumo.")} | {"coopsumo"}
    compiled = {"coopsumo.sim._kernels"}  # the C extension built from coopsumo/sim/kernels.c (pyproject.toml)
    assert (PACKAGE_DIR / "sim" / "kernels.c").is_file()
    assert walked == set(module_files()) | compiled


def test_no_import_cycle_inside_coopsumo() -> None:
    cycle = find_cycle(import_graph(module_files()))
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_layers_import_one_way() -> None:
    wrong = []
    for name, deps in import_graph(module_files()).items():
        own = layer(name)
        if own is None:
            continue
        for dep in deps:
            dep_layer = layer(dep)
            if dep not in SHARED and (dep_layer is None or dep_layer not in ALLOWED[own]):
                wrong.append(f"{name} imports {dep}")
    assert not wrong, "; ".join(sorted(wrong))


def test_sim_and_report_never_import_torch() -> None:
    for name, path in module_files().items():
        if layer(name) in ("coopsumo.sim", "coopsumo.report"):
            tree = ast.parse(path.read_text())
            names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
            names |= {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
            assert not any(n == "torch" or n.startswith("torch.") for n in names), name


def test_text_names_only_modules_that_exist() -> None:
    """Docstrings, comments and docs name modules by their current dotted paths, not by the top-level
    paths they had before the subpackages (the world, the dqn, ...): every dotted name is a module or an
    attribute of one."""
    import re

    names = set(module_files())
    root = PACKAGE_DIR.parent
    files = [*root.glob("coopsumo/**/*.py"), *root.glob("tests/*.py"), *root.glob("experiments/*.py"),
             *root.glob("*.md"), *root.glob("docs/*.md")]  # fmt: skip
    stale = []
    for path in files:
        for dotted in re.findall(r"\bcoopsumo(?:\.[a-z_][a-z0-9_]*)+", path.read_text()):
            parts = dotted.split(".")
            longest = max((".".join(parts[:i]) for i in range(1, len(parts) + 1) if ".".join(parts[:i]) in names),
                          key=len)  # fmt: skip
            rest = parts[len(longest.split(".")) :]
            module = importlib.import_module(longest) if rest else None
            if module is not None and not hasattr(module, rest[0]):
                stale.append(f"{path.relative_to(root)}: {dotted}")
    assert not stale, "; ".join(sorted(set(stale)))


MAX_MODULE_LINES = 500
"""a module past this is two concepts: split it"""


def test_every_module_stays_short() -> None:
    lengths = {name: len(path.read_text().splitlines()) for name, path in module_files().items()}
    long = {name: n for name, n in lengths.items() if n > MAX_MODULE_LINES}
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"


MAX_FUNCTION_LINES = 60
"""a function past this does two things: give one of them a name"""


def test_every_function_stays_short() -> None:
    long = {}
    for name, path in module_files().items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = (node.end_lineno or node.lineno) - node.lineno + 1
                if lines > MAX_FUNCTION_LINES:
                    long[f"{name}.{node.name}"] = lines
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines: {long}"


def test_the_engine_reaches_into_no_study() -> None:
    """studies/engine/ (runner, records, run folders, trainings, model store, statistics) is what every study runs on:
    it imports no study's folder, so that a study can change or go without touching the others."""
    graph = import_graph(module_files())
    engine = "coopsumo.studies.engine"
    bad = {f"{name} -> {dep}" for name, deps in graph.items() if name.startswith(engine) for dep in deps
           if dep.startswith("coopsumo.studies.") and not dep.startswith(engine)}  # fmt: skip
    assert not bad, sorted(bad)


MAX_FOLDER_MODULES = 12
"""a study folder past this holds two things: give one of them a folder (agents/ and sim/ are past it, 19 and 13)"""


def test_every_study_folder_stays_small() -> None:
    folders: dict[Path, int] = {}
    for path in module_files().values():
        if path.name != "__init__.py" and "studies" in path.relative_to(PACKAGE_DIR).parts:
            folders[path.parent] = folders.get(path.parent, 0) + 1
    big = {str(p.relative_to(PACKAGE_DIR)): n for p, n in folders.items() if n > MAX_FOLDER_MODULES}
    assert not big, f"folders over {MAX_FOLDER_MODULES} modules: {big}"


def test_the_ground_floor_imports_only_the_ground_floor() -> None:
    graph = import_graph(module_files())
    bad = {f"{name} -> {dep}" for name in GROUND for dep in graph[name] if dep not in GROUND | {"coopsumo"}}
    assert not bad, sorted(bad)


def test_only_commands_import_the_command_line_helpers() -> None:
    """runio (the parser, run_cli, signals) is the command layer's: the simulation, the configuration, the input
    checks, the policy grammar and the ground floor never import it."""
    graph = import_graph(module_files())
    below = [n for n in graph if n.startswith("coopsumo.sim.") or n in GROUND
             or n in {"coopsumo.config", "coopsumo.dqn_config", "coopsumo.validation", "coopsumo.policy_spec",
                      "coopsumo.run_dirs"}]
    bad = {f"{name} -> coopsumo.runio" for name in below if "coopsumo.runio" in graph[name]}
    assert not bad, sorted(bad)


def test_the_simulation_reads_no_policy_string() -> None:
    """sim/ receives typed values: whether SUMO's own models drive comes from SimConfig.sumo_driver, the policy
    grammar's (policy_spec) answer; no module of sim/ imports the grammar."""
    graph = import_graph(module_files())
    sim = [n for n in graph if n == "coopsumo.sim" or n.startswith("coopsumo.sim.")]
    bad = {name for name in sim if "coopsumo.policy_spec" in graph[name]}
    assert not bad, sorted(bad)
