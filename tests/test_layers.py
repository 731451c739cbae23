"""Import boundaries: the tracker, smoother and fit can never see the truth (the simulator); the physics core stays free of I/O libraries.

Checked statically over each module's own imports, followed through gyrorig's modules
(the package ``__init__`` is not followed: importing a submodule runs it, but the
submodule's code cannot reach what it does not import).
"""

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "gyrorig"


def _module_file(name: str) -> Path | None:
    parts = name.split(".")[1:]
    f = SRC.joinpath(*parts).with_suffix(".py")
    if f.exists():
        return f
    init = SRC.joinpath(*parts, "__init__.py")
    return init if parts and init.exists() else None


def _imports(path: Path, package: str) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
                out.add(mod)
                out |= {f"{mod}.{a.name}" for a in node.names}
            else:
                out.add(node.module)
    return out


def closure(module: str) -> set[str]:
    seen, todo = set(), [module]
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        f = _module_file(m)
        if f is None:
            continue
        package = m if f.name == "__init__.py" else m.rsplit(".", 1)[0]
        for imp in _imports(f, package):
            if imp.startswith("gyrorig.") and _module_file(imp) is not None and imp != "gyrorig":
                todo.append(imp)
            elif not imp.startswith("gyrorig"):
                seen.add(imp)
    return seen


def test_identification_cannot_reach_the_simulator():
    """identify fits exact models (the elliptic solution, steady precession), never the simulator that makes
    its synthetic tables."""
    import ast

    reached = closure("gyrorig.identify")
    forbidden = {m for m in reached if m.startswith(("gyrorig.render", "gyrorig.bench", "gyrorig.montecarlo",
                                                     "gyrorig.pipeline", "gyrorig.validation", "gyrorig.expectation",
                                                     "gyrorig.physics.gimbal"))}
    assert not forbidden, sorted(forbidden)
    # the elliptic solution's module imports the simulator's state helpers; identify itself never takes simulate
    # (nor predict, which simulates damped scenes)
    for f in (SRC / "identify").glob("*.py"):
        names = {a.asname or a.name for node in ast.walk(ast.parse(f.read_text()))
                 if isinstance(node, ast.ImportFrom) for a in node.names}
        assert not names & {"simulate", "predict", "simulate_gimbal"}, f


@pytest.mark.parametrize("module", ["gyrorig.tracking", "gyrorig.calibration", "gyrorig.board_pose", "gyrorig.smooth",
                                    "gyrorig.fit"])
def test_tracking_cannot_reach_the_truth(module):
    reached = closure(module)
    forbidden = {m for m in reached if m.startswith(("gyrorig.physics", "gyrorig.render", "gyrorig.theory",
                                                     "gyrorig.validation", "gyrorig.bench", "gyrorig.montecarlo",
                                                     "gyrorig.expectation", "gyrorig.pipeline"))}
    assert not forbidden, f"{module} reaches {sorted(forbidden)}"


@pytest.mark.parametrize("module", ["gyrorig.physics.simulate", "gyrorig.physics.exact", "gyrorig.physics.phasor",
                                    "gyrorig.physics._jit", "gyrorig.physics.gimbal", "gyrorig.theory"])
def test_physics_core_has_no_video_filtering_or_plotting(module):
    reached = {m.split(".")[0] for m in closure(module)}
    assert not reached & {"cv2", "matplotlib", "filterpy"}, sorted(reached & {"cv2", "matplotlib", "filterpy"})


@pytest.mark.parametrize("module", ["gyrorig.bench", "gyrorig.theory", "gyrorig.validation", "gyrorig.bench.stability", "gyrorig.montecarlo",
                                    "gyrorig.pipeline", "gyrorig.demo", "gyrorig.expectation",
                                    "gyrorig.render", "gyrorig.tracking", "gyrorig.physics.simulate", "gyrorig.smooth",
                                    "gyrorig.fit", "gyrorig.analysis", "gyrorig.plan"])
def test_library_modules_do_not_import_the_command_line(module):
    assert "gyrorig.cli" not in closure(module)


def _graph() -> dict[str, set[str]]:
    """Every gyrorig module's imports of other gyrorig modules (function-level imports included), without
    the edges to its own parent packages (a submodule cannot be imported without them)."""
    graph = {}
    for f in SRC.rglob("*.py"):
        rel = f.relative_to(SRC.parent).with_suffix("")
        name = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        package = name if f.name == "__init__.py" else name.rsplit(".", 1)[0]
        deps = {m for m in _imports(f, package) if m.startswith("gyrorig.") and _module_file(m) is not None}
        graph[name] = {d for d in deps if d != name and not name.startswith(d + ".")}
    return graph


def test_no_import_cycles():
    graph = _graph()
    state: dict[str, int] = {}
    cycles = []

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                cycles.append(path[path.index(d):] + [d] if d in path else [m, d])
            elif d not in state:
                visit(d, path + [d])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    assert not cycles, cycles[:5]


#: functions allowed above the length limit: compiled kernels (one loop, no calls) and the argument parser
LONG_FUNCTIONS_ALLOWED = {"build_parser", "_integrate", "_filter"}


def test_modules_and_functions_stay_small():
    """No module over about 600 lines, no function over about 100 (the layout in docs/architecture.md)."""
    big_files, long_functions = [], []
    for f in SRC.rglob("*.py"):
        text = f.read_text()
        if text.count("\n") > 620:
            big_files.append((f.name, text.count("\n")))
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name not in LONG_FUNCTIONS_ALLOWED:
                length = node.end_lineno - node.lineno + 1
                if length > 100:
                    long_functions.append((f"{f.name}:{node.name}", length))
    assert not big_files and not long_functions, (big_files, long_functions)


def test_every_package_is_installed():
    """pyproject.toml lists the packages explicitly (the bundled protocols map to another folder): the list
    must hold every package under src/gyrorig, and the bundled protocols."""
    import tomllib
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    listed = set(tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(root / "src").parts) for p in (root / "src" / "gyrorig").rglob("__init__.py")}
    assert found | {"gyrorig.bundled_protocols"} == listed


def test_the_command_lines_modules_do_not_import_their_package():
    """cli/__init__.py runs the commands; the modules it dispatches to import nothing back from it (no cycle
    hidden behind a package edge)."""
    for f in (SRC / "cli").glob("*.py"):
        if f.name != "__init__.py":
            assert "gyrorig.cli" not in _imports(f, "gyrorig.cli"), f.name
