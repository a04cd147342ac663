"""The package layout's rules (README "Layout"), checked on the source with ``ast``.

- Imports point down only: data model <- io <- usd <- render <- shadows <- relight <- pipeline <- farm <- cli;
  evaluation/ and demo/ use anything below pipeline/ (evaluation may also use demo/ and the option types in
  ``usd_gs.pipeline.options``). Modules of one subpackage may import each other.
- No import cycle between modules (imports inside functions included).
- ``numba_kernels`` imports nothing from ``usd_gs``, and no test-only package at module level.
- ``import usd_gs`` (and every subpackage) imports no heavy optional package.
- Every lazily re-exported name of a subpackage resolves.
"""

from __future__ import annotations

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA_MODEL = 0
#: rank of each top-level part of usd_gs; an import must go to a strictly lower rank (or stay in its part)
RANKS = {"": DATA_MODEL, "io": 1, "usd": 2, "render": 3, "shadows": 4, "relight": 5, "pipeline": 6,
         "demo": 7, "evaluation": 8, "farm": 9, "cli": 10}
#: (importing part or module, imported module) allowed against the ranks: the package root registers the
#: role schema plugin on import; evaluation reads the main job's option types
EXCEPTIONS = {("usd_gs", "usd_gs.usd.plugin_path"), ("evaluation", "usd_gs.pipeline.options")}
SUBPACKAGES = [k for k in RANKS if k]
TEST_ONLY = {"mpmath", "scipy", "hypothesis", "pytest"}
HEAVY_OPTIONAL = {"scipy", "matplotlib", "trimesh", "embreex", "ot", "distributed", "dask", "numba", "tqdm"}


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_of(path: Path) -> list[tuple[str, bool]]:
    """(imported module, at module level) for every import statement of ``path``; ``from X import
    name`` counts as an import of ``X.name`` when that is a module of this repository."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    here = module_name(path)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0]
    out = []

    def visit(node, top):
        for ch in ast.iter_child_nodes(node):
            if isinstance(ch, ast.Import):
                out.extend((a.name, top) for a in ch.names)
            elif isinstance(ch, ast.ImportFrom):
                base = ch.module or ""
                if ch.level:
                    anchor = package.split(".")[: len(package.split(".")) - ch.level + 1]
                    base = ".".join(anchor + ([base] if base else []))
                for a in ch.names:
                    sub = f"{base}.{a.name}"
                    out.append((sub if _is_module(sub) else base, top))
            elif isinstance(ch, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                visit(ch, False)
            else:
                visit(ch, top)

    visit(tree, True)
    return out


def _is_module(name: str) -> bool:
    p = ROOT.joinpath(*name.split("."))
    return p.with_suffix(".py").is_file() or (p / "__init__.py").is_file()


def _part(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in RANKS else ""


def _sources(package: str) -> list[Path]:
    return sorted(p for p in (ROOT / package).rglob("*.py") if "__pycache__" not in p.parts)


def test_imports_point_down_only():
    bad = []
    for path in _sources("usd_gs"):
        src = module_name(path)
        for target, _ in imports_of(path):
            if not target.startswith("usd_gs.") or target.startswith("usd_gs.schemas"):
                continue
            a, b = _part(src), _part(target)
            if a == b or RANKS[b] < RANKS[a] or (a, target) in EXCEPTIONS or (src, target) in EXCEPTIONS:
                continue
            bad.append(f"{src} -> {target}")
    assert not bad, "upward or sideways imports across the layer rule:\n" + "\n".join(bad)


def test_layer_rule_catches_an_upward_import(tmp_path):
    # the checker itself: an io module importing the pipeline is refused
    assert RANKS[_part("usd_gs.pipeline.shot")] > RANKS[_part("usd_gs.io.ply")]
    assert _part("usd_gs.gaussians") == "" and _part("usd_gs.cli") == "cli"


def _graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for package in ("usd_gs", "numba_kernels"):
        for path in _sources(package):
            src = module_name(path)
            deps = graph.setdefault(src, set())
            for target, _ in imports_of(path):
                t = target
                while t and t not in graph and not _is_module(t):
                    t = t.rpartition(".")[0]
                if t and t != src and t.split(".")[0] in ("usd_gs", "numba_kernels"):
                    deps.add(t)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A cycle of ``graph`` as a list of nodes (first == last), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def dfs(u):
        state[u] = 1
        stack.append(u)
        for v in sorted(graph.get(u, ())):
            if state.get(v) == 1:
                return stack[stack.index(v):] + [v]
            if v not in state:
                c = dfs(v)
                if c:
                    return c
        stack.pop()
        state[u] = 2
        return None

    for u in sorted(graph):
        if u not in state:
            c = dfs(u)
            if c:
                return c
    return None


def test_find_cycle_finds_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_no_import_cycle():
    cycle = find_cycle(_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_numba_kernels_import_nothing_from_usd_gs_nor_test_packages_at_module_level():
    bad = []
    for path in _sources("numba_kernels"):
        for target, top in imports_of(path):
            root = target.split(".")[0]
            if root == "usd_gs" or (top and root in TEST_ONLY):
                bad.append(f"{module_name(path)} -> {target}{' (module level)' if top else ''}")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("module", ["usd_gs", "usd_gs.cli"] + [f"usd_gs.{p}" for p in SUBPACKAGES])
def test_importing_a_package_imports_no_heavy_optional_package(module):
    code = (f"import sys, {module}; heavy = {sorted(HEAVY_OPTIONAL)!r}; "
            "print(' '.join(sorted(m for m in heavy if m in sys.modules)))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "", f"import {module} imported {r.stdout.strip()}"


@pytest.mark.parametrize("package", SUBPACKAGES[:-1])  # cli's __init__ is the command line, not a re-export
def test_every_reexported_name_resolves(package):
    mod = importlib.import_module(f"usd_gs.{package}")
    assert mod.__all__, package
    for name in mod.__all__:
        assert getattr(mod, name) is not None, f"usd_gs.{package}.{name}"
