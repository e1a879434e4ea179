"""The project's import graph has no cycles (lazy, function-level imports included): data flows one way,
landmarks -> inference core -> models -> pipeline/train -> cli/app/deploy."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("landmarks", "models_def", "deploy", "lsr", "app")


def project_modules() -> dict[str, Path]:
    modules = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


def import_graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """module -> the project modules it imports anywhere in its file. ``from package import submodule`` is an
    edge to the submodule (the package's __init__ runs first in any case, as for every import below it)."""
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                submodules = [f"{node.module}.{alias.name}" for alias in node.names]
                targets = [t for t in submodules if t in modules] or [node.module]
            else:
                continue
            graph[name].update(t for t in targets if t in modules and t != name)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for target in sorted(graph[node]):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_no_import_cycles():
    assert cycles(import_graph(project_modules())) == []


def test_the_cycle_finder_finds_one():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_lower_floors_do_not_import_upper_ones():
    graph = import_graph(project_modules())
    # what each lower floor may import of ours (the inference core: landmarks and the lsr package's __init__ only)
    floors = {"landmarks": set(), "models_def": {"landmarks"}, "lsr.core": {"landmarks", "lsr"}}
    for name, targets in graph.items():
        floor = next((f for f in floors if name == f or name.startswith(f + ".")), None)
        if floor is not None:
            outside = {t for t in targets if t != "lsr" and t.split(".")[0] not in floors[floor] - {"lsr"}
                       and not (t == floor or t.startswith(floor + "."))}
            assert not outside, f"{name} imports {sorted(outside)}"


# README's order: imports flow rightwards. lsr.bench is the top floor: its commands run the app and the web page.
FLOORS = ("landmarks", "models_def", "lsr.core", "deploy", "lsr", "app", "lsr.bench")


def floor_of(module: str) -> str:
    """The floor of a module: the longest floor it sits in (lsr.core and lsr.bench before lsr)."""
    return max((f for f in FLOORS if module == f or module.startswith(f + ".")), key=len)


def floor_imports() -> dict[str, set[str]]:
    """floor -> the other floors its modules import (README's "imports of ours")."""
    found: dict[str, set[str]] = {floor: set() for floor in FLOORS}
    for name, targets in import_graph(project_modules()).items():
        found[floor_of(name)].update(floor_of(t) for t in targets if floor_of(t) != floor_of(name))
    return found


def test_floors_import_only_floors_to_their_left():
    for floor, targets in floor_imports().items():
        assert targets <= set(FLOORS[:FLOORS.index(floor)]), f"{floor} imports {sorted(targets)}"


def test_the_readme_layout_table_shows_the_imports_that_exist():
    rows = {}
    for line in (ROOT / "README.md").read_text().splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0].startswith("`") and cells[0].rstrip("`").endswith("/"):
            folder = cells[0].strip("`").rstrip("/").replace("/", ".")
            if folder in FLOORS:
                rows[folder] = set() if cells[2] == "none" else {name.strip() for name in cells[2].split(",")}
    assert set(rows) == set(FLOORS)
    actual = floor_imports()
    assert {floor: rows[floor] for floor in FLOORS} == actual


def test_the_inference_core_needs_no_torch():
    """lsr.core is shared by the torch pipeline and the ONNX runtime: importing it must not import torch."""
    import subprocess
    import sys

    code = "import sys, lsr.core.engine, lsr.core.inputs; assert 'torch' not in sys.modules, 'torch imported'"
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


INFERENCE_PATH = ("lsr.core", "deploy", "lsr.pipeline", "lsr.export.graphs", "lsr.export.bundle", "lsr.layout_view")


def reachable(graph: dict[str, set[str]], starts: list[str]) -> set[str]:
    seen, todo = set(), list(starts)
    while todo:
        name = todo.pop()
        if name not in seen:
            seen.add(name)
            todo.extend(graph[name])
    return seen


def test_the_per_frame_inference_path_never_imports_training():
    """Fine-tuning is composed on top of inference (lsr reenact, the app, lsr eval), never imported by it."""
    modules = project_modules()
    graph = import_graph(modules)
    starts = [name for name in modules if name.startswith(INFERENCE_PATH)]
    assert "lsr.pipeline" in starts and "lsr.core.engine" in starts
    training = sorted(name for name in reachable(graph, starts) if name.startswith("lsr.train"))
    assert training == [], f"the inference path reaches {training}"


def test_training_never_imports_evaluation():
    """Data flows one way: training (and fine-tuning) reaches no module of lsr.eval or lsr.bench."""
    modules = project_modules()
    graph = import_graph(modules)
    starts = [name for name in modules if name.startswith("lsr.train")]
    reached = sorted(name for name in reachable(graph, starts) if name.startswith(("lsr.eval", "lsr.bench")))
    assert reached == [], f"training reaches {reached}"


def test_landmarks_keeps_at_most_ten_modules_at_its_top():
    top = sorted(path.name for path in (ROOT / "landmarks").glob("*.py") if path.name != "__init__.py")
    assert len(top) <= 10, top


def test_no_two_modules_share_a_file_name():
    """A file's name says what it does, once: grep and tracebacks find one file."""
    names: dict[str, list[str]] = {}
    for name, path in project_modules().items():
        if path.name not in ("__init__.py", "__main__.py"):
            names.setdefault(path.name, []).append(name)
    assert {file: found for file, found in names.items() if len(found) > 1} == {}


def test_every_cli_runner_resolves_to_a_function():
    """The CLI table names its runners as "module:function" (imported when chosen): each must exist."""
    from lsr.cli import COMMANDS, GROUPS, _resolve

    tables = [COMMANDS, *GROUPS.values()]
    runners = [runner for table in tables for _, runner in table.values()]
    assert runners and all(callable(_resolve(runner)) for runner in runners)


def test_no_module_is_a_side_entry_point():
    """Every command is an `lsr` sub-command: no module of ours runs as `python -m` (a __main__ block)."""
    modules = project_modules()
    side = [name for name, path in modules.items() if 'if __name__ == "__main__"' in path.read_text()
            and name not in ("lsr.cli", "app.__main__", "deploy.example_embed")]
    assert side == [], f"run these as lsr sub-commands instead: {side}"
