"""Check the layout rules of docs/design.md over the package's source (a report, not a test).

1. No lanecast module is imported inside a function, except modules that load a heavy or optional
   dependency at import, directly or through other lanecast modules (torch, matplotlib, ray,
   libsumo, onnxruntime; and numpy, pyarrow, pandas, scipy and the log libraries, which a
   command's ``--help`` must not pay for), and the command modules ``cli.py`` loads lazily.
2. No import cycle among lanecast modules (module-level imports; function-level ones are listed
   apart, since they run later; imports under ``if TYPE_CHECKING:`` never run and do not count).
3. Every file over 500 lines says why at its top (a ``Size:`` paragraph in its docstring).

    python .ci/check_layout.py [--root .]     # exit status 1 when a rule is broken
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections import defaultdict
from pathlib import Path

PACKAGES = ("io_adapters", "pipeline", "models", "workflows")
HEAVY = (
    *("torch", "matplotlib", "ray", "libsumo", "traci", "sumolib", "onnxruntime", "onnx"),
    *(
        "numpy",
        "pyarrow",
        "pandas",
        "scipy",
        "mcap",
        "mcap_protobuf",
        "rosbags",
        "ruamel",
        "zstandard",
    ),
)
MAX_LINES = 500


def module_files(root: Path) -> dict[str, Path]:
    """lanecast.<package>.<...> → file, for every .py of the package folders."""
    out = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(("lanecast", *parts))] = path
    return out


def imported_names(node: ast.Import | ast.ImportFrom, modules: dict[str, Path]) -> list[str]:
    """The modules an import statement loads (lanecast modules resolved to files where possible)."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    base = node.module or ""
    names = []
    for a in node.names:
        full = f"{base}.{a.name}"
        names.append(full if full in modules else base)
    return names


def scan(
    modules: dict[str, Path],
) -> tuple[dict[str, set[str]], dict[str, set[str]], dict[str, list[tuple[int, str]]]]:
    """Per module: lanecast modules imported at module level, third-party roots imported at module
    level, and (line, module) of every import inside a function."""
    top: dict[str, set[str]] = defaultdict(set)
    third: dict[str, set[str]] = defaultdict(set)
    local: dict[str, list[tuple[int, str]]] = defaultdict(list)
    for name, path in modules.items():
        tree = ast.parse(path.read_text(), str(path))
        functions = [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]
        inside = {id(n) for f in functions for n in ast.walk(f) if n is not f}
        typing_only = [
            n for n in ast.walk(tree) if isinstance(n, ast.If) and "TYPE_CHECKING" in ast.unparse(n.test)
        ]
        never_run = {id(n) for block in typing_only for n in ast.walk(block) if n is not block}
        for node in ast.walk(tree):
            if not isinstance(node, (ast.Import, ast.ImportFrom)):
                continue
            if id(node) in never_run:
                continue
            for target in imported_names(node, modules):
                if id(node) in inside:
                    local[name].append((node.lineno, target))
                elif target.startswith("lanecast."):
                    top[name].add(target)
                else:
                    third[name].add(target.split(".")[0])
    return top, third, local


def heavy_modules(modules: dict[str, Path], top: dict[str, set[str]], third: dict[str, set[str]]) -> set[str]:
    """lanecast modules that load a heavy dependency at import, directly or through lanecast modules."""
    heavy = {m for m in modules if third[m] & set(HEAVY)}
    changed = True
    while changed:
        changed = False
        for m in modules:
            if m not in heavy and top[m] & heavy:
                heavy.add(m)
                changed = True
    return heavy


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (or a self-import): Tarjan."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
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
            if len(component) > 1 or v in graph.get(v, ()):
                out.append(sorted(component))

    sys.setrecursionlimit(10_000)
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def size_reasons(modules: dict[str, Path]) -> list[tuple[str, int, bool]]:
    """(file, lines, states a reason) of every file over MAX_LINES lines."""
    out = []
    for path in sorted(set(modules.values())):
        text = path.read_text()
        lines = text.count("\n")
        if lines > MAX_LINES:
            doc = ast.get_docstring(ast.parse(text)) or ""
            out.append((str(path), lines, "Size:" in doc))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path(__file__).resolve().parent.parent)
    root = ap.parse_args().root
    modules = module_files(root)
    top, third, local = scan(modules)
    heavy = heavy_modules(modules, top, third)
    broken = 0

    print(f"{len(modules)} lanecast modules; {len(heavy)} load a heavy dependency at import")
    print("\n1. lanecast modules imported inside a function")
    allowed = bad = 0
    for name in sorted(local):
        for line, target in local[name]:
            if not target.startswith("lanecast."):
                continue
            lazy_command = name == "lanecast.workflows.cli" and target.startswith("lanecast.workflows.")
            if target in heavy or lazy_command:
                allowed += 1
                continue
            bad += 1
            print(f"   VIOLATION {modules[name]}:{line}: {target} (loads no heavy dependency)")
    print(f"   {allowed} allowed (heavy or lazily loaded commands), {bad} violations")
    broken += bad

    print("\n2. import cycles among lanecast modules")
    module_level = cycles(top)
    every: dict[str, set[str]] = {m: set(top[m]) for m in modules}
    for name, items in local.items():
        every[name] |= {t for _, t in items if t.startswith("lanecast.")}
    with_lazy = [c for c in cycles(every) if c not in module_level]
    for c in module_level:
        print("   CYCLE (module level): " + " -> ".join(c))
    for c in with_lazy:
        print("   cycle through function-level imports only: " + " -> ".join(c))
    print(f"   {len(module_level)} module-level cycles, {len(with_lazy)} through function-level imports")
    broken += len(module_level) + len(with_lazy)

    print(f"\n3. files over {MAX_LINES} lines")
    for path, lines, reason in size_reasons(modules):
        print(f"   {'ok (Size: stated)' if reason else 'VIOLATION (no reason at top)':30s} {lines:5d} {path}")
        broken += not reason
    print(f"\n{'OK' if not broken else f'{broken} problem(s)'}")
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main())
