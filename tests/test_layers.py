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


@pytest.mark.parametrize("module", ["gyrorig.tracking", "gyrorig.calibration", "gyrorig.smooth", "gyrorig.fit"])
def test_tracking_cannot_reach_the_truth(module):
    reached = closure(module)
    forbidden = {m for m in reached if m.startswith(("gyrorig.physics", "gyrorig.render", "gyrorig.theory",
                                                     "gyrorig.validation", "gyrorig.stability", "gyrorig.bench"))}
    assert not forbidden, f"{module} reaches {sorted(forbidden)}"


@pytest.mark.parametrize("module", ["gyrorig.physics.simulate", "gyrorig.physics.exact", "gyrorig.physics.phasor",
                                    "gyrorig.physics._jit", "gyrorig.theory"])
def test_physics_core_has_no_video_filtering_or_plotting(module):
    reached = {m.split(".")[0] for m in closure(module)}
    assert not reached & {"cv2", "matplotlib", "filterpy"}, sorted(reached & {"cv2", "matplotlib", "filterpy"})


@pytest.mark.parametrize("module", ["gyrorig.bench", "gyrorig.theory", "gyrorig.validation", "gyrorig.stability",
                                    "gyrorig.render", "gyrorig.tracking", "gyrorig.physics.simulate", "gyrorig.smooth",
                                    "gyrorig.fit", "gyrorig.analysis", "gyrorig.plan"])
def test_library_modules_do_not_import_the_command_line(module):
    assert "gyrorig.cli" not in closure(module)
