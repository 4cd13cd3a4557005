"""Imports inside functions (issue 59): kept only where they save start-up time or break a real
dependency, each saying which on its line (``# lazy: start-up`` or ``# lazy: cycle``), and the
reason checked here against the source:

* ``start-up``: the import pulls a package in `HEAVY` (or a bcfpipe module whose module-level
  imports pull one) that the importing module does not already pull at module level;
* ``cycle``: the imported module, through its module-level imports (a package's ``__init__``
  included), already reaches the importing module, so importing it at the top would be a cycle.

An import inside a ``try`` (an optional dependency, or a failure that must stay its caller's) is
exempt. No private name (``_x``) is imported from another module, at any level.
"""
from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ROOT = REPO / "bcfpipe"
#: packages whose import costs start-up time worth deferring: 0.05 to 2 s each on this machine
#: (`python -X importtime -c "import X"`), against a few ms for a bcfpipe module of numpy code
HEAVY = {"torch", "rich", "pxr", "OpenImageIO", "onnx", "onnxruntime", "quicktex", "_quicktex", "ispc_texcomp",
         "scipy", "skimage", "flip_evaluator", "ray", "matplotlib", "numba", "texture2ddecoder", "zstandard",
         "PIL", "jsonschema", "etcpak", "OpenGL", "moderngl", "vulkan", "wgpu", "xxhash", "filelock",
         "platformdirs", "click", "torch._dynamo"}


def _name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_name(p): p for p in ROOT.rglob("*.py")}


def _targets(module: str, node: ast.Import | ast.ImportFrom) -> list[str]:
    """What ``node`` imports: dotted names, a ``from pkg import submodule``'s submodule too."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    if node.level:
        base = module.split(".")
        if MODULES[module].name != "__init__.py":
            base = base[:-1]
        name = ".".join(base[:len(base) - node.level + 1] + ([node.module] if node.module else []))
    else:
        name = node.module or ""
    return [name] + [f"{name}.{a.name}" for a in node.names if f"{name}.{a.name}" in MODULES]


def _module_level(tree: ast.Module) -> list[ast.Import | ast.ImportFrom]:
    """The imports a module runs when it is imported (not under TYPE_CHECKING, not in functions)."""
    out: list = []

    def visit(body):
        for n in body:
            if isinstance(n, (ast.Import, ast.ImportFrom)):
                out.append(n)
            elif isinstance(n, ast.If) and not (isinstance(n.test, ast.Name) and n.test.id == "TYPE_CHECKING"):
                visit(n.body)
                visit(n.orelse)
            elif isinstance(n, ast.Try):
                visit(n.body)
                for h in n.handlers:
                    visit(h.body)
                visit(n.orelse)
                visit(n.finalbody)
            elif isinstance(n, ast.ClassDef):
                visit(n.body)
    visit(tree.body)
    return out


def _heavy_of(name: str) -> set[str]:
    """The `HEAVY` packages importing ``name`` (not a bcfpipe module) pulls."""
    return ({name.split(".")[0]} & HEAVY) | ({"torch._dynamo"} if name.startswith("torch._dynamo") else set())


def _graph() -> tuple[dict, dict, dict]:
    """(module-level bcfpipe edges, heavy packages each module pulls itself, parsed trees)."""
    trees = {m: ast.parse(p.read_text()) for m, p in MODULES.items()}
    edges, heavy = {}, {}
    for m, tree in trees.items():
        e, h = set(), set()
        for node in _module_level(tree):
            for name in _targets(m, node):
                if name.split(".")[0] == "bcfpipe":
                    parts = name.split(".")
                    e |= {".".join(parts[:i]) for i in range(1, len(parts) + 1)} & MODULES.keys() - {m}
                else:
                    h |= _heavy_of(name)
        edges[m], heavy[m] = e, h
    return edges, heavy, trees


def _closure(edges: dict, start: str) -> set[str]:
    seen, todo = {start}, [start]
    while todo:
        for n in edges[todo.pop()] - seen:
            seen.add(n)
            todo.append(n)
    return seen


def _in_function_imports(trees: dict):
    """(module, import node, its enclosing statement's parent) for every import inside a function."""
    for m, tree in trees.items():
        parent = {c: p for p in ast.walk(tree) for c in ast.iter_child_nodes(p)}
        for fn in ast.walk(tree):
            if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for node in ast.walk(fn):
                    if isinstance(node, (ast.Import, ast.ImportFrom)):
                        yield m, node, parent[node]


def test_every_import_inside_a_function_says_why_and_the_reason_holds():
    edges, heavy, trees = _graph()
    reach = {m: _closure(edges, m) for m in MODULES}
    pulls = {m: set().union(*(heavy[x] for x in reach[m])) for m in MODULES}
    wrong, seen = [], set()
    for m, node, parent in _in_function_imports(trees):
        if id(node) in seen:  # a nested function's import is walked twice
            continue
        seen.add(id(node))
        where = f"{MODULES[m].relative_to(REPO)}:{node.lineno}"
        if isinstance(parent, (ast.Try, ast.ExceptHandler)):
            continue
        line = MODULES[m].read_text().splitlines()[node.lineno - 1]
        said = "start-up" if "lazy: start-up" in line else "cycle" if "lazy: cycle" in line else None
        names = _targets(m, node)
        # importing bcfpipe.a.b runs bcfpipe/a/__init__.py too
        inner = sorted({".".join(n.split(".")[:i]) for n in names for i in range(2, n.count(".") + 2)} & MODULES.keys())
        if said is None:
            wrong.append(f"{where}: an import inside a function says neither '# lazy: start-up' nor '# lazy: cycle'")
        elif said == "start-up":
            adds = set().union(*(pulls[x] for x in inner)) if inner else set().union(*(_heavy_of(n) for n in names))
            if not adds - pulls[m]:
                wrong.append(f"{where}: says start-up, but pulls nothing heavy that {m} does not already pull")
        elif not any(m in reach[x] for x in inner):
            wrong.append(f"{where}: says cycle, but {', '.join(inner) or names[0]} does not reach {m}")
    assert not wrong, "\n".join(wrong)


def test_no_private_name_is_imported_across_modules():
    bad = []
    for m, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("bcfpipe") or \
                    isinstance(node, ast.ImportFrom) and node.level:
                bad += [f"{path.relative_to(REPO)}:{node.lineno}: {a.name}" for a in node.names
                        if a.name.startswith("_") and not a.name.startswith("__")]
    assert not bad, "\n".join(bad)


def test_the_checks_see_what_they_check():
    edges, heavy, trees = _graph()
    assert "torch" in set().union(*(heavy[x] for x in _closure(edges, "bcfpipe.train.trainer")))
    assert sum(1 for _ in _in_function_imports(trees)) > 50


def test_a_classic_layout_runs_without_importing_torch(tmp_path):
    """`bcfpipe train` where classic ships without a probe (a 64² set: nothing neural fits within
    BC@R's bytes) estimates, encodes, exports and measures without importing torch (1 to 2 s of a
    20 s run at 2048², docs/benchmarks.md)."""
    import subprocess
    import sys

    import numpy as np
    from PIL import Image

    yy, xx = np.mgrid[0:64, 0:64] / 64
    Image.fromarray((np.stack([0.5 + 0.4 * np.sin(6.28 * xx), 0.5 + 0.3 * np.cos(6.28 * yy), 0.3 + 0.2 * xx], -1)
                     * 255).astype(np.uint8)).save(tmp_path / "a.png")
    Image.fromarray((np.clip(0.5 + 0.3 * np.sin(6.28 * (xx + yy)), 0, 1) * 255).astype(np.uint8)).save(tmp_path / "r.png")
    code = ("import sys\nfrom bcfpipe.cli import main\n"
            f"try:\n    main(['train', 'albedo={tmp_path / 'a.png'}:rgb', 'roughness={tmp_path / 'r.png'}:r', "
            f"'-o', '{tmp_path / 'out'}', '--quality', 'draft'])\nexcept SystemExit as e:\n    assert e.code == 0, e.code\n"
            "print('torch' in sys.modules)\n")
    p = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    assert (tmp_path / "out" / "layout.json").exists()
    assert p.stdout.strip().splitlines()[-1] == "False", "torch was imported on the classic path"
