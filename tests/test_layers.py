"""The package's shape (docs/layout.md): layers that import only downwards, no import cycle
(imports inside functions included), no private name imported across modules, no module much
past 500 lines. Read from the source with ``ast``: nothing is imported to check it."""
import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "bdipole_cl"

#: layer of each module, by its dotted path below bdipole_cl (the longest prefix decides);
#: a module may import its own layer and those below
LAYERS = {
    "errors": 0, "caches": 0, "version": 0, "signals": 0, "vocabulary": 0, "durable": 0,
    "physics": 1,
    "device": 2,
    "methods": 3,
    "ops": 4,
    "io": 5,
    "jobs": 6,                                # job records, the one runner, batches, scenes
    "apps": 7, "__main__": 7, "scene": 7,     # bdipole_cl/scene.py: the scene API facade
    "dask": 7, "cluster": 7,                  # bdipole_cl/dask.py, cluster.py: clusters
    "": 8,                 # bdipole_cl/__init__.py: the public facade re-exports every layer
}
#: a module this long is a sign of two concerns in one file
MAX_LINES = 500


def module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


MODULES = {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def layer_of(module: str) -> int:
    rest = module[len("bdipole_cl"):].lstrip(".")
    key = max((k for k in LAYERS if rest == k or rest.startswith(k + ".") or k == ""),
              key=len)
    return LAYERS[key]


def resolve(module: str, node: ast.ImportFrom) -> str:
    """The absolute module a ``from ... import`` names (relative levels resolved)."""
    if node.level == 0:
        return node.module or ""
    is_package = MODULES[module].name == "__init__.py"
    base = module.split(".")
    base = base if is_package else base[:-1]
    base = base[:len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imports(module: str):
    """(imported module, imported names) for every import of ``module``, at any depth."""
    tree = ast.parse(MODULES[module].read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, ()
        elif isinstance(node, ast.ImportFrom):
            target = resolve(module, node)
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                if sub in MODULES:                 # ``from package import module``
                    yield sub, ()
                else:
                    yield target, (alias.name,)


def graph():
    """{module: {imported bdipole_cl module: names}} over the package's own modules."""
    edges = {}
    for module in MODULES:
        out = edges.setdefault(module, {})
        for target, names in imports(module):
            if target in MODULES and target != module:
                out.setdefault(target, set()).update(names)
    return edges


def test_the_package_is_found():
    # the checks below mean nothing on an empty walk
    assert {"bdipole_cl.ops.invert", "bdipole_cl.device.runtime", "bdipole_cl.jobs.batch",
            "bdipole_cl.apps.cli", "bdipole_cl.physics.reference"} <= set(MODULES)
    assert sum(len(v) for v in graph().values()) > 50


def test_no_import_cycle():
    edges = graph()
    state, stack, cycles = {}, [], []

    def visit(m):
        state[m] = "open"
        stack.append(m)
        for t in edges[m]:
            if state.get(t) == "open":
                cycles.append(stack[stack.index(t):] + [t])
            elif t not in state:
                visit(t)
        stack.pop()
        state[m] = "done"

    for m in edges:
        if m not in state:
            visit(m)
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_imports_point_down_the_layers():
    upward = [f"{m} (layer {layer_of(m)}) imports {t} (layer {layer_of(t)})"
              for m, targets in graph().items() for t in targets
              if layer_of(t) > layer_of(m)]
    assert not upward, "\n".join(upward)


def test_no_private_name_crosses_a_module():
    private = [f"{m} imports {name} from {t}" for m, targets in graph().items()
               for t, names in targets.items() for name in names
               if name.startswith("_") and not name.startswith("__")]
    assert not private, "\n".join(private)


@pytest.mark.parametrize("module", sorted(MODULES))
def test_module_size(module):
    lines = len(MODULES[module].read_text().splitlines())
    assert lines <= MAX_LINES, f"{module}: {lines} lines (at most {MAX_LINES})"


def test_the_checks_catch_what_they_check(tmp_path, monkeypatch):
    # an upward import, a cycle and a private import, planted in a copy of two modules' text
    fake = {"bdipole_cl.physics.tables": "from ..ops import invert\nfrom ..caches import _x\n",
            "bdipole_cl.ops.invert": "from ..physics import tables\n"}
    paths = {}
    for name, text in fake.items():
        p = tmp_path / (name.replace(".", "_") + ".py")
        p.write_text(text)
        paths[name] = p
    monkeypatch.setitem(MODULES, "bdipole_cl.physics.tables", paths["bdipole_cl.physics.tables"])
    monkeypatch.setitem(MODULES, "bdipole_cl.ops.invert", paths["bdipole_cl.ops.invert"])
    for check in (test_no_import_cycle, test_imports_point_down_the_layers,
                  test_no_private_name_crosses_a_module):
        with pytest.raises(AssertionError):
            check()
