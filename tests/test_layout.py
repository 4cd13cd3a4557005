"""The package layout's promises (issue 17): a click-free library, one set of training options for
`train` and `build`, and `bcfpipe scan` reporting exactly the texture sets that `bcfpipe build` trains."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

from bcfpipe.builder import BuildError, plan
from bcfpipe.cli import main
from bcfpipe.cli.build import build as build_cmd
from bcfpipe.config import TrainingOptions
from bcfpipe.cli.train import train_cmd


def test_library_does_not_import_click():
    code = ("import bcfpipe.builder, bcfpipe.scan, bcfpipe.train, bcfpipe.verify, bcfpipe.formats, sys; "
            "import bcfpipe.bench.run, bcfpipe.bench.report, bcfpipe.bench.decode_cost, bcfpipe.fit.rate; "
            "import bcfpipe.render.frames, bcfpipe.render.compare; "
            "assert 'click' not in sys.modules, 'click imported'")
    subprocess.run([sys.executable, "-c", code], check=True)


def _options(cmd: click.Command) -> dict[str, click.Option]:
    return {p.name: p for p in cmd.params if isinstance(p, click.Option)}


def test_train_and_build_take_the_same_training_options():
    """The options record and --help agree: every field of config.TrainingOptions is one click
    option of the same name on `train`, `plan` and `build`, with the record's default."""
    from dataclasses import MISSING, fields

    from bcfpipe.cli.plan import plan_cmd

    names = [f.name for f in fields(TrainingOptions)]
    train, build = _options(train_cmd), _options(build_cmd)
    ctx = click.Context(train_cmd)
    for f in fields(TrainingOptions):
        assert f.default is not MISSING and train[f.name].get_default(ctx) == f.default, f.name
    for cmd in (train, build, _options(plan_cmd)):
        assert set(names) <= set(cmd)
    for name in names:
        a, b = train[name], build[name]
        assert (a.opts, a.default, a.is_flag, str(a.type), a.help) == (b.opts, b.default, b.is_flag, str(b.type), b.help)
    help_of = {c: CliRunner().invoke(main, [c, "--help"]).output for c in ("train", "build")}
    for name in names:
        for opt in train[name].opts:
            assert opt in help_of["train"] and opt in help_of["build"], opt
    # no other option of either command sets something a training depends on
    only_train = set(train) - set(names)
    only_build = set(build) - set(names)
    assert only_train == {"output", "resolution", "wrap", "force", "as_json"}
    # --texel-density and --no-coverage read the scene's meshes (train's --resolution is the first's counterpart)
    # --shard, --executor and --ray-address choose which jobs run and where, not how they train;
    # --material which materials are built; -v how much --verify prints
    assert only_build == {"out", "variants", "all_materials", "materials", "jobs", "as_json", "force",
                          "run_verify_after", "verbose", "cache_dir", "no_cache", "depfile", "depfile_target",
                          "texel_density", "no_coverage", "shard", "executor_name", "ray_address"}


def _scenes(root):
    return sorted(p for p in root.rglob("*") if p.suffix in (".usd", ".usda", ".usdc", ".usdz"))


def test_scan_reports_the_texture_sets_that_build_trains(shared_scenes):
    """On every USD file in ../shared/scenes: `scan --json` texture sets == the planned jobs, with
    the same materials (no training; plan reads and hashes the textures)."""
    runner = CliRunner()
    compared = 0
    for scene in _scenes(shared_scenes):
        r = runner.invoke(main, ["scan", "--json", str(scene)])
        try:
            bp = plan(scene, TrainingOptions(device="cpu"))
        except BuildError:
            assert r.exit_code == 2, (scene, r.output)
            continue
        assert r.exit_code == 0, (scene, r.output)
        sets = json.loads(r.output)["texture_sets"]
        assert [(s["name"], s["materials"]) for s in sets] == [(j.name, list(j.materials)) for j in bp.jobs], scene
        modelled = {m.path for m in bp.materials if m.job}
        assert modelled == {p for s in sets for p in s["materials"]}, scene
        compared += 1
    assert compared >= 10


REPO = Path(__file__).resolve().parents[1]
BASE_IMPORTS = {"config": {"errors", "formats"}, "errors": set(), "bc6h": {"bptc", "errors", "pooltrace"},
                "bc7": {"bptc", "errors", "process_env"}, "bptc": set(),
                "formats": {"bc6h", "bc7", "errors", "process_env", "resources"}, "resources": {"errors"}, "extras": {"errors"},
                "pooltrace": set(), "process_env": set()}


def _bcfpipe_imports(path: Path, module: str):
    """(line, imported module) for every import of bcfpipe in a file, relative ones resolved."""
    import ast

    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                package = module.split(".")[: -1 if path.name != "__init__.py" else None]
                base = package[: len(package) - node.level + 1]
                names = [".".join(base + ([node.module] if node.module else []))]
            else:
                names = [node.module or ""]
        else:
            continue
        yield from ((node.lineno, n) for n in names if n == "bcfpipe" or n.startswith("bcfpipe."))


def test_imports_point_down_the_flow():
    """docs/architecture.md's order, over every module: a package imports the base and the
    packages before it in the flow, never one after it."""
    doc = (REPO / "docs" / "architecture.md").read_text()
    (line,) = [ln for ln in doc.splitlines() if ln.strip().startswith("flow: ")]
    flow = line.split(":", 1)[1].split()
    package = REPO / "bcfpipe"
    assert {p.name for p in package.iterdir() if p.is_dir() and (p / "__init__.py").exists()} == \
        set(flow) | {"bc6h", "bc7", "formats"}, "every subpackage has its place in the documented flow"
    wrong = []
    for path in sorted(package.rglob("*.py")):
        rel = path.relative_to(REPO).with_suffix("")
        module = ".".join(rel.parts)
        me = rel.parts[1]
        if me in ("__init__", "__main__"):  # the package's entry points sit above the flow
            continue
        for lineno, name in _bcfpipe_imports(path, module):
            other = name.split(".")[1] if "." in name else "__init__"
            if other in (me, "__init__", "__main__"):
                continue
            if me in BASE_IMPORTS:
                ok = other in BASE_IMPORTS[me]
            elif other in BASE_IMPORTS:
                ok = True
            else:
                ok = me in flow and other in flow and flow.index(other) < flow.index(me)
            if not ok:
                wrong.append(f"{path.relative_to(REPO)}:{lineno}: {me} imports {name}")
    assert not wrong, "\n".join(wrong)


def _module_graph(*packages: str) -> dict[str, set[str]]:
    """module -> the modules of `packages` it imports, read from the source (every import,
    module-level and inside functions; `from pkg import mod` counts as importing mod)."""
    modules = {}
    for name in packages:
        for path in sorted((REPO / "bcfpipe" / name.replace(".", "/")).glob("*.py")):
            dotted = f"bcfpipe.{name}" + ("" if path.stem == "__init__" else f".{path.stem}")
            modules[dotted] = path
    graph = {}
    for dotted, path in modules.items():
        module = dotted if path.stem != "__init__" else dotted + ".__init__"
        edges = set()
        for _, imported in _bcfpipe_imports(path, module):
            edges.add(imported)
        import ast

        for node in ast.walk(ast.parse(path.read_text())):  # `from bcfpipe.scan import content`
            if isinstance(node, ast.ImportFrom) and not node.level and node.module in modules:
                edges.update(f"{node.module}.{a.name}" for a in node.names)
        graph[dotted] = {e for e in edges if e in modules and e != dotted}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles of `graph`: each group of modules that reach one another (a strongly
    connected component of more than one module), sorted."""
    def reach(start):
        seen, todo = set(), [start]
        while todo:
            for nxt in graph[todo.pop()] - seen:
                seen.add(nxt)
                todo.append(nxt)
        return seen

    reaches = {m: reach(m) for m in graph}
    groups = {tuple(sorted(n for n in reaches[m] if m in reaches[n])) for m in graph if m in reaches[m]}
    return sorted(list(g) for g in groups)


def test_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": {"f"}, "f": {"e"}}) == [["a", "b", "c"],
                                                                                               ["e", "f"]]
    assert _cycles({"a": {"b", "c"}, "b": {"c"}, "c": set()}) == []


def _packages() -> list[str]:
    """Every package under bcfpipe/, dotted below it (``train.fused``)."""
    root = REPO / "bcfpipe"
    return sorted(".".join(p.parent.relative_to(root).parts) for p in root.rglob("__init__.py") if p.parent != root)


def test_no_package_has_an_import_cycle():
    """Within every package, modules import each other one way only (issues 51, 59): a shared piece
    sits in a module below both, so each module can be read, tested and moved on its own. Every
    import counts, inside functions and under TYPE_CHECKING too."""
    assert {"scan", "layout", "builder", "train.fused"} <= set(_packages())
    found = []
    for package in _packages():
        graph = _module_graph(package)
        found += _cycles(graph)
    graph = _module_graph("scan", "model")
    assert graph["bcfpipe.scan.requirements"], "the graph sees imports"
    assert not found, "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


#: the size limits issue 51 set: a function in these packages reads on one screen
SHORT_PACKAGES, MAX_LINES, MAX_PARAMETERS = ("layout", "builder", "cli"), 60, 8


def _is_click_command(fn) -> bool:
    """Decorated by click (its parameters are the command's options, one per flag)."""
    import ast

    def name(d):
        d = d.func if isinstance(d, ast.Call) else d
        return d.attr if isinstance(d, ast.Attribute) else getattr(d, "id", "")
    return any(name(d) in ("command", "option", "argument", "pass_context") or name(d).endswith("_options")
               for d in fn.decorator_list)


def _functions():
    """(module path, function node, lines, parameters) for every function under bcfpipe/."""
    import ast

    for path in sorted((REPO / "bcfpipe").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                a = node.args
                params = [*a.posonlyargs, *a.args, *a.kwonlyargs, *filter(None, (a.vararg, a.kwarg))]
                n = len([p for p in params if p.arg not in ("self", "cls")])
                yield path.relative_to(REPO / "bcfpipe"), node, node.end_lineno - node.lineno + 1, n


def test_functions_stay_short_and_take_few_parameters():
    """Every function in layout/, builder/ and cli/ is at most 60 lines; no function outside
    train/fused/ (the kernels' argument lists) and the click commands takes more than 8
    parameters: more travels as a record (issue 51)."""
    long = [f"{p}:{fn.lineno} {fn.name} ({n} lines)" for p, fn, n, _ in _functions()
            if p.parts[0] in SHORT_PACKAGES and n > MAX_LINES]
    wide = [f"{p}:{fn.lineno} {fn.name} ({k} parameters)" for p, fn, _, k in _functions()
            if k > MAX_PARAMETERS and p.parts[:2] != ("train", "fused") and not _is_click_command(fn)]
    assert not long and not wide, "\n".join(long + wide)
