"""The tree shows the architecture: one package per concern, dependencies that point
one way, no import cycle in Python or in C, no module too long to read, and a command
line that starts without the heavy libraries."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from graphlib import CycleError, TopologicalSorter
from pathlib import Path

import pytest
from rigtest import ROOT

# What each package may import (besides itself); docs/architecture.md draws it.
ALLOWED = {
    "rig.data": set(),
    "rig.estimator": {"rig.data"},
    "rig.sim": {"rig.data", "rig.estimator"},
    "rig.bias": {"rig.data", "rig.estimator", "rig.sim"},
    "rig.hil": {"rig.data", "rig.estimator"},
    "rig.diagnosis": {"rig.data", "rig.estimator", "rig.sim"},
    "rig.cli": {"rig.data", "rig.estimator", "rig.sim", "rig.bias", "rig.hil", "rig.diagnosis"},
    "bridge": {"rig.hil"},
}
MAX_LINES = 650          # "about 600": a module a reader takes in at one sitting
HEAVY = ("scipy", "torch", "matplotlib", "zenoh", "mcap")


def python_modules() -> dict[str, Path]:
    found = {}
    for path in [*(ROOT / "rig").rglob("*.py"), *(ROOT / "bridge").rglob("*.py")]:
        parts = path.relative_to(ROOT).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        found[name] = path
    return found


def imports_of(path: Path, modules: dict[str, Path]) -> set[str]:
    """The project's modules `path` imports (anywhere in it, lazily too)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for name in (node.module, *(f"{node.module}.{a.name}" for a in node.names)):
                if name in modules:
                    out.add(name)
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name in modules}
    return out


def package_of(module: str) -> str:
    parts = module.split(".")
    return ".".join(parts[:2]) if parts[0] == "rig" and len(parts) > 1 else parts[0]


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    modules = python_modules()
    return {name: imports_of(path, modules) - {name} for name, path in modules.items()}


def test_no_python_module_imports_itself_round_a_cycle(graph) -> None:
    # a package's __init__ importing its own modules is not a cycle between concerns
    edges = {m: {d for d in deps if not m.startswith(d + ".") and not d.startswith(m + ".")} for m, deps in graph.items()}
    try:
        tuple(TopologicalSorter(edges).static_order())
    except CycleError as exc:
        pytest.fail(f"import cycle: {' -> '.join(exc.args[1])}")


def test_each_package_imports_only_what_its_layer_allows(graph) -> None:
    wrong = sorted(f"{m} imports {d}" for m, deps in graph.items() for d in deps
                   if package_of(m) in ALLOWED and package_of(d) != package_of(m)
                   and package_of(d) not in ALLOWED[package_of(m)])
    assert not wrong, "\n".join(wrong)


def test_every_package_says_what_it_owns_and_may_import() -> None:
    for package in ALLOWED:
        init = ROOT / package.replace(".", "/") / "__init__.py"
        doc = ast.get_docstring(ast.parse(init.read_text())) or ""
        assert "May import" in doc or package == "bridge", f"{init}: its docstring says what it may import"
        assert len(doc.split()) >= 15, f"{init}: its docstring says what it owns"


def test_no_module_is_too_long_to_read() -> None:
    long = {str(p.relative_to(ROOT)): n for p in python_modules().values()
            if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not long, long


def test_no_c_file_calls_back_into_one_that_calls_it() -> None:
    """The C estimator's files call down (measurement models into the EKF core), never
    round a cycle: each function's defining file against the files that call it."""
    sources = sorted((ROOT / "estimator_c" / "src").glob("*.c"))
    defined = {}
    for src in sources:
        for name in re.findall(r"^[A-Za-z_][\w \*]*?\b(\w+)\([^;{]*\)\s*\{", src.read_text(), re.M):
            defined[name] = src.name
    calls = {src.name: set() for src in sources}
    for src in sources:
        text = src.read_text()
        for name, home in defined.items():
            if home != src.name and re.search(rf"\b{name}\s*\(", text):
                calls[src.name].add(home)
    try:
        tuple(TopologicalSorter(calls).static_order())
    except CycleError as exc:
        pytest.fail(f"C call cycle between files: {' -> '.join(exc.args[1])}")


def test_the_command_line_starts_without_the_heavy_libraries() -> None:
    code = ("import sys, rig.cli; rig.cli.build_parser(); "
            f"print(','.join(m for m in {HEAVY!r} if m in sys.modules))")
    loaded = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert loaded.stdout.strip() == "", f"`rig --help` imports {loaded.stdout.strip()}"
