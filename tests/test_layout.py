"""The house's one-way layers, checked on the source: no import cycles between gof_warp modules, library
code imports no command-line module (the stability suite's bad-input harness runs the CLIs on purpose), the
kernels import neither torch nor gof_warp, and ``docs/architecture.md`` names every module that exists (and
none that does not), so the design note cannot drift from the tree."""

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLI_MODULES = {"gof_warp.train", "gof_warp.bench", "gof_warp.evaluate", "gof_warp.inspect", "gof_warp.view", "gof_warp.extract",
               "gof_warp.synthetic.__main__"}
RUNS_CLIS = {"gof_warp.stability_inputs"}  # exercises the CLIs in-process: that is its job


def _graph() -> dict[str, set[str]]:
    mods = {}
    for p in (ROOT / "gof_warp").rglob("*.py"):
        name = ".".join(p.relative_to(ROOT).with_suffix("").parts)
        mods[name.removesuffix(".__init__")] = p
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


def test_library_code_imports_no_cli():
    graph = _graph()
    bad = [f"{m} -> {c}" for m in sorted(graph) if m not in CLI_MODULES | RUNS_CLIS
           for c in sorted(graph[m] & CLI_MODULES)]
    assert not bad, "library modules importing a CLI:\n" + "\n".join(bad)


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
    bad = {p.name: sorted(_imported_roots(p) & {"torch", "gof_warp"}) for p in sorted((ROOT / "kernels").glob("*.py"))}
    bad = {k: v for k, v in bad.items() if v}
    assert not bad, f"kernels/ must not import torch or gof_warp: {bad}"


def _tree_modules() -> set[str]:
    """Every module as ``docs/architecture.md`` names it: ``bench.py``, ``data/sfm.py``, ``kernels/tsdf.py``."""
    pkg = {p.relative_to(ROOT / "gof_warp").as_posix() for p in (ROOT / "gof_warp").rglob("*.py")}
    return pkg | {f"kernels/{p.name}" for p in (ROOT / "kernels").glob("*.py")}


def test_architecture_note_names_every_module_and_no_missing_one():
    doc = (ROOT / "docs" / "architecture.md").read_text()
    named = set(re.findall(r"`([\w/]+\.py)`", doc))
    modules = _tree_modules()
    assert {"bench.py", "data/sfm.py", "synthetic/__main__.py", "kernels/renderer.py"} <= modules  # the naming rule
    missing = sorted(modules - named)
    assert not missing, "modules not named in docs/architecture.md (add a line saying what each holds): " + ", ".join(missing)
    ours = {n for n in named if not n.startswith(("tests/", "examples/", "benchmarks/", "configs/"))}
    stale = sorted(ours - modules)
    assert not stale, "docs/architecture.md names modules that do not exist: " + ", ".join(stale)
    for cli in CLI_MODULES:  # the note lists the CLIs the import rule above protects
        assert f"`{cli.removeprefix('gof_warp.').replace('.', '/')}.py`" in doc, cli


def test_readme_layout_names_the_folders_that_exist():
    readme = (ROOT / "README.md").read_text()
    block = readme[readme.index("## Conventions and layout"):]
    block = block[block.index("```") + 3:]
    block = block[:block.index("```")]
    folders = {line.split("/")[0] for line in block.splitlines() if re.match(r"^\w+/", line)}
    assert folders, "README's layout block lists no folders"
    assert not [f for f in folders if not (ROOT / f).is_dir()], folders
    assert {"gof_warp", "kernels", "configs", "tests", "examples", "benchmarks", "docs"} <= folders
