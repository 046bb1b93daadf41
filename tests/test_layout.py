"""The house's one-way layers, checked on the source: no import cycles between gof_warp modules, and library
code imports no command-line module (the stability suite's bad-input harness runs the CLIs on purpose)."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLI_MODULES = {"gof_warp.train", "gof_warp.bench", "gof_warp.evaluate", "gof_warp.inspect", "gof_warp.synthetic.__main__"}
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
