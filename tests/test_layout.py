"""The house's one-way layers, checked on the source.

* the subpackages follow the data flow and import only their own layer and the layers below it
  (``LAYERS``); the bench harness's bad-input runner is the one module that runs the commands;
* no import cycles between gof_warp modules; library code imports no command-line module;
* the kernels import neither torch nor gof_warp (they are embedded in other Warp programs);
* the top level of ``gof_warp/`` stays small (the public names and one thin module per command), and each
  subpackage opens with its design note;
* ``docs/architecture.md`` names every module that exists (and none that does not), so the note cannot drift.
"""

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Lowest first: a module may import its own layer and those before it.
LAYERS = ("core", "data", "synthetic", "rendering", "eval", "training", "mesh", "viz", "benchmarking", "cli")
COMMANDS = ("train", "extract", "evaluate", "bench", "view", "pictures", "inspect", "prepare")
RUNS_CLIS = {"gof_warp.benchmarking.stability_inputs"}  # exercises the CLIs in-process: that is its job
MAX_TOP_LEVEL_MODULES = 12


def _modules() -> dict[str, Path]:
    mods = {}
    for p in (ROOT / "gof_warp").rglob("*.py"):
        name = ".".join(p.relative_to(ROOT).with_suffix("").parts)
        mods[name.removesuffix(".__init__")] = p
    return mods


def _cli_modules(mods) -> set[str]:
    """The command modules: everything in ``gof_warp.cli``, the top-level thin ones, and ``__main__`` modules."""
    return {m for m in mods if m.startswith("gof_warp.cli") or m.endswith(".__main__")
            or m in {f"gof_warp.{c}" for c in COMMANDS}}


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    graph = {m: set() for m in mods}
    for m, p in mods.items():
        pkg = m if p.name == "__init__.py" else m.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
                for c in ([target] if node.module else []) + [f"{target}.{a.name}" for a in node.names]:
                    if c in mods and c != m:
                        graph[m].add(c)
    return graph


def _layer(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else None


def test_no_import_cycles():
    graph, state, cycles = _graph(), {}, []

    def visit(v, path):
        state[v] = "open"
        path.append(v)
        for w in sorted(graph[v]):
            if state.get(w) == "open":
                cycles.append(" -> ".join(path[path.index(w):] + [w]))
            elif w not in state:
                visit(w, path)
        path.pop()
        state[v] = "done"

    for v in sorted(graph):
        if v not in state:
            visit(v, [])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_layers_import_downwards_only():
    graph = _graph()
    clis = _cli_modules(graph)
    bad = []
    for m in sorted(graph):
        if m in clis | RUNS_CLIS or _layer(m) is None:
            continue
        for c in sorted(graph[m]):
            if _layer(c) is not None and LAYERS.index(_layer(c)) > LAYERS.index(_layer(m)):
                bad.append(f"{m} -> {c}")
    assert not bad, f"imports against the layers {' <- '.join(LAYERS)}:\n" + "\n".join(bad)


def test_library_code_imports_no_cli():
    graph = _graph()
    clis = _cli_modules(graph)
    assert {"gof_warp.cli.train", "gof_warp.train", "gof_warp.synthetic.__main__"} <= clis  # the naming rule
    bad = [f"{m} -> {c}" for m in sorted(graph) if m not in clis | RUNS_CLIS | {"gof_warp"}
           for c in sorted(graph[m] & clis)]
    assert not bad, "library modules importing a CLI:\n" + "\n".join(bad)


def test_top_level_is_small_and_each_subpackage_has_its_note():
    top = sorted(p.name for p in (ROOT / "gof_warp").glob("*.py"))
    assert len(top) <= MAX_TOP_LEVEL_MODULES, top
    assert set(top) <= {"__init__.py", "__main__.py", *(f"{c}.py" for c in COMMANDS)}, top
    for c in COMMANDS:  # the top-level command modules are thin: the command lives in gof_warp.cli
        assert len((ROOT / "gof_warp" / f"{c}.py").read_text().splitlines()) <= 12, c
    for pkg in sorted(p.parent for p in (ROOT / "gof_warp").glob("*/__init__.py")):
        doc = ast.get_docstring(ast.parse((pkg / "__init__.py").read_text()))
        assert doc and len(doc.split()) >= 15, f"{pkg.name}/__init__.py: a design note (what it owns) opens it"


def _imported_roots(path: Path) -> set[str]:
    """Top-level names of the absolute imports in ``path`` (``import torch`` / ``from torch.x import y`` → torch)."""
    roots = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            roots |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and not node.level:
            roots.add(node.module.split(".")[0])
    return roots


def test_kernels_are_pure_warp():
    bad = {p.name: sorted(_imported_roots(p) & {"torch", "gof_warp"}) for p in sorted((ROOT / "kernels").rglob("*.py"))}
    bad = {k: v for k, v in bad.items() if v}
    assert not bad, f"kernels/ must not import torch or gof_warp: {bad}"


def _tree_modules() -> set[str]:
    """Every module as ``docs/architecture.md`` names it: ``cli/bench.py``, ``data/sfm.py``, ``kernels/tsdf.py``."""
    pkg = {p.relative_to(ROOT / "gof_warp").as_posix() for p in (ROOT / "gof_warp").rglob("*.py")}
    return pkg | {f"kernels/{p.relative_to(ROOT / 'kernels').as_posix()}" for p in (ROOT / "kernels").rglob("*.py")}


def test_architecture_note_names_every_module_and_no_missing_one():
    doc = (ROOT / "docs" / "architecture.md").read_text()
    named = set(re.findall(r"`([\w/]+\.py)`", doc))
    modules = _tree_modules()
    assert {"cli/bench.py", "data/sfm.py", "synthetic/__main__.py", "kernels/renderer.py"} <= modules  # the naming rule
    missing = sorted(modules - named)
    assert not missing, "modules not named in docs/architecture.md (add a line saying what each holds): " + ", ".join(missing)
    ours = {n for n in named if not n.startswith(("tests/", "examples/", "benchmarks/", "configs/"))}
    stale = sorted(ours - modules)
    assert not stale, "docs/architecture.md names modules that do not exist: " + ", ".join(stale)


def test_readme_layout_names_the_folders_that_exist():
    readme = (ROOT / "README.md").read_text()
    block = readme[readme.index("## Conventions and layout"):]
    block = block[block.index("```") + 3:]
    block = block[:block.index("```")]
    folders = {line.split("/")[0] for line in block.splitlines() if re.match(r"^\w+/", line)}
    assert folders, "README's layout block lists no folders"
    assert not [f for f in folders if not (ROOT / f).is_dir()], folders
    assert {"gof_warp", "kernels", "configs", "tests", "examples", "benchmarks", "docs"} <= folders


def test_old_module_paths_are_the_new_modules():
    """The first, one-floor layout's import paths still work, and give the moved module itself (not a copy)."""
    import importlib

    import gof_warp

    for old, new in gof_warp._MOVED.items():
        assert importlib.import_module(f"gof_warp.{old}") is importlib.import_module(f"gof_warp.{new}"), old
    from gof_warp.render import render as old_render
    from gof_warp.rendering.render import render as new_render
    assert old_render is new_render
