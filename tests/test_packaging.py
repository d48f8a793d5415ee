"""A non-editable install (a built wheel) carries the kernels and data and works on its own."""
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_wheel_ships_kernels_and_runs_outside_the_source_tree(tmp_path):
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(wheels),
                    str(ROOT)], check=True)
    (wheel,) = wheels.glob("bdipole_cl-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    kernels = {p.name for p in (ROOT / "kernels").iterdir()}
    for k in kernels:
        assert f"bdipole_cl/kernels/{k}" in names, k
    assert "bdipole_cl/data/choice.json" in names
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target",
                    str(target), str(wheel)], check=True)
    code = ("import bdipole_cl, bdipole_cl.device.programs as d; "
            "assert str(d.kernel_dir()).startswith(%r), d.kernel_dir(); "
            "a = bdipole_cl.invert_albedo([0.5], 1.4, 'auto'); "
            "print(bdipole_cl.__file__, float(a[0]))" % str(target))
    env = dict(os.environ, PYTHONPATH=str(target))
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, check=True,
                         capture_output=True, text=True).stdout
    assert str(target) in out and 0.9 < float(out.split()[-1]) < 1.0


#: modules the library imports that no extra installs, and why
BESIDE_EXTRAS = {"bpy": "Blender's bpy pins numpy<2: installed beside with --no-deps "
                        "(docs/conventions.md)"}


def _requirement_names(requirements):
    """Distribution names (normalised) of PEP 508 strings, markers and extras dropped."""
    import re
    return {re.split(r"[\s<>=!~;\[]", r.strip(), maxsplit=1)[0].lower().replace("_", "-")
            for r in requirements}


def _module_name(path):
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path, name):
    """(absolute module, at module level?) of each import in one source file, except those
    under ``try: ... except ImportError`` (the file has a way without them)."""
    import ast
    tree = ast.parse(path.read_text())
    top_level = {id(n) for n in tree.body}
    guarded = {id(n) for t in ast.walk(tree) if isinstance(t, ast.Try)
               and any("ImportError" in ast.unparse(h.type or ast.Name("")) for h in t.handlers)
               for b in t.body for n in ast.walk(b)}
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                base = ".".join(up + ([base] if base else []))
            targets = [base] + [f"{base}.{a.name}" for a in node.names]
        else:
            continue
        if id(node) in guarded:
            continue
        for target in targets:
            yield target, id(node) in top_level


def _third_party_imports():
    """{top-level module: imported whenever bdipole_cl or its CLI is?} for every import
    under bdipole_cl/ of neither the standard library nor the package itself: a module the
    package or the CLI imports at module level, transitively, is always loaded; its own
    module-level imports are needed by every install."""
    sources = {_module_name(p): p for p in (ROOT / "bdipole_cl").rglob("*.py")}
    found = {name: list(_imports(path, name)) for name, path in sources.items()}
    eager, todo = set(), ["bdipole_cl", "bdipole_cl.__main__", "bdipole_cl.apps.cli"]
    while todo:
        name = todo.pop()
        if name in eager or name not in sources:
            continue
        eager.add(name)
        parts = name.split(".")
        todo += [".".join(parts[:i]) for i in range(1, len(parts))]      # parent packages
        todo += [t for t, top in found[name] if top and t in sources]
    third = {}
    for name, targets in found.items():
        for target, top in targets:
            module = target.split(".")[0]
            if module and module not in sys.stdlib_module_names and module != "bdipole_cl":
                third[module] = third.get(module, False) or (top and name in eager)
    return third


def test_every_module_the_library_imports_is_installed_by_its_own_dependencies():
    """What `import bdipole_cl` and the CLI load is a core dependency; what is imported only
    on demand (USD, MaterialX, Dask, renderers) is in an extra. A module installed only by
    the test extra would pass every other test and fail on `pip install .` (OpenColorIO's
    did, for every undeclared 8-bit TIFF)."""
    import importlib.metadata as md
    import tomllib
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    core = _requirement_names(project["dependencies"])
    extras = _requirement_names(r for reqs in project["optional-dependencies"].values()
                                for r in reqs)
    dists = md.packages_distributions()
    imports = _third_party_imports()
    assert {"numpy", "pyopencl", "OpenImageIO"} <= {m for m, eager in imports.items() if eager}
    for module, at_module_level in sorted(imports.items()):
        if module in BESIDE_EXTRAS or module == "tomli":   # tomli: Python < 3.11 only
            continue
        names = {d.lower().replace("_", "-") for d in dists.get(module, [])}
        assert names, f"{module}: imported by bdipole_cl, installed by no distribution here"
        when, wanted, kind = (("whenever bdipole_cl is", core, "core") if at_module_level
                              else ("on demand", core | extras, "core or extra"))
        assert names & wanted, (f"{module} ({', '.join(sorted(names))}) is imported {when} "
                                f"but is not in the {kind} dependencies of pyproject.toml")
