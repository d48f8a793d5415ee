"""Scene files (TOML): parsed, checked and resolved into typed materials and blurs (I/O).

    [defaults]                        # any material or blur key
    eta = 1.4
    unit = "mm"
    tol = 1e-4
    model = "better"                  # or "dipole" (docs/python.md "Vocabulary")
    working_space = "ACEScg"          # the renderer's rendering space (docs/colour.md)

    [[material]]
    name = "skin"
    albedo = "tex/skin_albedo.<UDIM>.exr"
    mfp = [1.2, 0.6, 0.3]             # a number, one per channel, or a texture path
    outputs = ["sigma_a", "sigma_s"]
    output = "out/skin_sss.<UDIM>.exr"
    mask = "alpha"                    # optional: the albedo's alpha, or a texture path
    half = true
    colorspace = "auto"               # the albedo's: as the file declares, or a name
    texture = true                    # optional: tiled, mip-mapped EXR textures

    [[blur]]
    name = "skin_tsd"
    material = "skin"
    irradiance = "light/skin_irr.<UDIM>.exr"
    texel_size = 0.05                 # or stretch = "bound" (a stage's material: the meshes
    output = "out/skin_exitance.<UDIM>.exr"   # it is bound to), a mesh file, stretch maps

    materials_from = "asset.usda"     # optional: a USD stage or MaterialX document's
                                      # subsurface materials; a [[material]] of the same
                                      # name overrides their keys

Paths are relative to the scene file; ``{material}`` in an output is the material's name.
Every error is one line naming the file, the line, the key and what is allowed
(``SceneError``); unknown keys are errors. A stage or document itself is a scene too
(``load_imported``): its materials with the built-in defaults.
"""
from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path


try:
    import tomllib
except ImportError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

from ..physics.models import MODEL
from .colour import resolve_colorspace, resolve_working_space
from .targets import parse_targets
from .mipmaps import scene_texture
from .scene_keys import (DEFAULT_TOL, DEFAULTS, KEYS, REQUIRED, STAGE_SUFFIXES,  # noqa: F401
                         UNIT_METERS, blur_lengths)     # (KEYS ... UNIT_METERS: read from here)
from .scene_types import Blur, ImportedMaterial, Material, SceneData  # noqa: F401
from .scene_values import as_list, check_material_eta, check_scaled_mfp, floats


class SceneError(ValueError):
    """A scene file that cannot be used: one line with the file, line, key and what is allowed."""




def line_of(text: str, section: str | None, index: int, key: str | None) -> int:
    """The line of ``key`` in the ``index``-th ``[[section]]`` (or ``[section]``), else of the
    section's header, else 1: for error messages (TOML parsers keep no positions)."""
    lines = text.splitlines()
    count, start = -1, None
    header = re.compile(r"^\s*\[\[?\s*" + re.escape(section or "") + r"\s*\]\]?\s*(#.*)?$")
    for n, line in enumerate(lines):
        if section is not None and header.match(line):
            count += 1
            if count == index:
                start = n
                break
    if section is not None and start is None:
        return 1
    begin = 0 if start is None else start + 1
    for n in range(begin, len(lines)):
        if n > begin - 1 and re.match(r"^\s*\[", lines[n]) and n != start:
            break
        if key is not None and re.match(r"^\s*" + re.escape(key) + r"\s*=", lines[n]):
            return n + 1
    return (start or 0) + 1




def load(path, importer=None, working_space=None) -> SceneData:
    """Read, check and resolve a scene file (``SceneError`` on any problem, one line).
    ``importer(path) -> [ImportedMaterial]`` reads the stage or document ``materials_from``
    names; ``working_space``: the one of entries that give none (in them or in [defaults]);
    None: the default working space."""
    path = Path(path)
    working_space = _working_space(working_space)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise SceneError(f"{path}: cannot read the scene: {exc.strerror or exc}") from None
    try:
        text = data.decode("utf-8-sig")            # TOML is UTF-8; a leading BOM is allowed
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise SceneError(f"{path}:{line}: not UTF-8 text (byte 0x{data[exc.start]:02x} at "
                         f"offset {exc.start}): save the scene file as UTF-8") from None
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: not valid TOML: {exc}") from None

    def fail(section, index, key, message):
        line = line_of(text, section, index, key)
        raise SceneError(f"{path}:{line}: {message}")

    unknown_top = set(raw) - {"defaults", "material", "blur", "materials_from"}
    if unknown_top:
        key = sorted(unknown_top)[0]
        fail(None, 0, key, f"unknown table or key '{key}': expected [defaults], [[material]], "
                           f"[[blur]] or materials_from")
    defaults = raw.get("defaults", {})
    for key, value in defaults.items():
        _check(fail, "defaults", 0, key, value, {"material", "blur"})
    base = path.parent

    def resolve(rel):
        return str((base / rel).resolve()) if rel and rel != "alpha" else rel

    source, imports = None, ()
    if "materials_from" in raw:
        if not (isinstance(raw["materials_from"], str) and raw["materials_from"]):
            fail(None, 0, "materials_from", "materials_from: expected the path of a USD stage "
                                            "or MaterialX document")
        source = resolve(raw["materials_from"])
        if importer is None:
            fail(None, 0, "materials_from", "materials_from needs an importer "
                                            "(bdipole_cl.scene.load reads it)")
        try:
            imports = tuple(importer(source))
        except SceneError as exc:
            fail(None, 0, "materials_from", str(exc))
    entries = raw.get("material", [])
    overrides = {e.get("name"): i for i, e in enumerate(entries)}
    materials, checked = {}, []
    for imp in imports:
        i = overrides.get(imp.name)
        if imp.left_out:
            if i is not None:
                fail("material", i, "name", f"material '{imp.name}' of {source} is left out "
                                            f"({imp.left_out}); an override cannot bake it")
        elif i is not None:          # the user's override: its problems are this file's
            materials[imp.name] = _imported(fail, i, entries[i], imp, defaults, resolve,
                                            working_space)
        else:                        # the stage's own values: a problem leaves it out, named
            try:                     # ([defaults]' problems stay this file's)
                materials[imp.name] = _imported(
                    lambda sec, *a: fail(sec, *a) if sec == "defaults" else _raise(a[-1]),
                    None, {}, imp, defaults, resolve, working_space)
            except StageValueError as exc:
                imp = replace(imp, left_out=f"not bakeable: {exc}")
        checked.append(imp)
    imports = tuple(checked)
    for i, entry in enumerate(entries):
        if any(imp.name == entry.get("name") for imp in imports):
            continue
        if imports and "albedo" not in entry:      # meant as an override, by another name
            fail("material", i, "name", f"material '{entry.get('name')}' is not a material of "
                                        f"{source} (its materials: "
                                        f"{', '.join(imp.name for imp in imports)}); a new "
                                        f"material needs 'albedo'")
        m = _entry(fail, "material", i, entry, defaults)
        check_material_eta(fail, i, entry, m)
        check_scaled_mfp(fail, i, entry, m)
        if not isinstance(m["albedo"], str) and isinstance(m["mfp"], str):
            fail("material", i, "albedo", f"albedo = {m['albedo']!r} is constant and mfp a "
                                          f"texture: a bake is driven by an albedo texture")
        if m["name"] in materials:
            fail("material", i, "name", f"material name '{m['name']}' is used twice")
        materials[m["name"]] = _material(m, resolve, (
            _colour(fail, "material", i, entry, m, "colorspace"),
            _colour(fail, "material", i, entry, m, "working_space") or working_space))
    blurs, names = [], set()
    for i, entry in enumerate(raw.get("blur", [])):
        b = _entry(fail, "blur", i, entry, defaults)
        if b["name"] in names:
            fail("blur", i, "name", f"blur name '{b['name']}' is used twice")
        names.add(b["name"])
        if b["material"] not in materials:
            fail("blur", i, "material", f"material '{b['material']}' is not in the scene "
                                        f"(materials: {', '.join(materials) or 'none'})")
        mat = materials[b["material"]]
        if not isinstance(mat.albedo, str):
            fail("blur", i, "material", f"material '{mat.name}' has a constant albedo: a blur "
                                        f"needs an albedo texture")
        mask = resolve(b["mask"]) if "mask" in entry else mat.mask
        from_stage = (str(source or "").lower().endswith(STAGE_SUFFIXES)
                      and any(imp.name == mat.name for imp in imports))
        texel, stretch, mesh_unit = blur_lengths(fail, i, entry, defaults, b, mat, from_stage,
                                                 resolve)
        blurs.append(Blur(b["name"], mat, resolve(b["irradiance"]), texel,
                          resolve(b["output"]), mask, b["half"], float(b["tol"]),
                          b["blur_method"], b["border"], b["on_invalid"],
                          _colour(fail, "blur", i, entry, b, "colorspace"),
                          _colour(fail, "blur", i, entry, b, "working_space")
                          if "working_space" in entry else mat.working_space,
                          scene_texture(b), stretch, b["charts"], mesh_unit))
    if not materials and not blurs and not imports:
        fail(None, 0, None, "the scene has no [[material]] and no [[blur]]")
    return SceneData(path.resolve(), tuple(materials.values()), tuple(blurs), source, imports)


def load_imported(path, importer, working_space=None) -> SceneData:
    """A USD stage or MaterialX document as a scene: its materials (``importer(path)``), the
    built-in defaults, outputs beside it."""
    path = Path(path).resolve()
    working_space = _working_space(working_space)
    imports = tuple(importer(str(path)))

    materials, checked = [], []
    for imp in imports:               # a value the stage gives that cannot be baked leaves
        if not imp.left_out:          # that material out, named; the others bake
            try:
                materials.append(_imported(lambda *a: _raise(a[-1]), None, {}, imp, {},
                                           lambda p: p, working_space))
            except StageValueError as exc:
                imp = replace(imp, left_out=f"not bakeable: {exc}")
        checked.append(imp)
    return SceneData(path, tuple(materials), (), str(path), tuple(checked))


def _material(m, resolve, colour) -> Material:
    """The record of a checked, merged material entry; ``colour``: its (colorspace,
    working_space) as the OCIO config names them."""
    mfp, albedo = m["mfp"], m["albedo"]
    return Material(
        m["name"], resolve(albedo) if isinstance(albedo, str) else floats(albedo),
        resolve(mfp) if isinstance(mfp, str) else floats(mfp), floats(m["eta"]),
        tuple(m["outputs"]), resolve(m["output"].replace("{material}", m["name"])),
        resolve(m.get("mask")), m["half"], m["unit"], float(m["tol"]),
        MODEL.canonical(m["model"]),
        m["method"], m["exact"], m["double"], m["on_invalid"], *colour, m["mfp_kind"],
        floats(m["mfp_scale"]), scene_texture(m), parse_targets(m.get("targets", [])),
        m.get("albedo_layer"), m.get("mfp_layer"))


def _imported(fail, index, entry, imp, defaults, resolve, working_space) -> Material:
    """An imported material: the built-in defaults, then its suggestions (output), [defaults],
    its facts (the stage's values), then its [[material]] override. A unit the user names
    converts the stage's distances (in its scene unit) into it."""
    for key, value in imp.facts.items():
        if not KEYS[key][1](value):
            fail("material", index or 0, "name",
                 f"{imp.path}: {key} = {value!r}: expected {KEYS[key][2]}")
    # the stage's layer of its texture, not of the override's own texture
    facts = {k: v for k, v in imp.facts.items()
             if not (k.endswith("_layer") and k[:-len("_layer")] in entry)}
    m = _entry(fail, "material", index or 0, {"name": imp.name, **entry}, defaults,
               below=imp.suggestions, above=facts)
    check_material_eta(fail, index or 0, entry, m, from_stage="eta" in imp.facts)
    named = entry.get("unit", defaults.get("unit"))
    if "mfp" in entry:
        m["mfp_scale"] = entry.get("mfp_scale", 1.0)
    elif named is not None:
        meters = UNIT_METERS.get(named)
        if meters is None:
            where = ("material", index) if "unit" in entry else ("defaults", 0)
            fail(*where, "unit", f"unit = {named!r}: converting {imp.name}'s distances from "
                                 f"the stage's unit needs one of {', '.join(UNIT_METERS)}")
        factor = imp.unit_m / meters
        m["mfp_scale"] = [v * factor for v in as_list(m["mfp_scale"])]
        m["unit"] = named
    try:                                 # a texture's colour space as the stage names it
        space = _colour(fail, "material", index or 0, entry, m, "colorspace")
    except SceneError:                   # the stage's own name: kept, so that the plan
        if "colorspace" in entry or "colorspace" not in imp.facts:   # makes this material
            raise                        # a job that cannot run and the others still bake
        space = imp.facts["colorspace"]
    check_scaled_mfp(fail, index or 0, entry, m)
    ws = _colour(fail, "material", index or 0, entry, m, "working_space") or working_space
    return _material(m, resolve, (space, ws))


def _working_space(name):
    return resolve_working_space(name).name if name else None


def _colour(fail, kind, index, entry, merged, key):
    """A colour key of an entry (or of [defaults]) as the OCIO config names it: colorspace
    "auto" or a space, working_space a scene-linear space or None (the default); an unknown
    name fails on the line that gives it, listing the known ones."""
    value = merged.get(key)
    if value is None or (key == "colorspace" and value == "auto"):
        return value
    try:
        if key == "colorspace":
            return resolve_colorspace(value)
        return resolve_working_space(value).name
    except ValueError as exc:
        where = (kind, index) if key in entry else ("defaults", 0)
        fail(*where, key, f"{key} = {value!r}: {exc}")


class StageValueError(SceneError):
    """A value a stage or document gives that cannot be baked: its material is left out."""


def _raise(message):
    raise StageValueError(message)


def _check(fail, section, index, key, value, kinds):
    spec = KEYS.get(key)
    if key == "materials_from":
        fail(section, index, key, f"materials_from is in [{section}]: it is a top-level key, "
                                  f"so it goes before the first table")
    if spec is None or not (spec[0] & kinds):
        allowed = sorted(k for k, s in KEYS.items() if s[0] & kinds)
        fail(section, index, key, f"unknown key '{key}' in [{section}]: allowed keys are "
                                  f"{', '.join(allowed)}")
    if not spec[1](value):
        fail(section, index, key, f"{key} = {value!r}: expected {spec[2]}")


def _entry(fail, kind, index, entry, defaults, below=None, above=None):
    """One [[material]] or [[blur]] checked, with [defaults] and the built-in defaults
    (``below`` and ``above`` [defaults]: an imported material's keys)."""
    for key, value in entry.items():
        _check(fail, kind, index, key, value, {kind})
    merged = {k: v for k, v in DEFAULTS.items() if kind in KEYS[k][0]}
    merged["tol"] = DEFAULT_TOL[kind]
    merged.update(below or {})
    merged.update({k: v for k, v in defaults.items() if kind in KEYS[k][0]})
    merged.update(above or {})
    merged.update(entry)
    for key in REQUIRED[kind]:
        if key not in merged:
            fail(kind, index, None, f"[[{kind}]] #{index + 1} needs '{key}' "
                                    f"({KEYS[key][2]})")
    return merged
