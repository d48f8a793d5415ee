"""One vocabulary: every option kind's registry is what the CLI offers, what scene files
accept, what the Python checks accept and what docs/python.md "Vocabulary" lists. No device needed
but for the last test (once per working device)."""
import argparse
import ast
import importlib
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from bdipole_cl import errors, vocabulary
from bdipole_cl.apps.cli import build_parser
from bdipole_cl.device.programs import build_options
from bdipole_cl.io import scene_file
from bdipole_cl.methods import registry
from bdipole_cl.ops.invert import check_mfp_kind, check_outputs
from bdipole_cl.physics import models
from bdipole_cl.physics import reference as ref
from bdipole_cl.vocabulary import Option, Registry

#: the page that holds the Vocabulary and Methods tables
PYTHON_DOCS = Path(__file__).resolve().parent.parent / "docs" / "python.md"
#: the modules that define registries (a registry defined elsewhere is a test failure below)
REGISTRY_MODULES = ("bdipole_cl.errors", "bdipole_cl.physics.models",
                    "bdipole_cl.physics.conventions", "bdipole_cl.methods.registry",
                    "bdipole_cl.device.numerics")
PACKAGE = Path(__file__).resolve().parent.parent / "bdipole_cl"


def vocabulary_rows():
    """docs/python.md "Vocabulary"'s table: one dict per row, keyed by the header."""
    text = PYTHON_DOCS.read_text()
    section = text.split("\n## Vocabulary", 1)[1].split("\n## ", 1)[0]
    lines = [ln for ln in section.splitlines() if ln.startswith("|")]
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    return [dict(zip(header, (c.strip() for c in ln.strip("|").split("|"))))
            for ln in lines[2:]]


def registry_at(path: str) -> Registry:
    module, _, name = path.strip("`").rpartition(".")
    return getattr(importlib.import_module(module), name)


def names_column(text: str):
    """'`better` (`better-dipole`), `dipole`' -> [("better", ("better-dipole",)), ...]."""
    out = []
    for part in re.findall(r"`[^`]+`(?: \((?:`[^`]+`(?:, )?)+\))?", text):
        words = re.findall(r"`([^`]+)`", part)
        out.append((words[0], tuple(words[1:])))
    return out


ROWS = vocabulary_rows()
ROW_IDS = [row["kind"] for row in ROWS]


def test_the_table_is_found():
    # the checks below mean nothing on an empty table
    assert len(ROWS) >= 7 and {"model", "inversion method", "outputs"} <= set(ROW_IDS)


@pytest.mark.parametrize("row", ROWS, ids=ROW_IDS)
def test_the_docs_list_each_registry(row):
    reg = registry_at(row["registry"])
    assert isinstance(reg, Registry), row
    assert names_column(row["names"]) == [(o.name, tuple(o.aliases)) for o in reg], row


def all_registries():
    for module in REGISTRY_MODULES:
        for name, value in vars(importlib.import_module(module)).items():
            if isinstance(value, Registry):
                yield f"{module}.{name}", value


def test_every_registry_is_in_the_docs():
    # a registry is listed, or its options are a part of a listed one of the same kind
    # (METHOD: METHOD_OR_AUTO without auto)
    listed = [registry_at(row["registry"]) for row in ROWS]
    missing = [path for path, reg in all_registries()
               if not any(reg is r or (reg.kind == r.kind and set(reg.options) <= set(r.options))
                          for r in listed)]
    assert not missing, missing


def test_registries_are_defined_only_where_expected():
    # a Registry(...) anywhere else in the package would be a second vocabulary
    found = sorted(str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*.py")
                   if re.search(r"(?<![\w.])Registry\(", p.read_text()))   # not Sdr.Registry()
    assert found == ["device/numerics.py", "errors.py", "io/targets.py", "methods/registry.py",
                     "physics/conventions.py", "physics/models.py", "vocabulary.py"]


def cli_actions(option: str):
    """(command, argparse action) for each ``command --option`` of the CLI column."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for command, flag in (c.strip("` ").split() for c in option.split("(")[0].split(",")):
        p = sub.choices[command]
        yield command, next(a for a in p._actions if flag in a.option_strings)


@pytest.mark.parametrize("row", ROWS, ids=ROW_IDS)
def test_the_cli_offers_each_registry(row):
    reg = registry_at(row["registry"])
    for command, action in cli_actions(row["CLI"]):
        if action.choices is None:            # a comma list (--outputs, --target), its type's
            for option in reg:                # every spelling alone, to the canonical name
                for spelling in (option.name, *option.aliases):
                    assert action.type(spelling) == (option.name,), (command, spelling)
            if row["kind"] != "render target":    # targets: one per render context
                assert action.type(",".join(reg.names)) == reg.names, command
            with pytest.raises(argparse.ArgumentTypeError) as exc:
                action.type("nonsense")
            assert all(name in str(exc.value) for name in reg.names), str(exc.value)
            continue
        assert tuple(action.choices) == reg.names, (command, action.option_strings)
        assert action.default in reg.names, (command, action.default)
        for option in reg:                    # every spelling parses, to the canonical name
            for spelling in (option.name, *option.aliases):
                value = action.type(spelling) if action.type else spelling
                assert value == option.name and value in action.choices, (command, spelling)


def test_every_cli_choice_comes_from_a_registry():
    # no command retypes a list of words: each choices tuple is a registry's names
    # (crosscheck --against: the user-kernel signatures, user_kernel.SIGNATURES)
    from bdipole_cl.apps.user_kernel import SIGNATURES
    known = {reg.names for _, reg in all_registries()} | {tuple(SIGNATURES)}
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    stray = [(command, a.option_strings, a.choices) for command, p in sub.choices.items()
             for a in p._actions
             if a.choices is not None and not isinstance(a, argparse._SubParsersAction)
             and tuple(a.choices) not in known]
    assert not stray, stray


@pytest.mark.parametrize("row", [r for r in ROWS if not r["scene file"].startswith("-")],
                         ids=[r["kind"] for r in ROWS if not r["scene file"].startswith("-")])
def test_scene_files_accept_each_registry(row):
    reg = registry_at(row["registry"])
    key = row["scene file"].split()[0].strip("`")
    _, check, allowed = scene_file.KEYS[key]
    as_value = (lambda v: [v]) if row["scene file"].endswith("(list)") else (lambda v: v)
    for spelling in reg.spellings:
        assert check(as_value(spelling)), (key, spelling)
        assert spelling in allowed, (key, spelling, allowed)
    assert not check(as_value("nonsense")), key
    assert not check(["not", "a", "word"]) or key == "outputs", key


def load_material(tmp_path, model):
    path = tmp_path / "scene.toml"
    path.write_text(f'[[material]]\nname = "skin"\nalbedo = "a.exr"\noutput = "o.exr"\n'
                    f'model = "{model}"\n')
    return scene_file.load(path).materials[0]


@pytest.mark.parametrize("spelling", models.MODEL.spellings)
def test_every_model_spelling_works_everywhere(tmp_path, spelling):
    canonical = models.MODEL.canonical(spelling)
    # scene files: stored as the canonical name
    assert load_material(tmp_path, spelling).model == canonical
    # the Python reference and the kernels' build options: the same as the canonical name's
    a = np.linspace(0.01, 0.99, 7)
    np.testing.assert_array_equal(ref.rd(a, 1.4, model=spelling), ref.rd(a, 1.4, model=canonical))
    assert build_options({}, model=spelling) == build_options({}, model=canonical)
    # the CLI: the canonical name
    args = build_parser().parse_args(["invert", "x.exr", "--model", spelling])
    assert args.model == canonical


def test_the_scene_default_model_is_the_canonical_name():
    assert scene_file.DEFAULTS["model"] == models.MODEL.names[0] == "better"


def test_a_scene_with_an_unknown_model_names_every_spelling(tmp_path):
    with pytest.raises(scene_file.SceneError,
                       match='model = \'jensen\': expected "better", "better-dipole" or '
                             '"dipole"'):
        load_material(tmp_path, "jensen")


def test_a_scene_value_of_the_wrong_type_is_a_scene_error(tmp_path):
    # a list where a word belongs: a one-line SceneError (was a TypeError: unhashable list)
    path = tmp_path / "scene.toml"
    path.write_text('[[material]]\nname = "skin"\nalbedo = "a.exr"\noutput = "o.exr"\n'
                    'model = ["better"]\n')
    with pytest.raises(scene_file.SceneError, match="model = \\['better'\\]: expected"):
        scene_file.load(path)


@pytest.mark.parametrize("check, reg", [
    (errors.check_policy, errors.POLICY), (check_mfp_kind, registry.MFP_KIND),
    (registry.MethodConfig, registry.METHOD),
], ids=["on_invalid", "mfp_kind", "method"])
def test_the_python_checks_take_each_registry(check, reg):
    for name in reg.names:
        assert check(name) is not None, name
    with pytest.raises(ValueError, match=f"{reg.kind}='nonsense': expected one of "
                                         f"{', '.join(reg.names)}"):
        check("nonsense")


def test_check_outputs_takes_every_output():
    assert check_outputs(registry.OUTPUTS) == registry.OUTPUTS
    with pytest.raises(ValueError, match="unknown outputs"):
        check_outputs(("sigma_x",))


def test_the_public_tuples_are_the_registries_names():
    import bdipole_cl as bd
    assert bd.METHODS == registry.METHOD.names
    assert bd.MODELS == models.MODEL.names == ref.MODELS
    assert bd.OUTPUTS == registry.OUTPUT.names
    assert bd.POLICIES == errors.POLICY.names
    assert registry.TEXTURED_BLUR_METHODS == ("auto", "gaussians", "fft")
    assert registry.BLUR_KERNELS == ("direct", "gaussians", "fft")


def test_a_registry_refuses_a_spelling_that_names_two_options():
    with pytest.raises(ValueError, match="'b' names two options"):
        Registry("kind", (Option("a", "one", aliases=("b",)), Option("b", "two")))


def test_a_registry_looks_up_names_and_aliases_only():
    reg = Registry("kind", (Option("a", "one", aliases=("alpha",)), Option("b", "two")))
    assert reg.canonical("alpha") == "a" and reg["b"].summary == "two"
    assert reg.spellings == ("a", "alpha", "b") and reg.names == ("a", "b")
    assert ["x"] not in reg and None not in reg and "A" not in reg
    assert reg.listing('"') == '"a", "alpha" or "b"'
    assert Registry("kind", (Option("a", "one"), Option("b", "two"))).listing() == "a or b"
    with pytest.raises(ValueError, match="kind='c': expected one of a, alpha, b"):
        reg["c"]
    assert isinstance(errors.POLICY, vocabulary.Registry)


@pytest.mark.usefixtures("on_device")
@pytest.mark.parametrize("alias", models.BETTER.aliases)
def test_a_model_alias_runs_the_canonical_models_kernels(alias):
    # the Python API on a device: the alias's coefficients are the canonical name's, bit for
    # bit (the same build options and constants), and not the other model's
    import bdipole_cl as bd
    rd = np.linspace(0.01, 0.95, 257, dtype=np.float32)
    got = bd.albedo_to_coefficients(rd, 1.0, 1.4, model=alias)
    want = bd.albedo_to_coefficients(rd, 1.0, 1.4, model=models.BETTER.name)
    other = bd.albedo_to_coefficients(rd, 1.0, 1.4, model=models.DIPOLE.name)
    for g, w, o in zip(got, want, other):
        np.testing.assert_array_equal(g, w)
        assert not np.array_equal(g, o)


def methods_table():
    """docs/python.md "Methods"' table of inversion methods: {method: its knobs cell}."""
    text = PYTHON_DOCS.read_text()
    section = text.split("Methods (`method=`) and their knobs:", 1)[1].split("\n\n", 2)[1]
    rows = [[c.strip() for c in ln.strip("|").split("|")] for ln in section.splitlines()[2:]]
    return {re.match(r"`(\w+)`", r[0]).group(1): r[2] for r in rows}


def test_the_docs_give_each_methods_defaults():
    # the docs' methods and their knobs' defaults (float32; float64 where it differs) are
    # the registry's, and MethodConfig's own defaults (table_size, seed_size) too
    table = methods_table()
    assert tuple(table) == registry.METHOD_OR_AUTO.names
    config = registry.MethodConfig()
    for spec in registry.METHOD:
        knobs = table[spec.name]
        for knob, f32, f64 in spec.defaults:
            given = re.search(rf"`{knob}` \(([-+.e\d]+)(?:; ([-+.e\d]+) in float64)?", knobs)
            assert given, (spec.name, knob, knobs)
            doc32, doc64 = float(given[1]), float(given[2] or given[1])
            assert (doc32, doc64) == (f32, f64), (spec.name, knob, knobs)
        if spec.table:
            assert f"`{spec.table}` ({getattr(config, spec.table)})" in knobs, (spec.name, knobs)


def test_a_registry_of_plain_options_keeps_their_order():
    reg = Registry.of("kind", b="two", a="one")
    assert reg.names == ("b", "a") and reg["a"] == Option("a", "one")


#: retyped copies still in modules other work is restructuring this round (file, registry):
#: each goes when its module imports the registry instead; an entry that is no longer found
#: fails below, so the list only shrinks
KNOWN_COPIES = {
    ("apps/preview.py", "OUTPUT"),          # GROUP_LABELS: a label per output group
    ("dask.py", "BORDER"),                  # BOUNDARIES: dask's boundary per border
    ("jobs/invert_file.py", "MFP_KIND"),    # MFP_CONVENTIONS: a description per mfp kind
    ("jobs/scene_records.py", "MFP_KIND"),  # MFP_MEANING: a description per mfp kind
    ("ops/blur/fft.py", "BORDER"),          # numpy.pad's mode per border
}


def retyped_copies():
    """(file, registry) for each tuple, list, set or dict-keys literal of the package that
    names every option of a registry (by name or alias): a vocabulary typed again."""
    registries = [(path.rpartition(".")[2], reg) for path, reg in all_registries()
                  if len(reg) >= 2]
    found = set()
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
                elements = node.elts
            elif isinstance(node, ast.Dict):
                elements = [k for k in node.keys if k is not None]
            else:
                continue
            words = {e.value for e in elements
                     if isinstance(e, ast.Constant) and isinstance(e.value, str)}
            for name, reg in registries:
                if all(words & {o.name, *o.aliases} for o in reg):
                    found.add((str(path.relative_to(PACKAGE)), name))
    return found


def test_no_vocabulary_is_typed_again():
    found = retyped_copies()
    assert found - KNOWN_COPIES == set(), sorted(found - KNOWN_COPIES)
    assert KNOWN_COPIES - found == set(), ("switched to the registry: remove from KNOWN_COPIES",
                                           sorted(KNOWN_COPIES - found))


def test_the_copy_finder_finds_a_copy(tmp_path, monkeypatch):
    # the check above means nothing if it cannot see a retyped tuple
    (tmp_path / "planted.py").write_text('POLICIES = ("raise", "clamp")\n'
                                         'MODES = {"better-dipole": 1, "dipole": 2}\n')
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", tmp_path)
    assert retyped_copies() == {("planted.py", "POLICY"), ("planted.py", "MODEL")}
