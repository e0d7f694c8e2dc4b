"""Conventions stated in words, checked against the code: the README's rotation convention, and
docs/architecture.md's layout (no import circles, no in-function import dodging one, arrows only
pointing down)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from egovid.core.rotations import euler_from_matrix, matrix_from_euler

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
SRC = REPO / "src"
ARCHITECTURE = REPO / "docs" / "architecture.md"


def _readme() -> str:
    return " ".join(README.read_text(encoding="utf-8").split())


def test_readme_formula_and_scipy_call_are_the_code():
    text = _readme()
    assert "camera-to-world" in text
    m = re.search(r"`R = R(\w)\((\w+)\) · R(\w)\((\w+)\) · R(\w)\((\w+)\)`", text)
    assert m, "the README must state R = Rα(angle) · Rβ(angle) · Rγ(angle)"
    axes, names = m.group(1, 3, 5), m.group(2, 4, 6)
    assert names == ("yaw", "pitch", "roll")
    seq = re.search(r'from_euler\("([XYZ]{3})", \[yaw, pitch, roll\], degrees=True\)', text)
    assert seq and seq.group(1) == "".join(a.upper() for a in axes)
    rng = np.random.default_rng(0)
    angles = rng.uniform([-180, -89, -180], [180, 89, 180], (500, 3))
    stated = Rotation.from_euler(seq.group(1), angles, degrees=True).as_matrix()
    np.testing.assert_allclose(matrix_from_euler(*angles.T), stated, atol=1e-12)
    np.testing.assert_allclose(euler_from_matrix(stated), angles, atol=1e-9)


def test_readme_signs_are_the_code():
    text = _readme()
    assert "positive yaw turns the view right, positive pitch up, positive roll turns the camera clockwise" in text
    forward, right = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    # x right, y down, z forward: the view direction in world coordinates is R @ forward.
    assert (matrix_from_euler(10, 0, 0) @ forward)[0] > 0  # yaw: view goes right (+x)
    assert (matrix_from_euler(0, 10, 0) @ forward)[1] < 0  # pitch: view goes up (-y)
    # roll: the camera's right axis tips down (+y): clockwise for someone looking along +z.
    assert (matrix_from_euler(0, 0, 10) @ right)[1] > 0
    # The thesis' world-to-camera form: Rᵀ = Rz(-roll) Rx(-pitch) Ry(-yaw).
    y, p, r = 20.0, -7.0, 3.0
    Rt = Rotation.from_euler("ZXY", [-r, -p, -y], degrees=True).as_matrix()
    np.testing.assert_allclose(matrix_from_euler(y, p, r).T, Rt, atol=1e-12)


# -- the layout (docs/architecture.md) -------------------------------------------------------------


def _module_names(src: Path) -> dict[str, Path]:
    """Every module of ``src/egovid`` by its dotted name (a package by its ``__init__.py``)."""
    out = {}
    for path in (src / "egovid").rglob("*.py"):
        parts = list(path.relative_to(src).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _imports(path: Path, name: str, modules: dict[str, Path]) -> list[tuple[str, str, int]]:
    """(egovid module imported, where: ``module`` | ``function`` | ``typecheck``, line) for every
    import statement of the file; ``from P import N`` names the module P.N where there is one."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: list[tuple[str, str, int]] = []

    def owner(dotted: str) -> str | None:
        while dotted and dotted not in modules:
            dotted = dotted.rpartition(".")[0]
        return dotted or None

    def visit(node: ast.AST, where: str) -> None:
        for child in ast.iter_child_nodes(node):
            here = "function" if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda) else where
            targets: list[str] = []
            if isinstance(child, ast.Import):
                targets = [a.name for a in child.names]
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    up = package
                    for _ in range(child.level - 1):
                        up = up.rpartition(".")[0]
                    base = f"{up}.{base}" if base else up
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in child.names]
            elif isinstance(child, ast.If) and where == "module" and "TYPE_CHECKING" in ast.unparse(child.test):
                for stmt in child.body:
                    visit(ast.Module(body=[stmt], type_ignores=[]), "typecheck")
                for stmt in child.orelse:
                    visit(ast.Module(body=[stmt], type_ignores=[]), where)
                continue
            for t in targets:
                if (t == "egovid" or t.startswith("egovid.")) and (mod := owner(t)):
                    found.append((mod, here, child.lineno))
            visit(child, here)

    visit(ast.parse(path.read_text(encoding="utf-8"), str(path)), "module")
    return found


def _import_graph(src: Path = SRC) -> tuple[dict[str, set[str]], list[tuple[str, str, str, int]]]:
    """The module-level import graph of egovid (imports that run when a module is imported: not
    those under ``if TYPE_CHECKING``) and every import of an egovid module as
    (importer, imported, where, line)."""
    modules = _module_names(src)
    graph: dict[str, set[str]] = {m: set() for m in modules}
    every = []
    for name, path in modules.items():
        for target, where, line in _imports(path, name, modules):
            every.append((name, target, where, line))
            if where == "module" and target != name:
                graph[name].add(target)
    return graph, every


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import circle of ``graph`` (its modules in order, the first repeated at the end), or None."""
    state: dict[str, int] = {}  # 1 = on the current path, 2 = done
    path: list[str] = []

    def dfs(m: str) -> list[str] | None:
        state[m] = 1
        path.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                return [*path[path.index(n) :], n]
            if n not in state and (found := dfs(n)):
                return found
        path.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (found := dfs(m)):
            return found
    return None


def _layers() -> dict[str, set[str]]:
    """What each top-level package may import, read from docs/architecture.md's layout block:
    ``imports dashcam/, core/`` lists them, ``nothing imports cli/`` marks the top (it may import
    everything), ``imports nothing above it`` the bottom."""
    text = ARCHITECTURE.read_text(encoding="utf-8")
    block = text.split("```", 2)[1]
    rows = re.findall(r"^  (\w+)/ .*?  ((?:nothing )?imports .*)$", block, re.M)
    assert rows, "docs/architecture.md must open with the layout block"
    names = [n for n, _ in rows]
    allowed: dict[str, set[str]] = {}
    for name, says in rows:
        if says.startswith("nothing imports"):
            allowed[name] = set(names)
        elif says == "imports nothing above it":
            allowed[name] = set()
        else:
            allowed[name] = set(re.findall(r"(\w+)/", says))
    return allowed


def _top(module: str) -> str:
    return module.split(".")[1] if "." in module else ""


def test_no_import_circles():
    graph, _ = _import_graph()
    assert "egovid.core.errors" in graph and graph["egovid.dashcam.ingest.piece"], "the graph reads the source"
    assert _cycle(graph) is None, f"import circle: {' -> '.join(_cycle(graph) or [])}"


def test_cycle_finder_finds_a_planted_circle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycle(graph) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None


def test_no_in_function_import_of_egovid_outside_the_cli():
    """In-function imports are kept for heavy optional dependencies and the CLI's fast start, never
    to hold an import circle apart."""
    _, every = _import_graph()
    inside = [
        f"{m}:{line} imports {t}"
        for m, t, where, line in every
        if where == "function" and _top(m) != "cli" and m != "egovid.__main__"
    ]
    assert not inside, inside


def test_imports_point_down_the_layers_of_docs_architecture():
    allowed = _layers()
    assert set(allowed) == {"cli", "serve", "fpv", "dashcam", "voeval", "synth", "core"}
    packages = {p.name for p in (SRC / "egovid").iterdir() if (p / "__init__.py").exists()}
    assert packages - set(allowed) == {"data"}, "every package of src/egovid has its layer in the doc (data: files)"
    _, every = _import_graph()
    wrong = []
    for m, t, _where, line in every:
        a, b = _top(m), _top(t)
        if a == b or b in ("", "data") or (m == "egovid.__main__" and b == "cli"):
            continue
        if b not in allowed.get(a, set()):
            wrong.append(f"{m}:{line} imports {t}")
    assert not wrong, wrong
