"""Tile conventions (bdipole_cl/io/tiles.py): every token reads and writes the right tiles, in
batches and scenes, and a token that cannot name a tile is a one-line error."""

import numpy as np
import OpenImageIO as oiio
import pytest
from bdipole_cl.io.batch import expand_inputs, process_textures
from bdipole_cl.io.scene import load

from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.apps.demo import write_exr
from bdipole_cl.io import tiles

#: (pattern's tile part, how tiles (0, 0), (9, 0), (0, 1), (10, 0) are named: None = cannot
#: be), as each tool's documentation writes them (docs/tiles.md)
NAMES = {
    "<UDIM>": ("1001", "1010", "1011", None),
    "<udim>": ("1001", "1010", "1011", None),                      # Arnold
    "$UDIM": ("1001", "1010", "1011", None),                       # Mari, Substance Painter
    "%(UDIM)d": ("1001", "1010", "1011", None),                    # Houdini
    "<UVTILE>": ("u1_v1", "u10_v1", "u1_v2", "u11_v1"),
    "<uvtile>": ("u0_v0", "u9_v0", "u0_v1", "u10_v0"),             # OpenImageIO, V-Ray
    "%(UVTILE)d": ("u1_v1", "u10_v1", "u1_v2", "u11_v1"),
    "<UVTILE0>": ("u0_v0", "u9_v0", "u0_v1", "u10_v0"),
    "<tile>": ("_u1_v1", "_u10_v1", "_u1_v2", "_u11_v1"),          # Arnold: Mudbox's _uU_vV
    "_u##v##": ("_u00v00", "_u09v00", "_u00v01", "_u10v00"),       # OpenImageIO
    "u<U>_v<V>": ("u1_v1", "u10_v1", "u1_v2", "u11_v1"),           # Maya, 1-based
    "_u<u>_v<v>": ("_u0_v0", "_u9_v0", "_u0_v1", "_u10_v0"),       # Maya, 0-based
    "<U><V>": ("u1v1", "u10v1", "u1v2", "u11v1"),                  # OpenImageIO writes u, v
    "<u>_<v>": ("u0_v0", "u9_v0", "u0_v1", "u10_v0"),
    "%(U)02d_%(V)02d": ("01_01", "10_01", "01_02", "11_01"),       # Houdini, padded
    "$U_$V": ("1_1", "10_1", "1_2", "11_1"),                       # V-Ray
    "$2u_$2v": ("00_00", "09_00", "00_01", "10_00"),               # V-Ray, 0-based padded
}
TILES = (tiles.Tile(0, 0), tiles.Tile(9, 0), tiles.Tile(0, 1), tiles.Tile(10, 0))
#: the registry's entries each NAMES spelling uses
SPELT = {"u<U>_v<V>": ("u<U>", "v<V>"), "_u<u>_v<v>": ("u<u>", "v<v>"), "<U><V>": ("<U>", "<V>"),
         "<u>_<v>": ("<u>", "<v>"), "%(U)02d_%(V)02d": ("%(U)d", "%(V)d"), "$U_$V": ("$U", "$V"),
         "$2u_$2v": ("$u", "$v")}


def test_the_registry_holds_every_token():
    used = {t for k in NAMES for t in SPELT.get(k, (k,))}
    assert {t.text for t in tiles.TOKENS} == used


@pytest.mark.parametrize("token", NAMES)
def test_each_token_names_each_tile(token):
    for tile, name in zip(TILES, NAMES[token]):
        pattern = f"skin.{token}.exr"
        if name is None:
            with pytest.raises(tiles.TileError, match="cannot name tile u11_v1"):
                tiles.fill(pattern, tile, "x.exr")
        else:
            assert tiles.fill(pattern, tile, "x.exr") == f"skin.{name}.exr"
            assert tiles.match(pattern, f"skin.{name}.exr") == tile, (token, name)


def test_mudbox_names_are_udims_as_the_convention_says():
    """u1_v1 is UDIM 1001; u10_v1 is 1010; u1_v2 is 1011 (and ZBrush's u0_v0 is 1001); a
    number a token would not write is no tile (1000, u0_v1 1-based, 01 unpadded)."""
    for text, udim in (("u1_v1", 1001), ("u10_v1", 1010), ("u1_v2", 1011)):
        tile = tiles.match("a.<UVTILE>.exr", f"a.{text}.exr")
        assert tile.udim == udim, (text, tile)
    assert tiles.match("a.<UVTILE0>.exr", "a.u0_v0.exr").udim == 1001
    for pattern, name in (("a.<UDIM>.exr", "a.1000.exr"), ("a.<UVTILE>.exr", "a.u0_v1.exr"),
                          ("a.$U_$V.exr", "a.01_1.exr"), ("a.$2U_$2V.exr", "a.1_01.exr")):
        assert tiles.match(pattern, name) is None, (pattern, name)


def _tile_set(folder, token, albedos):
    """One small RGB albedo file per tile of TILES[:3], named in ``token``'s convention, each
    of its own constant value; returns the pattern."""
    for tile, rd in zip(TILES[:3], albedos):
        name = tiles.fill(f"alb.{token}.exr", tile, "test")
        write_exr(folder / name, np.full((4, 6, 3), rd, np.float32), ("R", "G", "B"))
    return str(folder / f"alb.{token}.exr")


@pytest.mark.parametrize("token_in", NAMES)
def test_every_token_reads_and_writes_the_right_tiles(tmp_path, token_in, on_device):
    albedos = (0.2, 0.5, 0.8)
    pattern = _tile_set(tmp_path, token_in, albedos)
    write_exr(tmp_path / "alb.1000.exr", np.full((4, 6, 3), 0.5, np.float32),  # no tile
              ("R", "G", "B"))
    found = expand_inputs([pattern])
    assert [t for _, t in found] == [TILES[0], TILES[1], TILES[2]]    # ordered by v, then u
    order = list(NAMES)                 # each output token from three inputs, not all (time)
    for token_out in {token_in, "<UDIM>", order[(order.index(token_in) + 1) % len(order)]}:
        out = tmp_path / "out" / str(list(NAMES).index(token_out)) / f"sss.{token_out}.exr"
        rep = process_textures(pattern, mfp=1.0, eta=1.4, output=str(out),
                               outputs=("alpha",))
        assert rep.exit_code == 0, (token_in, token_out, rep.summary())
        for tile, name, rd in zip(TILES, NAMES[token_out], albedos):
            path = out.parent / f"sss.{name}.exr"
            buf = oiio.ImageBuf(str(path))
            assert not buf.has_error, (token_in, token_out, path, buf.geterror())
            source = buf.spec().getattribute("bdipole:albedo")
            assert source == tiles.fill(pattern, tile, "test"), (token_in, token_out, source)
            alpha = buf.get_pixels(oiio.FLOAT)[0, 0, 0]
            assert alpha == pytest.approx(ref_alpha(rd), rel=1e-4), (token_in, token_out)


def ref_alpha(rd):
    from bdipole_cl import reference as ref
    return float(ref.invert_rd(rd, 1.4))


def test_companion_textures_convert_their_own_token(tmp_path, on_device):
    """albedo in <UDIM>, mfp in ZBrush's u0_v0 names: each tile takes its own mfp."""
    _tile_set(tmp_path, "<UDIM>", (0.5, 0.5, 0.5))
    for tile, mfp in zip(TILES[:3], (1.0, 2.0, 4.0)):
        write_exr(tmp_path / tiles.fill("mfp.<UVTILE0>.exr", tile, "t"),
                  np.full((4, 6, 1), mfp, np.float32), ("Y",))
    rep = process_textures(str(tmp_path / "alb.<UDIM>.exr"),
                           mfp=str(tmp_path / "mfp.<UVTILE0>.exr"),
                           output=str(tmp_path / "o.<UVTILE>.exr"), outputs=("sigma_t",))
    assert rep.exit_code == 0, rep.summary()
    st = [oiio.ImageBuf(str(tmp_path / f"o.{n}.exr")).get_pixels(oiio.FLOAT)[0, 0, 0]
          for n in NAMES["<UVTILE>"][:3]]
    assert st[0] == pytest.approx(2 * st[1], rel=1e-5) == pytest.approx(4 * st[2], rel=1e-5)


def test_a_tile_the_output_token_cannot_name_is_a_one_line_error(tmp_path, capsys, on_device):
    write_exr(tmp_path / "alb.u11_v1.exr", np.full((4, 6, 3), 0.5, np.float32), ("R", "G", "B"))
    write_exr(tmp_path / "alb.u1_v1.exr", np.full((4, 6, 3), 0.5, np.float32), ("R", "G", "B"))
    rc = cli_main(["invert", str(tmp_path / "alb.<UVTILE>.exr"), "--no-progress",
                   "-o", str(tmp_path / "o.<UDIM>.exr")])
    out = capsys.readouterr().out
    assert rc == 1
    line = next(x for x in out.splitlines() if "u11_v1" in x and "failed" in x)
    assert "<UDIM> cannot name tile u11_v1" in line and "<UVTILE>" in line
    assert (tmp_path / "o.1001.exr").exists()            # the other tile is done


@pytest.mark.parametrize("inputs, output, expected", [
    ("alb.<UDIM>.<UVTILE>.exr", "o.exr", "one tile token per pattern"),
    ("alb.exr", "o.<UDIM>.exr", "needs a tile (<UDIM>) but the input has none"),
], ids=["two-tokens", "output-token-without-input-tile"])
def test_token_mismatches_are_one_line_errors(tmp_path, capsys, inputs, output, expected,
                                              on_device):
    write_exr(tmp_path / "alb.exr", np.full((4, 6, 3), 0.5, np.float32), ("R", "G", "B"))
    rc = cli_main(["invert", str(tmp_path / inputs), "--no-progress",
                   "-o", str(tmp_path / output)])
    cap = capsys.readouterr()
    text = cap.err if rc == 2 else cap.out
    lines = [x for x in text.splitlines() if expected in x]
    assert rc in (1, 2) and len(lines) == 1, (rc, cap)


def test_globs_and_literal_brackets_with_tile_tokens(tmp_path):
    for name in ("a.1001.exr", "b.1002.exr", "b.1000.exr", "b.x001.exr"):
        write_exr(tmp_path / name, np.full((2, 2, 1), 0.5, np.float32), ("Y",))
    found = expand_inputs([str(tmp_path / "*.<UDIM>.exr")])
    assert [(p.rsplit("/", 1)[1], t.label) for p, t in found] == [("a.1001.exr", "1001"),
                                                                   ("b.1002.exr", "1002")]
    d = tmp_path / "tex[v2]"                              # brackets in a real folder's name
    d.mkdir()
    write_exr(d / "c.u1_v2.exr", np.full((2, 2, 1), 0.5, np.float32), ("Y",))
    (found,) = expand_inputs([str(d / "c.<UVTILE>.exr")])
    assert found[1].udim == 1011


SCENE = """
[[material]]
name = "skin"
albedo = "tex/alb.<UVTILE>.exr"
mfp = 1.0
output = "out/skin.<UDIM>.exr"
"""


def test_scenes_convert_tiles_and_report_what_they_cannot_name(tmp_path, on_device):
    (tmp_path / "tex").mkdir()
    for name in ("u1_v1", "u10_v1", "u1_v2", "u11_v1"):
        write_exr(tmp_path / "tex" / f"alb.{name}.exr", np.full((4, 6, 3), 0.5, np.float32),
                  ("R", "G", "B"))
    (tmp_path / "scene.toml").write_text(SCENE)
    plan = load(tmp_path / "scene.toml").plan()
    outs = {j.udim: j.output.rsplit("/", 1)[1] for j in plan.jobs if not j.problem}
    assert outs == {"1001": "skin.1001.exr", "1010": "skin.1010.exr", "1011": "skin.1011.exr"}
    (bad,) = [j for j in plan.jobs if j.problem]
    assert bad.udim == "u11_v1" and "cannot name tile u11_v1" in bad.problem
    assert "\n" not in bad.problem
    report = plan.run()
    assert sum(r.status == "ok" for r in report.results) == 3, report.summary()


def test_the_cli_reads_and_writes_arnolds_token(tmp_path, capsys, on_device):
    """Arnold's <udim> read (was: 'no such file' with the tiles there) and written (was: one
    file literally named o.<udim>.exr, exit 0)."""
    _tile_set(tmp_path, "<udim>", (0.2, 0.5, 0.8))
    rc = cli_main(["invert", str(tmp_path / "alb.<udim>.exr"), "--no-progress",
                   "-o", str(tmp_path / "o" / "sss.<udim>.exr")])
    assert rc == 0, capsys.readouterr()
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == [
        "sss.1001.exr", "sss.1010.exr", "sss.1011.exr"]


@pytest.mark.parametrize("token, why", [
    ("<f>", "Maya's frame token"), ("####", "frame-number padding"),
    ("%04d", "frame-number padding"), ("$textureSet", "Substance Painter export token"),
    ("$F4", "Houdini's frame token"),
    ("_MAPID_", "RenderMan's atlas token"), ("<Udim>", "did you mean <UDIM> or <udim>?"),
    ("<tiles>", "not a tile token this tool knows"), ("<U>", "names the tile's u but not its v"),
], ids=["maya-frame", "hashes", "printf", "substance", "houdini-frame", "mapid", "case",
        "unknown", "u-only"])
@pytest.mark.parametrize("where", ["input", "output"])
def test_an_unknown_token_is_refused_named_never_a_file_name(tmp_path, capsys, token, why,
                                                             where, on_device):
    _tile_set(tmp_path, "<UDIM>", (0.5, 0.5, 0.5))
    src = f"alb.{token}.exr" if where == "input" else "alb.<UDIM>.exr"
    out = f"o.{token}.exr" if where == "output" else "o.<UDIM>.exr"
    rc = cli_main(["invert", str(tmp_path / src), "--no-progress", "-o", str(tmp_path / out)])
    text = capsys.readouterr().out
    lines = [x for x in text.splitlines() if token in x and why in x]
    assert rc == 1 and lines and "no such file" not in text, (rc, text)
    assert not list(tmp_path.glob("o.*")), list(tmp_path.glob("o.*"))   # nothing written


def test_preview_takes_a_tile_pattern(tmp_path, capsys, on_device):
    """preview reads the same tokens as invert and writes one sheet per tile."""
    _tile_set(tmp_path, "$UDIM", (0.2, 0.5, 0.8))
    rc = cli_main(["preview", str(tmp_path / "alb.$UDIM.exr"),
                   "-o", str(tmp_path / "sheet.<UDIM>.png")])
    assert rc == 0, capsys.readouterr()
    assert sorted(p.name for p in tmp_path.glob("sheet.*")) == [
        "sheet.1001.png", "sheet.1010.png", "sheet.1011.png"]
    rc = cli_main(["preview", str(tmp_path / "alb.$UDIM.exr"), "-o", str(tmp_path / "s.png")])
    err = capsys.readouterr().err
    assert rc == 1 and err.count("names one picture") == 3, err      # never one over another
    rc = cli_main(["invert", str(tmp_path / "alb.$UDIM.exr"), "--no-progress",
                   "-o", str(tmp_path / "o" / "sss.<udim>.exr")])
    assert rc == 0, capsys.readouterr()
    rc = cli_main(["preview", str(tmp_path / "o" / "sss.<udim>.exr")])   # its own outputs too
    assert rc == 0 and len(list((tmp_path / "o").glob("*.preview.png"))) == 3, capsys.readouterr()
    rc = cli_main(["preview", str(tmp_path / "alb.<f>.exr")])
    err = capsys.readouterr().err
    assert rc == 1 and "<f> is Maya's frame token" in err, err


def test_scenes_read_every_token_and_refuse_unknown_ones(tmp_path, on_device):
    """A scene's albedo in Substance's $UDIM, output in Maya's u<U>_v<V>; a second material
    whose output has a Maya frame token is a planned problem naming it."""
    (tmp_path / "tex").mkdir()
    _tile_set(tmp_path / "tex", "$UDIM", (0.5, 0.5, 0.5))
    (tmp_path / "scene.toml").write_text(
        '[[material]]\nname = "skin"\nalbedo = "tex/alb.$UDIM.exr"\nmfp = 1.0\n'
        'output = "out/skin.u<U>_v<V>.exr"\n'
        '[[material]]\nname = "bad"\nalbedo = "tex/alb.$UDIM.exr"\nmfp = 1.0\n'
        'output = "out/bad.<f>.exr"\n')
    plan = load(tmp_path / "scene.toml").plan()
    outs = sorted(j.output.rsplit("/", 1)[1] for j in plan.jobs if j.name == "skin")
    assert outs == ["skin.u10_v1.exr", "skin.u1_v1.exr", "skin.u1_v2.exr"], plan.describe()
    bad = [j for j in plan.jobs if j.name == "bad"]
    assert bad and all("<f> is Maya's frame token" in (j.problem or "") for j in bad)


def test_the_blur_command_takes_tile_patterns(tmp_path, capsys, on_device):
    """blur irr.<udim>.exr -o out.$UDIM.exr blurs each tile into its own output (it wrote one
    file literally named out.<udim>.exr, or found no such file); an albedo texture pattern
    is filled per tile."""
    for name in ("1001", "1002"):
        write_exr(tmp_path / f"irr.{name}.exr", np.full((6, 8, 3), 0.5, np.float32),
                  ("R", "G", "B"))
        write_exr(tmp_path / f"alb.{name}.exr", np.full((6, 8, 3), 0.6, np.float32),
                  ("R", "G", "B"))
    rc = cli_main(["blur", str(tmp_path / "irr.<udim>.exr"), "--albedo",
                   str(tmp_path / "alb.<UDIM>.exr"), "--mfp", "1", "--no-progress",
                   "-o", str(tmp_path / "o" / "out.$UDIM.exr")])
    assert rc == 0, capsys.readouterr()
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["out.1001.exr",
                                                                  "out.1002.exr"]
    rc = cli_main(["blur", str(tmp_path / "irr.1001.exr"), "--albedo", "0.5", "--mfp", "1",
                   "--no-progress", "-o", str(tmp_path / "p" / "out.<f>.exr")])
    err = capsys.readouterr().err
    assert rc == 1 and "<f> is Maya's frame token" in err, err
    assert not (tmp_path / "p").exists() or not list((tmp_path / "p").iterdir())
