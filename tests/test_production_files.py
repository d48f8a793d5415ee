"""A production's files, as a hostile new user brings them: every input format, every output
checked, every signal obeyed (docs/safety.md). Each test writes its own real files (tiled
mip-mapped EXRs by ``make_texture``, RGBA PNGs with unassociated alpha, multi-part and deep
EXRs, a FIFO, a file size limit for the full disk) and asserts the exit code, the message and
what happened to the files."""
import json
import os
import resource
import signal
import subprocess
import sys
import time

import numpy as np
import OpenImageIO as oiio
import pytest

from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.io import scene as scenes
from bdipole_cl.io.batch import process_textures


def write(path, pixels, names=None, fmt="float", tile=0, window=(0, 0), extra=None):
    pixels = np.ascontiguousarray(pixels, np.float32)
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, fmt)
    spec.x, spec.y = window
    spec.full_x, spec.full_y = window
    if names:
        spec.channelnames = tuple(names)
    if tile:
        spec.tile_width = spec.tile_height = tile
    for k, v in (extra or {}).items():
        spec.attribute(k, v)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec), oiio.geterror()
    assert out.write_image(pixels)
    out.close()
    return path


def read(path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    px = np.asarray(inp.read_image(oiio.FLOAT))
    spec = inp.spec()
    inp.close()
    return px, spec


def ramp(h=16, w=12, c=3, lo=0.1, hi=0.8):
    v = np.linspace(lo, hi, h * w * c, dtype=np.float32).reshape(h, w, c)
    return v


def run_cli(*argv, timeout=120, **kw):
    """The CLI in a subprocess: (returncode, stdout, stderr)."""
    p = subprocess.run([sys.executable, "-m", "bdipole_cl", *map(str, argv)],
                       capture_output=True, text=True, timeout=timeout, **kw)
    return p.returncode, p.stdout, p.stderr


def snapshot(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def scene(tmp_path, text):
    path = tmp_path / "scene.toml"
    path.write_text(text)
    return path


# {{{ class 1: an output may never land on any input of the run

def test_scene_output_on_its_mfp_or_another_materials_mask_is_refused(tmp_path, capsys):
    (tmp_path / "tex").mkdir()
    write(tmp_path / "tex" / "a.exr", ramp())
    write(tmp_path / "tex" / "b.exr", ramp())
    write(tmp_path / "tex" / "mfp.exr", np.ones((16, 12, 1)), ["Y"])
    write(tmp_path / "tex" / "mask.exr", np.ones((16, 12, 1)), ["Y"])
    before = snapshot(tmp_path / "tex")
    path = scene(tmp_path, '[[material]]\nname = "a"\nalbedo = "tex/a.exr"\n'
                           'mfp = "tex/mfp.exr"\noutput = "tex/mfp.exr"\n'
                           '[[material]]\nname = "b"\nalbedo = "tex/b.exr"\nmfp = 1.0\n'
                           'mask = "tex/mask.exr"\noutput = "tex/out_b.exr"\n'
                           '[[material]]\nname = "c"\nalbedo = "tex/a.exr"\nmfp = 1.0\n'
                           'output = "tex/mask.exr"\n')
    rc = cli_main(["bake", str(path), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 1
    assert "would overwrite an input (its own mfp" in err, err
    assert "would overwrite an input" in err and "'s mask" in err, err
    after = snapshot(tmp_path / "tex")
    assert {k: after[k] for k in before} == before           # no input touched
    assert "out_b.exr" in after                               # the good job still ran


def test_bake_previews_never_land_on_a_file_of_the_run(tmp_path, capsys):
    """A contact sheet goes beside its output (out.preview.png): where that is another
    material's albedo, bake --preview --force drew the sheet over it, and the next bake
    inverted the sheet. The pictures are outputs of the run's collision check, checked
    before any work: the job whose sheet would land there does not run, forced or not (exit
    1), and the others do."""
    tex = tmp_path / "tex"
    tex.mkdir()
    write(tex / "a.exr", ramp())
    png = oiio.ImageBuf(oiio.ImageSpec(12, 16, 3, "uint8"))
    oiio.ImageBufAlgo.fill(png, (0.4, 0.3, 0.2))
    assert png.write(str(tex / "paint.preview.png"))
    before = snapshot(tex)
    path = scene(tmp_path, '[[material]]\nname = "a"\nalbedo = "tex/a.exr"\nmfp = 1.0\n'
                           'output = "tex/paint.exr"\n[[material]]\nname = "b"\n'
                           'albedo = "tex/paint.preview.png"\nmfp = 1.0\n'
                           'output = "tex/b_out.exr"\non_invalid = "clamp"\n')
    for force in ([], ["--force"]):
        rc = cli_main(["bake", str(path), "--preview", "--no-progress", *force])
        err = capsys.readouterr().err
        # the job whose sheet would land on b's albedo does not run (exit 1); b does
        assert rc == 1 and "--preview: contact sheet of" in err and "would overwrite an input" \
            in err and "albedo" in err, err
        after = snapshot(tex)
        assert {k: after[k] for k in before} == before        # no input touched
        assert "paint.exr" not in after and "b_out.exr" in after, sorted(after)


def three_material_scene(tmp_path):
    for name in ("a", "b", "c"):
        write(tmp_path / f"{name}.exr", ramp())
    return scene(tmp_path, "".join(f'[[material]]\nname = "{n}"\nalbedo = "{n}.exr"\n'
                                   f'mfp = 1.0\noutput = "{n}_out.exr"\n' for n in "abc"))


def ctrl_c_after(monkeypatch, owner, name):
    """``owner.name`` replaced by itself followed by a SIGINT to this process; the list of
    its results so far."""
    real, done = getattr(owner, name), []

    def then_ctrl_c(*a, **k):
        done.append(real(*a, **k))
        os.kill(os.getpid(), signal.SIGINT)
        return done[-1]
    monkeypatch.setattr(owner, name, then_ctrl_c)
    return done


def test_a_stop_during_bake_previews_ends_them(tmp_path, monkeypatch, capsys):
    """Ctrl-C while bake --preview draws its sheets: the pictures end there (the sheet being
    drawn whole, no page), and the command exits 130, not 0 after drawing everything."""
    pytest.importorskip("matplotlib")
    from bdipole_cl.apps import bake_page
    path = three_material_scene(tmp_path)
    drawn = ctrl_c_after(monkeypatch, bake_page, "contact_sheet")
    rc = cli_main(["bake", str(path), "--preview", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 130 and "during the previews" in err, err
    assert len(drawn) == 1 and not (tmp_path / "scene.preview.png").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_a_stop_while_a_bake_plans_ends_it_before_any_job(tmp_path, monkeypatch, capsys):
    """Ctrl-C during bake's planning (its statistics pass over many tiles): the command ends
    there (exit 130), nothing written; it went on planning every tile, then (on a cluster)
    started the jobs."""
    from bdipole_cl.jobs import scene as scene_jobs
    path = three_material_scene(tmp_path)
    planned = ctrl_c_after(monkeypatch, scene_jobs, "_plan_invert")
    rc = cli_main(["bake", str(path), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 130 and "while planning: nothing written" in err, err
    assert len(planned) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.exr", "b.exr", "c.exr",
                                                          "scene.toml"]


def test_skipped_jobs_inputs_are_still_inputs(tmp_path):
    tex = tmp_path / "tex"
    tex.mkdir()
    write(tex / "a.exr", ramp())
    time.sleep(0.02)
    write(tex / "a.tif", ramp(), fmt="uint16")
    before = (tex / "a.exr").read_bytes()
    rep = process_textures(str(tex / "*"), output="{dir}/{stem}.exr", skip_existing=True)
    assert rep.exit_code == 1, rep.summary()
    assert (tex / "a.exr").read_bytes() == before
    assert all("would overwrite an input" in r.error for r in rep.results), rep.summary()


def test_a_hard_link_to_an_input_is_the_input(tmp_path):
    write(tmp_path / "a.exr", ramp())
    os.link(tmp_path / "a.exr", tmp_path / "linked.exr")
    before = (tmp_path / "a.exr").read_bytes()
    rep = process_textures(str(tmp_path / "a.exr"), output=str(tmp_path / "linked.exr"))
    assert rep.exit_code == 1 and "would overwrite an input" in rep.results[0].error
    assert (tmp_path / "a.exr").read_bytes() == before


def test_cluster_blur_onto_its_input_is_refused_before_any_task(tmp_path):
    from bdipole_cl.dask import blur_file_on_cluster
    write(tmp_path / "irr.exr", ramp())
    before = (tmp_path / "irr.exr").read_bytes()
    with pytest.raises(ValueError, match="would overwrite an input"):
        blur_file_on_cluster(tmp_path / "irr.exr", tmp_path / "irr.exr", None, albedo=0.5,
                             mfp=1.0)
    assert (tmp_path / "irr.exr").read_bytes() == before


def test_collision_message_is_on_the_right_files_row(tmp_path):
    write(tmp_path / "a.exr", ramp())
    write(tmp_path / "b.exr", ramp())
    rep = process_textures([str(tmp_path / "a.exr"), str(tmp_path / "b.exr")],
                           output=str(tmp_path / "same.exr"))
    for r in rep.results:
        assert r.error.startswith(r.path + ":"), rep.summary()

# }}}

# {{{ class 1b: an output replaces only what bdipole-cl wrote, or what --force allows

def painted(path, value=0.3):
    """A file the user made (no bdipole:version): an 8x8 EXR, or a PNG by suffix."""
    if str(path).endswith(".png"):
        write(path, np.full((8, 8, 3), value, np.float32), fmt="uint8")
    else:
        write(path, np.full((8, 8, 3), value, np.float32))
    return path.read_bytes()


def test_preview_never_writes_onto_its_input_or_a_users_picture(tmp_path, capsys):
    write(tmp_path / "a.exr", ramp())
    before = painted(tmp_path / "paint.png")
    for target, why in ((tmp_path / "paint.png", "would overwrite an input"),):
        rc = cli_main(["preview", str(tmp_path / "paint.png"), "-o", str(target)])
        assert rc == 2 and why in capsys.readouterr().err
    rc = cli_main(["preview", str(tmp_path / "a.exr"), "-o", str(tmp_path / "paint.png")])
    assert rc == 2 and "not written by bdipole-cl" in capsys.readouterr().err
    assert (tmp_path / "paint.png").read_bytes() == before
    rc = cli_main(["preview", str(tmp_path / "a.exr"), "-o", str(tmp_path / "a2.exr")])
    assert rc == 2 and "a picture is PNG or SVG" in capsys.readouterr().err
    for suffix in (".png", ".svg"):                      # its own sheet it may replace
        out = tmp_path / f"sheet{suffix}"
        assert cli_main(["preview", str(tmp_path / "a.exr"), "-o", str(out)]) == 0
        assert cli_main(["preview", str(tmp_path / "a.exr"), "-o", str(out)]) == 0, \
            capsys.readouterr().err
    assert cli_main(["preview", str(tmp_path / "a.exr"), "-o", str(tmp_path / "paint.png"),
                     "--force"]) == 0
    assert (tmp_path / "paint.png").read_bytes() != before
    before = painted(tmp_path / "p.png")
    rc = cli_main(["profile", "--albedo", "0.5", "--mfp", "1", "-o", str(tmp_path / "p.png")])
    assert rc == 2 and "not written by bdipole-cl" in capsys.readouterr().err
    assert (tmp_path / "p.png").read_bytes() == before


def test_invert_and_blur_never_replace_a_file_they_did_not_write(tmp_path, capsys):
    write(tmp_path / "a.exr", ramp())
    before = painted(tmp_path / "precious.exr")
    rep = process_textures(str(tmp_path / "a.exr"), output=str(tmp_path / "precious.exr"))
    assert rep.exit_code == 1 and "not written by bdipole-cl" in rep.results[0].error
    rc = cli_main(["blur", str(tmp_path / "a.exr"), "--albedo", "0.5", "--mfp", "1",
                   "-o", str(tmp_path / "precious.exr"), "--no-progress"])
    assert rc == 2 and "not written by bdipole-cl" in capsys.readouterr().err
    assert (tmp_path / "precious.exr").read_bytes() == before
    (tmp_path / "adir.exr").mkdir()
    rep = process_textures(str(tmp_path / "a.exr"), output=str(tmp_path / "adir.exr"),
                           force=True)
    assert "is a directory" in rep.results[0].error           # never, even forced
    # its own outputs it replaces; a foreign one only when forced
    for out in ("inv.exr", "precious.exr"):
        force = out == "precious.exr"
        for _ in range(2):
            rep = process_textures(str(tmp_path / "a.exr"), output=str(tmp_path / out),
                                   force=force)
            assert rep.exit_code == 0, rep.summary()
    for _ in range(2):
        assert cli_main(["blur", str(tmp_path / "a.exr"), "--albedo", "0.5", "--mfp", "1",
                         "-o", str(tmp_path / "sss.exr"), "--no-progress"]) == 0


def test_only_this_tools_mark_makes_a_file_its_own(tmp_path):
    """An unrelated bdipole: attribute is not the mark, and a texture another tool made from
    one of its outputs (maketx copies the whole header), or an edit of one by another tool,
    is the user's; its own outputs and texture outputs it replaces."""
    write(tmp_path / "a.exr", ramp())
    spec = oiio.ImageSpec(8, 8, 3, "float")
    spec.attribute("bdipole:note", "a studio's own tag")
    out = oiio.ImageOutput.create(str(tmp_path / "tagged.exr"))
    out.open(str(tmp_path / "tagged.exr"), spec)
    out.write_image(np.zeros((8, 8, 3), np.float32))
    out.close()
    assert process_textures(str(tmp_path / "a.exr"),
                            output=str(tmp_path / "plain.exr")).exit_code == 0
    oiio.ImageBufAlgo.make_texture(oiio.MakeTxTexture, oiio.ImageBuf(str(tmp_path / "plain.exr")),
                                   str(tmp_path / "tx.exr"), oiio.ImageSpec())
    # an output edited by another tool (as `oiiotool plain.exr --mulc 2 -o edited.exr`: the
    # header kept, Software its own) is the user's too
    edited = oiio.ImageBufAlgo.mul(oiio.ImageBuf(str(tmp_path / "plain.exr")), 2.0)
    edited.specmod().attribute("Software", "OpenImageIO 3.2.2.0 : oiiotool")
    assert edited.write(str(tmp_path / "edited.exr"))
    assert oiio.ImageBuf(str(tmp_path / "edited.exr")).spec().getattribute("bdipole:version")
    for name in ("tagged.exr", "tx.exr", "edited.exr"):
        before = (tmp_path / name).read_bytes()
        rep = process_textures(str(tmp_path / "a.exr"), output=str(tmp_path / name))
        assert "not written by bdipole-cl" in rep.results[0].error, (name, rep.summary())
        assert (tmp_path / name).read_bytes() == before
    for _ in range(2):                                   # its own texture output, again
        assert process_textures(str(tmp_path / "a.exr"), output=str(tmp_path / "t.exr"),
                                texture=True).exit_code == 0


def test_an_svg_that_only_mentions_the_mark_is_the_users(tmp_path, capsys):
    """A hand-made SVG whose comment contains the words 'bdipole_cl preview' was replaced by
    profile -o: the mark is the creator element this tool's sheets carry."""
    from bdipole_cl.io.collisions import ours
    svg = tmp_path / "mine.svg"
    svg.write_text('<svg xmlns="http://www.w3.org/2000/svg"><!-- not a bdipole_cl preview -->'
                   '<rect width="4" height="4"/></svg>')
    before = svg.read_bytes()
    assert not ours(svg)
    rc = cli_main(["profile", "--albedo", "0.8", "--mfp", "1", "-o", str(svg)])
    assert rc == 2 and "not written by bdipole-cl" in capsys.readouterr().err
    assert svg.read_bytes() == before
    assert cli_main(["profile", "--albedo", "0.8", "--mfp", "1", "-o",
                     str(tmp_path / "p.svg")]) == 0
    assert ours(tmp_path / "p.svg")


def test_bake_never_replaces_an_output_it_did_not_write(tmp_path, capsys):
    write(tmp_path / "a.exr", ramp())
    path = scene(tmp_path, '[[material]]\nname = "a"\nalbedo = "a.exr"\nmfp = 1.0\n'
                           'output = "out/a_sss.exr"\n')
    (tmp_path / "out").mkdir()
    before = painted(tmp_path / "out" / "a_sss.exr")
    assert cli_main(["bake", str(path), "--no-progress"]) == 1
    assert "not written by bdipole-cl" in capsys.readouterr().err
    assert (tmp_path / "out" / "a_sss.exr").read_bytes() == before
    assert cli_main(["bake", str(path), "--no-progress", "--force"]) == 0
    assert cli_main(["bake", str(path), "--no-progress"]) == 0        # now its own

# }}}


# {{{ class 2: production image formats

def test_mip_mapped_tiled_albedo_gives_a_plain_complete_output(tmp_path):
    src = oiio.ImageBuf(oiio.ImageSpec(64, 32, 3, "float"))
    src.set_pixels(oiio.ROI(), np.full((32, 64, 3), 0.5, np.float32))
    assert oiio.ImageBufAlgo.make_texture(oiio.MakeTxTexture, src, str(tmp_path / "a.tx.exr"),
                                          oiio.ImageSpec())
    rep = process_textures(str(tmp_path / "a.tx.exr"), output=str(tmp_path / "out.exr"))
    assert rep.exit_code == 0, rep.summary()
    px, spec = read(tmp_path / "out.exr")
    assert np.all(np.isfinite(px)) and px.shape == (32, 64, 6)
    for stat in ("oiio:ConstantColor", "oiio:AverageColor", "oiio:miplevels"):
        assert spec.getattribute(stat) in (None, 1), (stat, spec.getattribute(stat))
    inp = oiio.ImageInput.open(str(tmp_path / "out.exr"))
    assert not inp.seek_subimage(0, 1), "a mip level the output does not hold is declared"
    inp.close()


def test_tiled_irradiance_is_read_in_bands(tmp_path):
    e = np.random.default_rng(0).uniform(0, 1, (100, 40, 3)).astype(np.float32)
    write(tmp_path / "tiled.exr", e, tile=32)
    write(tmp_path / "lines.exr", e)
    for name in ("tiled", "lines"):
        rc = cli_main(["blur", str(tmp_path / f"{name}.exr"), "--albedo", "0.7", "--mfp", "2",
                       "--max-memory", "64K",
                       "-o", str(tmp_path / f"{name}_out.exr")])
        assert rc == 0, name
    # bands of whole tiles and bands of scanlines: other FFT shapes, so the float32 FFT's
    # round-off differs between the two (by ~1 ulp; its bound is FFT32_ROUNDOFF x max(E) x Rd);
    # a misread tile or row would be off by a sizeable part of E
    from bdipole_cl.ops.blur.fft import FFT32_ROUNDOFF
    np.testing.assert_allclose(read(tmp_path / "tiled_out.exr")[0],
                               read(tmp_path / "lines_out.exr")[0],
                               rtol=0, atol=2 * FFT32_ROUNDOFF * e.max() * 0.7)


@pytest.mark.parametrize("ext", ["png", "tif"])
def test_painted_colour_is_not_changed_by_its_alpha(tmp_path, ext):
    px = np.zeros((4, 8, 4), np.float32)
    px[..., :3] = 0.6
    px[:, :4, 3] = 0.25
    px[:, 4:, 3] = 1.0
    path = write(tmp_path / f"a.{ext}", px, ["R", "G", "B", "A"], fmt="uint8",
                 extra={"oiio:UnassociatedAlpha": 1})
    rep = process_textures(str(path), outputs=("alpha",), output=str(tmp_path / "o.exr"),
                           colorspace="linear")
    assert rep.exit_code == 0, rep.summary()
    out, spec = read(tmp_path / "o.exr")
    out = out[..., [spec.channelnames.index(f"alpha.{c}") for c in "RGB"]]
    np.testing.assert_array_equal(out[:, :4], out[:, 4:])           # same colour, same alpha'


def test_multi_part_exr_is_refused_naming_its_parts(tmp_path):
    path = str(tmp_path / "parts.exr")
    specs = []
    for name in ("diffuse", "spec"):
        s = oiio.ImageSpec(8, 8, 3, "float")
        s.attribute("name", name)
        specs.append(s)
    out = oiio.ImageOutput.create(path)
    assert out.open(path, specs)
    out.write_image(np.full((8, 8, 3), 0.5, np.float32))
    assert out.open(path, specs[1], "AppendSubimage")
    out.write_image(np.full((8, 8, 3), 0.2, np.float32))
    out.close()
    rep = process_textures(path, output=str(tmp_path / "o.exr"))
    assert rep.exit_code == 1 and "2 parts (diffuse, spec)" in rep.results[0].error
    assert not (tmp_path / "o.exr").exists()


def test_deep_exr_is_refused(tmp_path):
    path = str(tmp_path / "deep.exr")
    spec = oiio.ImageSpec(4, 4, 4, "float")
    spec.channelnames = ("R", "G", "B", "A")
    spec.deep = True
    buf = oiio.ImageBuf(spec)
    for y in range(4):
        for x in range(4):
            buf.set_deep_samples(x, y, 0, 1)
            for c in range(4):
                buf.set_deep_value(x, y, 0, c, 0, 0.5)
    assert buf.write(path), buf.geterror()
    rep = process_textures(path, output=str(tmp_path / "o.exr"))
    assert rep.exit_code == 1 and "deep image" in rep.results[0].error, rep.summary()
    assert not (tmp_path / "o.exr").exists()


def test_lab_channels_are_not_colour_and_alpha(tmp_path):
    write(tmp_path / "lab.exr", ramp(), ["L", "a", "b"])
    rep = process_textures(str(tmp_path / "lab.exr"), output=str(tmp_path / "o.exr"))
    assert rep.exit_code == 1 and "not linear RGB" in rep.results[0].error, rep.summary()
    assert not (tmp_path / "o.exr").exists()


@pytest.mark.parametrize("names, left", [
    (["R", "G", "B", "A", "P.x", "P.y", "P.z"], ["P.x", "P.y", "P.z"]),
    (["R", "G", "B", "motion.x", "motion.y"], ["motion.x", "motion.y"]),
    (["R", "G", "B", "N.x", "N.y", "N.z", "uv.x", "uv.y"], ["N.x", "N.y", "N.z", "uv.x", "uv.y"]),
    (["R", "G", "B", "Y"], ["Y"]), (["R", "G", "B", "L"], ["L"]),
    (["R", "G", "B", "A", "P.X", "P.Y", "P.Z"], ["P.X", "P.Y", "P.Z"]),
    (["R", "G", "B", "A", "N.R", "N.G", "N.B"], ["N.R", "N.G", "N.B"])])
def test_vectors_and_a_luminance_beside_rgb_are_left_out(tmp_path, names, left):
    """A vector's y component (N.y, P.y, motion.y) is not a luminance Y, and a luminance
    beside R, G and B is not a fourth colour: only R, G, B are inverted (A kept), the rest
    named as left out, and a colour conversion still finds its R, G and B."""
    px = np.concatenate([ramp(), np.full((16, 12, len(names) - 3), 0.5, np.float32)], axis=2)
    write(tmp_path / "alb.exr", px, names)
    out = tmp_path / "o.exr"
    rep = process_textures(str(tmp_path / "alb.exr"), mfp=1.0, output=str(out),
                           working_space="ACEScg", colorspace="lin_rec709_scene")
    assert rep.exit_code == 0, rep.summary()
    got = read(out)[1].channelnames
    assert not any(n.endswith(tuple("." + x for x in left)) for n in got), got
    assert {n.rsplit(".", 1)[-1] for n in got if n.startswith("sigma_a")} == {"R", "G", "B"}
    assert ("A" in names) == ("A" in got)
    notes = " ".join(rep.results[0].notes)
    assert all(x in notes for x in left), notes


def test_one_colour_layer_is_inverted_and_a_vector_is_not_colour(tmp_path):
    """diffuse.R/G/B beside specular.R/G/B: the first layer is the albedo, the other left out
    (both were inverted); P.X, P.Y, P.Z alone have no colour (P.Y was inverted as grey)."""
    names = ["diffuse.R", "diffuse.G", "diffuse.B", "specular.R", "specular.G", "specular.B"]
    write(tmp_path / "aov.exr", np.concatenate([ramp(), ramp()], axis=2), names)
    rep = process_textures(str(tmp_path / "aov.exr"), mfp=1.0, output=str(tmp_path / "o.exr"))
    assert rep.exit_code == 0, rep.summary()
    got = read(tmp_path / "o.exr")[1].channelnames
    # each output's channels named {output}.{R, G, B}: never sigma_a.diffuse.R
    assert got == tuple(f"{o}.{c}" for o in ("sigma_a", "sigma_s") for c in "RGB"), got
    write(tmp_path / "p.exr", ramp(), ["P.X", "P.Y", "P.Z"])
    rep = process_textures(str(tmp_path / "p.exr"), mfp=1.0, output=str(tmp_path / "p_o.exr"))
    assert rep.exit_code == 1 and "no colour channel" in rep.results[0].error, rep.summary()


def test_albedo_and_mfp_with_different_data_windows_are_refused(tmp_path):
    write(tmp_path / "a.exr", ramp(8, 8))
    write(tmp_path / "a_mfp.exr", np.ones((8, 8, 1)), ["Y"], window=(4, 0))
    rep = process_textures(str(tmp_path / "a.exr"), mfp=str(tmp_path / "{stem}_mfp.exr"),
                           output=str(tmp_path / "o.exr"))
    assert rep.exit_code == 1 and "data windows" in rep.results[0].error, rep.summary()

def test_integer_and_luminance_chroma_exrs_are_refused_by_name(tmp_path):
    """A UINT EXR (IDs, counts) would be scaled by 1 / (2^32 - 1) as a normalized colour, and
    Y/RY/BY (OpenEXR luminance/chroma) would be read as grey Y: both refused, named."""
    spec = oiio.ImageSpec(8, 8, 3, "uint")
    out = oiio.ImageOutput.create(str(tmp_path / "ids.exr"))
    out.open(str(tmp_path / "ids.exr"), spec)
    out.write_image(np.full((8, 8, 3), 900, np.uint32))
    out.close()
    write(tmp_path / "yc.exr", np.full((8, 8, 3), 0.5, np.float32), ["Y", "RY", "BY"])
    write(tmp_path / "ok.exr", ramp())
    rep = process_textures([str(tmp_path / n) for n in ("ids.exr", "yc.exr", "ok.exr")],
                           output="{dir}/{stem}_out.exr")
    ids, yc, ok = rep.results
    assert "32-bit integers" in ids.error and "R, G, B" in ids.error, ids.error
    assert "not linear RGB" in yc.error, yc.error
    assert ok.status == "ok", rep.summary()

# }}}


# {{{ class 3: a written file is checked, and a re-run proves it complete

def _limit_file_size(limit):
    def apply():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)      # a write past it fails (EFBIG)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return apply


@pytest.mark.parametrize("tile", [0, 32], ids=["scanline", "tiled"])
def test_full_disk_fails_the_file_and_leaves_nothing(tmp_path, tile):
    px = np.random.default_rng(1).uniform(0.1, 0.9, (128, 128, 3)).astype(np.float32)
    write(tmp_path / "a.exr", px, tile=tile)
    rc, out, err = run_cli("invert", tmp_path / "a.exr", "-o",
                           tmp_path / "out" / "{stem}.exr")
    assert rc == 0, out + err
    full = os.path.getsize(tmp_path / "out" / "a.exr")
    os.remove(tmp_path / "out" / "a.exr")
    rc, out, err = run_cli("invert", tmp_path / "a.exr", "--no-progress", "-o",
                           tmp_path / "out" / "{stem}.exr", preexec_fn=_limit_file_size(full - 10))
    assert rc == 1 and "failed" in out and " ok " not in out, out + err
    assert os.listdir(tmp_path / "out") == []


SCENE = '[[material]]\nname = "m"\nalbedo = "a.exr"\nmfp = 1.0\noutput = "out/a.exr"\n'


def test_truncated_output_with_its_header_is_not_up_to_date(tmp_path):
    write(tmp_path / "a.exr", np.random.default_rng(2).uniform(0.1, 0.9, (64, 64, 3)))
    path = scene(tmp_path, SCENE)
    assert scenes.load(path).plan().run().exit_code == 0
    out = tmp_path / "out" / "a.exr"
    data = out.read_bytes()
    out.write_bytes(data[:len(data) * 2 // 3])
    job = scenes.load(path).plan().jobs[0]
    assert not job.up_to_date
    assert scenes.load(path).plan().run().exit_code == 0
    assert read(out)[0].shape == (64, 64, 6)


def test_content_changed_with_size_and_time_restored_is_rebuilt(tmp_path):
    px = np.random.default_rng(3).uniform(0.1, 0.9, (16, 16, 3)).astype(np.float32)
    write(tmp_path / "a.exr", px)
    path = scene(tmp_path, SCENE)
    assert scenes.load(path).plan().run().exit_code == 0
    st = os.stat(tmp_path / "a.exr")
    px[3, 4] = 0.2                                  # same size: an uncompressed float file
    write(tmp_path / "b.exr", px)
    data = (tmp_path / "b.exr").read_bytes()
    with open(tmp_path / "a.exr", "r+b") as f:      # rewritten in place, as an editor may
        f.write(data)
        f.truncate(len(data))
    os.utime(tmp_path / "a.exr", ns=(st.st_atime_ns, st.st_mtime_ns))     # touch -r
    assert os.path.getsize(tmp_path / "a.exr") == st.st_size
    assert not scenes.load(path).plan().jobs[0].up_to_date

# }}}


# {{{ class 4: every written value finite, or its texel invalid and counted

@pytest.mark.parametrize("mfp", ["1e-38", "1e-40"])
def test_tiny_mfp_is_never_written_as_infinite_coefficients(tmp_path, mfp):
    write(tmp_path / "a.exr", ramp(4, 4))
    with pytest.raises(SystemExit) as usage:                # a constant out of range
        cli_main(["invert", str(tmp_path / "a.exr"), "--mfp", mfp, "--no-progress",
                  "-o", str(tmp_path / "o.exr")])
    assert usage.value.code == 2 and not (tmp_path / "o.exr").exists()
    with pytest.raises(ValueError, match=f"mfp {float(mfp):g} x mfp_scale 1 "):
        process_textures(str(tmp_path / "a.exr"), mfp=float(mfp), output=str(tmp_path / "o.exr"))
    rep = process_textures(str(tmp_path / "a.exr"), mfp=float(mfp), on_invalid="clamp",
                           output=str(tmp_path / "o.exr"))
    # below MFP_MIN (1e-20) an mfp is invalid (its coefficients would overflow float32):
    # clamped to it and counted
    assert rep.exit_code == 0 and rep.results[0].invalid["mfp"] > 0, rep.summary()
    assert np.all(np.isfinite(read(tmp_path / "o.exr")[0]))


def test_half_blur_of_a_highlight_is_never_inf(tmp_path, capsys):
    e = np.zeros((16, 16, 3), np.float32)
    e[8, 8] = 1e6
    write(tmp_path / "irr.exr", e)
    rc = cli_main(["blur", str(tmp_path / "irr.exr"), "--albedo", "0.8", "--mfp", "0.5",
                   "--half", "-o", str(tmp_path / "o.exr")])
    err = capsys.readouterr().err
    assert rc == 1 and "half-float range" in err and "x=8, y=8" in err, err
    assert not (tmp_path / "o.exr").exists()
    rc = cli_main(["blur", str(tmp_path / "irr.exr"), "--albedo", "0.8", "--mfp", "0.5",
                   "--half", "--on-invalid", "clamp",
                   "-o", str(tmp_path / "o.exr")])
    px = read(tmp_path / "o.exr")[0]
    assert rc == 0 and np.all(np.isfinite(px))
    assert px[0, 0, 0] == px[0, 0, 0] and px[0, 0, 0] < 1e4     # far texels: as computed



@pytest.mark.parametrize("albedo", ["0.8", "texture"])
def test_half_blur_of_one_texel_among_zeros_writes_no_round_off(tmp_path, capsys, albedo):
    # the FFT's -1e-18 of an unlit texel is not light, nor invalid for half: written as 0
    e = np.zeros((48, 48, 3), np.float32)
    e[20, 30] = 1.0
    write(tmp_path / "irr.exr", e)
    if albedo == "texture":
        write(tmp_path / "alb.exr", np.full((48, 48, 3), 0.7, np.float32))
        albedo = str(tmp_path / "alb.exr")
    for fmt in ("--half", "--no-progress"):
        rc = cli_main(["blur", str(tmp_path / "irr.exr"), "--albedo", albedo, "--mfp", "3",
                       "--method", "fft", fmt, "-o", str(tmp_path / "o.exr")])
        err = capsys.readouterr().err
        assert rc == 0, err
        px = read(tmp_path / "o.exr")[0]
        assert px.min() >= 0 and px[0, 0, 0] == 0 and px[20, 30, 0] > 0.1, px.min()
# }}}


# {{{ class 5: signals and hangs

def test_one_band_blur_obeys_sigint_within_seconds(tmp_path):
    # 1024^2 at mfp 30 (radius ~126): ~2e11 taps, ~20 s on the 2-core AVX-512 machine
    # without the stop checks (512^2 at mfp 20 took 2.4 s there, under the 3 s before the
    # signal; ~15 s on the older AVX one), a launch ~0.1-0.5 s with them
    e = np.random.default_rng(0).uniform(0, 1, (1024, 1024, 3)).astype(np.float32)
    write(tmp_path / "irr.exr", e)
    proc = subprocess.Popen([sys.executable, "-m", "bdipole_cl", "--device", "intel", "blur",
                             str(tmp_path / "irr.exr"), "--albedo", "0.8", "--mfp", "30",
                             "--method", "direct",
                             "-o", str(tmp_path / "o.exr")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(3)
    assert proc.poll() is None, "the blur ended before the signal"
    proc.send_signal(signal.SIGINT)
    t0 = time.monotonic()
    out, err = proc.communicate(timeout=120)
    waited = time.monotonic() - t0
    assert proc.returncode == 130 and waited < 8, (proc.returncode, waited, out, err)
    assert "interrupted" in err and "Traceback" not in err
    assert sorted(os.listdir(tmp_path)) == ["irr.exr"]


@pytest.mark.parametrize("method, sig", [("gaussians", signal.SIGINT), ("fft", signal.SIGTERM)])
def test_texture_varying_blur_obeys_a_signal_within_seconds(tmp_path, method, sig):
    # mfp 60 texels at tol 1e-5: the plan's node kernels (radius ~ 500) and fits take minutes
    # on 2 cores; each is checked for a stop within ~0.1-1 s (rows of a node kernel, one fit)
    rng = np.random.default_rng(1)
    write(tmp_path / "irr.exr", rng.uniform(0, 1, (64, 64, 3)))
    write(tmp_path / "alb.exr", rng.uniform(0.1, 0.9, (64, 64, 3)))
    proc = subprocess.Popen([sys.executable, "-m", "bdipole_cl", "--device", "intel", "blur",
                             str(tmp_path / "irr.exr"), "--albedo", str(tmp_path / "alb.exr"),
                             "--mfp", "30", "--texel-size", "0.5", "--method", method,
                             "--tol", "1e-5", "-o", str(tmp_path / "o.exr")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(3)
    assert proc.poll() is None, "the blur ended before the signal"
    proc.send_signal(sig)
    t0 = time.monotonic()
    try:
        out, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise AssertionError("the signal was not obeyed within 30 s") from None
    waited = time.monotonic() - t0
    assert proc.returncode == 128 + sig and waited < 4, (proc.returncode, waited, out, err)
    assert "interrupted" in err and "Traceback" not in err
    assert sorted(os.listdir(tmp_path)) == ["alb.exr", "irr.exr"]


def test_a_fifo_is_refused_not_waited_on(tmp_path):
    os.mkfifo(tmp_path / "pipe.exr")
    rc, out, err = run_cli("invert", tmp_path / "pipe.exr", "-o",
                           tmp_path / "o.exr", timeout=60)
    assert rc == 1 and "not a regular file" in out, out + err


def test_a_worker_memory_no_worker_can_run_in_is_one_line(capsys):
    rc = cli_main(["blur", "x.exr", "--albedo", "0.5", "--mfp", "1", "--scheduler", "local:2",
                   "--worker-memory", "10M", "-o", "o.exr"])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "at least" in err, err

def test_a_signal_during_blurs_last_write_never_exits_0(tmp_path, monkeypatch, capsys):
    """SIGTERM arriving as the output's last band is written (the run then finishes: the file
    is complete) still exits 143, and says the output is complete."""
    from bdipole_cl.jobs import runner
    write(tmp_path / "irr.exr", ramp())
    real = runner.run_job

    def run_then_signal(*a, **kw):
        result = real(*a, **kw)
        os.kill(os.getpid(), signal.SIGTERM)             # the handler only records it
        return result
    monkeypatch.setattr(runner, "run_job", run_then_signal)
    try:
        rc = cli_main(["blur", str(tmp_path / "irr.exr"), "--albedo", "0.5", "--mfp", "1",
                       "-o", str(tmp_path / "o.exr"), "--no-progress"])
    finally:                            # this process goes on: un-stopped, SIGTERM its own
        from bdipole_cl.signals import STOP
        STOP.clear()
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
    assert rc == 128 + signal.SIGTERM
    assert "it is complete" in capsys.readouterr().err
    assert np.isfinite(read(tmp_path / "o.exr")[0]).all()

# }}}


# {{{ class 6: one bad input never stops the others

def test_a_truncated_tile_and_a_missing_alpha_fail_only_their_jobs(tmp_path, capsys):
    (tmp_path / "tex").mkdir()
    for t in ("1001", "1002"):
        write(tmp_path / "tex" / f"a.{t}.exr", ramp())
    data = (tmp_path / "tex" / "a.1002.exr").read_bytes()
    (tmp_path / "tex" / "a.1002.exr").write_bytes(data[:len(data) // 2])
    path = scene(tmp_path, '[[material]]\nname = "m"\nalbedo = "tex/a.<UDIM>.exr"\n'
                           'mfp = 1.0\nmethod = "auto"\noutput = "out/a.<UDIM>.exr"\n'
                           '[[material]]\nname = "masked"\nalbedo = "tex/a.1001.exr"\n'
                           'mfp = 1.0\nmask = "alpha"\noutput = "out/masked.exr"\n')
    assert cli_main(["plan", str(path)]) == 0
    capsys.readouterr()
    rc = cli_main(["bake", str(path), "--no-progress", "--max-memory", "1M"])
    captured = capsys.readouterr()
    assert rc == 1 and "1 done, 2 failed" in captured.out, captured
    assert os.listdir(tmp_path / "out") == ["a.1001.exr"]

# }}}


# {{{ class 7: one-line messages that name the right file, texel and value

def test_nan_is_reported_at_its_image_coordinates(tmp_path, capsys):
    e = np.ones((96, 20, 3), np.float32)
    e[77, 13, 1] = np.nan
    write(tmp_path / "irr.exr", e, window=(100, 200))
    rc = cli_main(["blur", str(tmp_path / "irr.exr"), "--albedo", "0.5", "--mfp", "1",
                   "--max-memory", "16K", "-o", str(tmp_path / "o.exr")])
    err = capsys.readouterr().err
    assert rc == 1 and "x=113, y=277" in err, err


@pytest.mark.parametrize("argv", [
    ["report", "--n", "0"], ["report", "--repeats", "0"], ["report", "--blur-size", "0"],
    ["blur", "x.exr", "--albedo", "0.5", "--mfp", "1", "--texel-size", "inf", "-o", "o.exr"],
], ids=["n", "repeats", "blur-size", "texel-size-inf"])
def test_bad_numbers_are_usage_errors(argv, capsys):
    with pytest.raises(SystemExit) as stop:            # argparse's exit, as in a shell
        cli_main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "unexpected" not in err, err


def test_texel_size_that_overflows_is_one_line(tmp_path, capsys):
    write(tmp_path / "irr.exr", ramp())
    rc = cli_main(["blur", str(tmp_path / "irr.exr"), "--albedo", "0.5", "--mfp", "1e-20",
                   "--texel-size", "1e300", "-o", str(tmp_path / "o.exr")])
    err = capsys.readouterr().err
    assert rc in (1, 2) and "overflows" in err and "unexpected" not in err, err
    path = scene(tmp_path, '[[material]]\nname = "m"\nalbedo = "irr.exr"\nmfp = 1.0\n'
                           'output = "o.exr"\n[[blur]]\nname = "b"\nmaterial = "m"\n'
                           'irradiance = "irr.exr"\ntexel_size = inf\noutput = "e.exr"\n')
    assert cli_main(["plan", str(path)]) == 2
    err = capsys.readouterr().err
    assert "texel_size" in err and "unexpected" not in err, err


def test_scene_files_in_other_encodings(tmp_path, capsys):
    write(tmp_path / "a.exr", ramp())
    (tmp_path / "bom.toml").write_bytes(b"\xef\xbb\xbf" + SCENE.encode())
    assert cli_main(["plan", str(tmp_path / "bom.toml")]) == 0
    capsys.readouterr()
    (tmp_path / "latin.toml").write_bytes(SCENE.replace('"m"', '"caf\xe9"').encode("latin-1"))
    assert cli_main(["plan", str(tmp_path / "latin.toml")]) == 2
    err = capsys.readouterr().err
    assert "latin.toml:2: not UTF-8" in err, err

def test_a_warning_is_one_line_naming_what_widened_the_bound(tmp_path):
    e = -np.ones((32, 32, 1), np.float32)
    e[12:20, 12:20] = 1.0
    write(tmp_path / "irr.exr", e, ["Y"])
    rc, _, err = run_cli("blur", tmp_path / "irr.exr", "--albedo", "0.8",
                         "--mfp", "1.5", "-o", tmp_path / "o.exr", "--no-progress")
    assert rc == 0, err
    lines = [ln for ln in err.splitlines() if "warning" in ln]
    # the file first: a warning made as the bands are blurred names it too
    assert lines and all(ln.startswith(f"bdipole-cl: warning: {tmp_path / 'irr.exr'}: "
                                       "channel 0: the irradiance has both signs")
                         for ln in lines), err
    assert ".py:" not in err                      # no source file and line, no code shown

# }}}


# {{{ class 8: paths and re-runs

def test_brackets_and_braces_in_real_names_are_literal(tmp_path):
    d = tmp_path / "tex[v2]"
    d.mkdir()
    write(d / "a.exr", ramp())
    out = tmp_path / "proj{v2}" / "{stem}.exr"
    rep = process_textures(str(d / "a.exr"), output=str(out))
    assert rep.exit_code == 0, rep.summary()
    assert (tmp_path / "proj{v2}" / "a.exr").exists()


def test_a_glob_twice_never_inverts_its_own_outputs(tmp_path):
    write(tmp_path / "a.exr", ramp())
    for _ in range(2):
        rc = cli_main(["invert", str(tmp_path / "*.exr"), "--no-progress"])
        assert rc == 0
    assert sorted(os.listdir(tmp_path)) == ["a.bdipole.exr", "a.exr"]


def test_demo_never_writes_into_a_users_folder(tmp_path):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "albedo.exr").write_bytes(b"my work")
    assert cli_main(["demo", "--dir", str(tmp_path / "mine"), "--no-progress"]) == 2
    assert (tmp_path / "mine" / "albedo.exr").read_bytes() == b"my work"


def test_udim_field_without_a_udim_input_writes_nothing(tmp_path):
    write(tmp_path / "a.exr", ramp())
    rep = process_textures(str(tmp_path / "a.exr"), output=str(tmp_path / "s.{udim}.exr"))
    assert rep.exit_code == 1 and "needs a UDIM" in rep.results[0].error
    assert sorted(os.listdir(tmp_path)) == ["a.exr"]

def test_one_file_named_twice_is_one_job(tmp_path, monkeypatch):
    write(tmp_path / "in.exr", ramp())
    os.symlink(tmp_path / "in.exr", tmp_path / "link.exr")
    monkeypatch.chdir(tmp_path)
    rep = process_textures(["in.exr", "./in.exr", str(tmp_path / "in.exr"), "link.exr"],
                           output="o/{stem}.exr")
    assert rep.exit_code == 0 and len(rep.results) == 1, rep.summary()


def test_skip_existing_digest_is_the_same_in_a_new_process(tmp_path):
    """The settings' digest has no per-process part (an object's address): a later run of the
    same command skips."""
    import subprocess
    import sys
    write(tmp_path / "a.exr", ramp())
    code = ("import sys; from bdipole_cl.io.batch import process_textures; "
            f"r = process_textures({str(tmp_path / 'a.exr')!r}, mfp=1.0, skip_existing=True, "
            f"output={str(tmp_path / 'o.exr')!r}, texture=True, working_space='ACEScg'); "
            "print(r.results[0].status)")
    runs = [subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           timeout=120) for _ in range(2)]
    assert [r.stdout.strip().splitlines()[-1] for r in runs] == ["ok", "skipped"], runs

# }}}


# {{{ class 9: the CLI as a newcomer meets it

def test_version_help_and_defaults(capsys):
    from bdipole_cl.version import __version__
    with pytest.raises(SystemExit) as stop:
        cli_main(["--version"])
    assert stop.value.code == 0 and __version__ in capsys.readouterr().out
    with pytest.raises(SystemExit):
        cli_main(["--help"])
    text = capsys.readouterr().out
    assert "``" not in text and "Better Dipole" in text
    with pytest.raises(SystemExit):
        cli_main(["invert", "--help"])
    assert "(default: 256M)" in capsys.readouterr().out


def test_blur_reports_its_texels(tmp_path, capsys):
    write(tmp_path / "irr.exr", ramp())
    assert cli_main(["blur", str(tmp_path / "irr.exr"), "--albedo", "0.5", "--mfp", "1",
                     "-o", str(tmp_path / "o.exr")]) == 0
    assert "192 texels" in capsys.readouterr().out


def test_an_unknown_device_still_lists_the_devices(capsys):
    assert cli_main(["--device", "nonsense", "devices"]) == 1
    captured = capsys.readouterr()
    assert "works" in captured.out and "nonsense" in captured.err

# }}}


def test_a_negative_albedo_texel_is_invalid_not_silently_zero(tmp_path):
    """Below 0 (a painted -0.2, or ACEScg green outside Rec.709's gamut) is no albedo: the
    file fails naming the texel, or with clamp it is 0 and counted; blur refuses it too."""
    px = np.full((8, 8, 3), 0.5, np.float32)
    px[3, 5, 2] = -0.2
    write(tmp_path / "n.exr", px)
    write(tmp_path / "ok.exr", np.full((8, 8, 3), 0.5, np.float32))
    rep = process_textures([str(tmp_path / "n.exr"), str(tmp_path / "ok.exr")],
                           output="{dir}/{stem}_out.exr")
    bad, good = rep.results
    assert rep.exit_code == 1 and good.status == "ok", rep.summary()
    assert "below 0" in bad.error and "x=5, y=3, channel B: -0.2" in bad.error, bad.error
    assert not (tmp_path / "n_out.exr").exists()
    rep = process_textures(str(tmp_path / "n.exr"), output="{dir}/{stem}_out.exr",
                           on_invalid="clamp")
    assert rep.exit_code == 0 and rep.results[0].invalid["albedo"] == 1, rep.summary()
    rho = read(tmp_path / "n_out.exr")[0]
    assert np.isfinite(rho).all()


# {{{ class 4 (continued): a clamp changes only its own texel

@pytest.mark.parametrize("bad", [np.nan, np.inf, -1.0], ids=["nan", "inf", "negative"])
@pytest.mark.parametrize("what", ["mfp", "albedo"])
def test_a_clamped_parameter_texel_changes_no_other_texel(what, bad):
    from bdipole_cl import blur
    rng = np.random.default_rng(1)
    e = rng.uniform(0, 1, (24, 24, 3)).astype(np.float32)
    maps = {"albedo": rng.uniform(0.3, 0.7, (24, 24, 3)).astype(np.float32),
            "mfp": rng.uniform(0.5, 2.0, (24, 24, 3)).astype(np.float32)}
    want = blur(e, texel_size=0.3, on_invalid="clamp", **maps)
    maps[what] = maps[what].copy()
    maps[what][5, 5, 1] = bad
    got = blur(e, texel_size=0.3, on_invalid="clamp", **maps)
    got[5, 5], want[5, 5] = 0, 0         # the gather uses the exit texel's own profile
    np.testing.assert_array_equal(got, want)

# }}}


@pytest.mark.parametrize("role", ["albedo", "mfp"])
def test_blur_refuses_parameter_textures_off_the_irradiances_window(tmp_path, capsys, role):
    """Textures are combined texel by texel: an irradiance whose data window starts at (-5, 7)
    and an albedo or mfp texture of the same size at (0, 0) would be misregistered by (5, -7)
    texels. blur fails the file, naming both windows, and writes nothing (as invert and a
    scene blur do)."""
    write(tmp_path / "irr.exr", ramp(), ("R", "G", "B"), window=(-5, 7))
    write(tmp_path / "param.exr", ramp(lo=0.3, hi=0.6), ("R", "G", "B"))
    other = {"albedo": ["--mfp", "1"], "mfp": ["--albedo", "0.5"]}[role]
    rc = cli_main(["blur", str(tmp_path / "irr.exr"), f"--{role}", str(tmp_path / "param.exr"),
                   *other, "-o", str(tmp_path / "out.exr"), "--no-progress"])
    captured = capsys.readouterr()
    text = captured.out + captured.err
    assert rc == 1 and "data windows and resolutions must match" in text, text
    assert not (tmp_path / "out.exr").exists()


def test_report_never_replaces_files_it_did_not_write(tmp_path, capsys):
    """report -o DIR and --write-choice PATH replaced a user's report.md and any file named
    as choice data: refused (exit 2, before any measuring) unless --force; the tool's own
    report and choice files are replaced as before."""
    from bdipole_cl.apps.report import Point, check_report_outputs, write_outputs
    from bdipole_cl.methods.choice import ChoiceData, write_choice_data
    folder, choice = tmp_path / "r", tmp_path / "mychoice.json"
    folder.mkdir()
    (folder / "report.md").write_text("my notes\n")
    choice.write_text("precious\n")
    for argv in (["-o", folder], ["-o", tmp_path / "r2", "--write-choice", choice]):
        rc = cli_main(["report", *map(str, argv), "--n", "4096", "--blur-size", "32",
                       "--repeats", "1"])
        err = capsys.readouterr().err
        assert rc == 2 and "was not written by bdipole-cl" in err and "--force" in err, err
    assert (folder / "report.md").read_text() == "my notes\n"
    assert choice.read_text() == "precious\n" and not (tmp_path / "r2").exists()
    check_report_outputs(folder, choice, force=True)           # --force: allowed
    points = [Point("inversion", "table", "table(size=4)", "f32", 1e-3, 1e-3, 1e-4)]
    write_outputs(points, tmp_path / "ours", "a device", ["a workload"])
    write_choice_data(ChoiceData("a device", (), ()), tmp_path / "ours.json")
    check_report_outputs(tmp_path / "ours", tmp_path / "ours.json")   # its own: no --force
    # its own files, changed since: the user's (report.md's mark records each file's digest)
    with open(tmp_path / "ours" / "report.md", "a") as f:
        f.write("\nmy notes\n")
    with pytest.raises(ValueError, match=r"report\.(csv|md) exists .* changed since"):
        check_report_outputs(tmp_path / "ours")
    raw = json.loads((tmp_path / "ours.json").read_text())
    raw["mine"] = 1
    (tmp_path / "ours.json").write_text(json.dumps(raw))
    with pytest.raises(ValueError, match="ours.json exists .* changed since"):
        check_report_outputs(tmp_path / "new", tmp_path / "ours.json")
    # the choice data on the report's own files, and a report folder that is a file
    for choice in (tmp_path / "new" / "report.csv", tmp_path / "new"):
        with pytest.raises(ValueError, match="is the report's folder or one of its files"):
            check_report_outputs(tmp_path / "new", choice)
    with pytest.raises(ValueError, match="exists and is not a folder"):
        check_report_outputs(tmp_path / "ours.json")
    (tmp_path / "d" / "report.csv").mkdir(parents=True)
    with pytest.raises(ValueError, match="not a regular file"):
        check_report_outputs(tmp_path / "d", force=True)


def test_report_files_change_together_or_not_at_all(tmp_path, monkeypatch):
    """A full disk while writing report.png left a new report.csv beside the old report.md:
    the three are written to temporary files first and renamed together; on a failure none
    changes and no temporary file is left. The choice data writer too."""
    import errno
    from bdipole_cl.apps import report
    from bdipole_cl.methods.choice import ChoiceData, write_choice_data
    points = [report.Point("inversion", "table", "table(size=4)", "f32", 1e-3, 1e-3, 1e-4)]
    report.write_outputs(points, tmp_path, "old device", ["old"])
    before = snapshot(tmp_path)

    real_write = type(tmp_path).write_bytes

    def full(self, data):                   # the disk fills while the picture is written
        if self.suffix == ".png":
            real_write(self, data[:100])
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(self, data)
    monkeypatch.setattr(type(tmp_path), "write_bytes", full)
    with pytest.raises(OSError):
        report.write_outputs(points, tmp_path, "new device", ["new"])
    monkeypatch.undo()
    assert snapshot(tmp_path) == before and sorted(p.name for p in tmp_path.iterdir()) == [
        "report.csv", "report.md", "report.png"]

    def full_text(self, *a, **k):
        open(self, "w").write("{\"half")
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(type(tmp_path), "write_text", full_text)
    with pytest.raises(OSError, match=r"writing .*c\.json: No space left"):
        write_choice_data(ChoiceData("a device", (), ()), tmp_path / "c" / "c.json")
    assert list((tmp_path / "c").iterdir()) == []


def test_report_under_sigterm_says_so_and_leaves_nothing(tmp_path):
    """SIGTERM during a report ended it by the signal's default action, silently: now it is
    'interrupted', exit 143, and no report file or temporary is left."""
    out = tmp_path / "r"
    proc = subprocess.Popen([sys.executable, "-m", "bdipole_cl", "report", "-o", str(out),
                             "--n", "65536", "--blur-size", "64", "--repeats", "3"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        line = proc.stdout.readline()
        if "inversion sweep" in line:
            break
    time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 143 and "interrupted" in stderr, (proc.returncode, stderr)
    assert not out.exists() or list(out.iterdir()) == []


def test_demo_never_rewrites_a_file_changed_in_its_folder(tmp_path):
    """A second demo into its folder replaced a scene.toml the user had edited and an albedo
    they had copied over the demo's: the demo records what it wrote, and refuses a folder
    whose files changed or were added since (a complete record; an unfinished run's folder is
    still its own)."""
    from bdipole_cl.apps.demo import claim_folder, record_folder
    folder = tmp_path / "dm"
    claim_folder(folder)
    (folder / "scene").mkdir()
    (folder / "scene" / "scene.toml").write_text("# the demo's\n")
    (folder / "albedo.exr").write_bytes(b"demo pixels")
    record_folder(folder, complete=True)
    claim_folder(folder)                                  # unchanged: its own
    record_folder(folder, complete=True)
    for change in (lambda: (folder / "scene" / "scene.toml").write_text("# my edit\n"),
                   lambda: (folder / "notes.txt").write_text("mine")):
        change()
        with pytest.raises(ValueError, match="changed or added since the demo made"):
            claim_folder(folder)
    assert (folder / "scene" / "scene.toml").read_text() == "# my edit\n"
    assert cli_main(["demo", "--dir", str(folder), "--no-progress"]) == 2
    # a demo that did not finish (Ctrl-C) recorded no files: its folder is not rewritten
    unfinished = tmp_path / "unfinished"
    claim_folder(unfinished)
    (unfinished / "albedo.exr").write_bytes(b"the user's copy")
    with pytest.raises(ValueError, match="an earlier demo there did not finish"):
        claim_folder(unfinished)
    assert (unfinished / "albedo.exr").read_bytes() == b"the user's copy"


@pytest.mark.parametrize("stop", [KeyboardInterrupt, "SIGTERM"])
def test_an_interrupted_demo_runs_again_in_its_folder(tmp_path, monkeypatch, capsys, stop):
    """Ctrl-C or SIGTERM during the demo: it ends 130 / 143 with nothing half-written, and
    records what its folder holds then (its own files), so the next demo there runs; an edit
    after that is still refused."""
    import bdipole_cl.jobs.blur_file as blur_file_module
    folder = tmp_path / "dm"

    def interrupted(*a, **k):
        if stop == "SIGTERM":
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1)
        raise KeyboardInterrupt
    monkeypatch.setattr(blur_file_module, "blur_file", interrupted)
    assert cli_main(["demo", "--dir", str(folder), "--no-progress"]) == (
        143 if stop == "SIGTERM" else 130)
    assert not [p for p in folder.rglob(".*") if p.name != ".bdipole_demo"]
    monkeypatch.undo()
    capsys.readouterr()
    rc = cli_main(["demo", "--dir", str(folder), "--no-progress"])
    assert rc == 0, capsys.readouterr()         # what failed, where it fails (a GPU did once)
    (folder / "albedo.exr").write_bytes(b"the user's")
    assert cli_main(["demo", "--dir", str(folder), "--no-progress"]) == 2
    assert (folder / "albedo.exr").read_bytes() == b"the user's"


def test_sigterm_in_a_picture_command_leaves_no_temporary_file(tmp_path, monkeypatch):
    """profile (and preview, demo: any command without its own stop checks) ends on SIGTERM
    as on Ctrl-C: exit 143, its temporary file removed (Python's default was to die there)."""
    from bdipole_cl.apps import preview

    def killed(tmp):                          # half a picture, then the signal
        tmp.write_bytes(b"half a picture")
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(1)
    real = preview.replaced_together

    def write_then_killed(writes):
        return real([(path, killed) for path, _ in writes])
    monkeypatch.setattr(preview, "replaced_together", write_then_killed)
    out = tmp_path / "p.svg"
    assert cli_main(["profile", "--albedo", "0.8", "--mfp", "1", "-o", str(out)]) == 143
    assert list(tmp_path.iterdir()) == []


def test_report_checks_its_outputs_again_before_it_writes(tmp_path, monkeypatch, capsys):
    """A report measures for minutes: a file the user put at report.csv meanwhile, or a
    hand-written choice file (the format, no digest), is refused when the report is about to
    write, not only before it measured; --calibrate takes no --write-choice."""
    from bdipole_cl.apps import report
    folder = tmp_path / "r"
    real = report.inversion_points

    def user_meanwhile(*args, **kw):
        folder.mkdir(exist_ok=True)
        (folder / "report.csv").write_text("precious\n")
        return real(*args, **kw)
    monkeypatch.setattr(report, "inversion_points", user_meanwhile)
    with pytest.raises(ValueError, match="report.csv exists and was not written"):
        report.run_report(folder, n=4096, blur_size=24, repeats=1, progress=lambda *_: None)
    assert (folder / "report.csv").read_text() == "precious\n"
    hand = tmp_path / "hand.json"
    hand.write_text(json.dumps({"device": "mine", "inversion": [], "blur": []}))
    with pytest.raises(ValueError, match="hand.json exists and was not written"):
        report.check_report_outputs(tmp_path / "new", hand)
    assert cli_main(["report", "--calibrate", "--write-choice", str(hand)]) == 2
    assert "--write-choice goes with a report" in capsys.readouterr().err


def test_demo_refuses_a_folder_with_a_symbolic_link(tmp_path):
    """A linked subfolder took the demo's writes into the user's folder (rglob does not walk
    into it, so the digests saw nothing changed)."""
    from bdipole_cl.apps.demo import claim_folder, record_folder
    folder, mine = tmp_path / "dm", tmp_path / "mine"
    claim_folder(folder)
    record_folder(folder, complete=True)
    mine.mkdir()
    (mine / "skin_albedo.1001.exr").write_text("precious")
    (folder / "scene").symlink_to(mine, target_is_directory=True)
    with pytest.raises(ValueError, match="is a symbolic link"):
        claim_folder(folder)
    assert (mine / "skin_albedo.1001.exr").read_text() == "precious"


def test_blur_values_clamped_to_the_half_range_are_counted_on_every_path(tmp_path, capsys):
    """A half output of a 1e6 highlight under --on-invalid clamp: the clamped values are
    counted (CLI line, the job's result, a scene's bake row), as invert counts them."""
    e = np.zeros((16, 16, 3), np.float32)
    e[8, 8] = 1e6
    write(tmp_path / "irr.exr", e)
    assert cli_main(["blur", str(tmp_path / "irr.exr"), "--albedo", "0.8", "--mfp", "2",
                     "--half", "--on-invalid", "clamp", "--no-progress",
                     "-o", str(tmp_path / "b.exr")]) == 0
    out = capsys.readouterr().out
    assert "invalid values clamped: half range 3" in out, out        # R, G and B
    assert np.nanmax(read(tmp_path / "b.exr")[0]) == 65504
    write(tmp_path / "alb.exr", np.full((16, 16, 3), 0.8, np.float32))
    path = scene(tmp_path, '[[material]]\nname = "m"\nalbedo = "alb.exr"\nmfp = 2.0\n'
                           'output = "m_out.exr"\n[[blur]]\nname = "b"\nmaterial = "m"\n'
                           'irradiance = "irr.exr"\ntexel_size = 1.0\nhalf = true\n'
                           'on_invalid = "clamp"\noutput = "b_out.exr"\n')
    report = scenes.load(path).plan().run()
    row = next(r for r in report.results if r.output.endswith("b_out.exr"))
    assert row.status == "ok" and row.invalid.get("half range", 0) > 0, report.summary()


def test_mfp_times_scale_out_of_range_is_named_whatever_the_policy(tmp_path, recwarn):
    """A constant --mfp x --mfp-scale out of range is a usage error under clamp too (a
    constant is no texel to clamp); a texture's texels overflowed by the scale name both
    values, and no NumPy warning leaks."""
    write(tmp_path / "a.exr", ramp(4, 4))
    write(tmp_path / "m.exr", np.full((4, 4, 1), 1e30, np.float32), ["Y"])
    for policy in ("raise", "clamp"):
        assert cli_main(["invert", str(tmp_path / "a.exr"), "--mfp", "3.4e38", "--mfp-scale",
                         "10", "--on-invalid", policy, "--no-progress",
                         "-o", str(tmp_path / "o.exr")]) == 2
    rep = process_textures(str(tmp_path / "a.exr"), mfp=str(tmp_path / "m.exr"),
                           mfp_scale=1e30, output=str(tmp_path / "o.exr"))
    assert rep.exit_code == 1 and "the mfp texture's 1e+30 x --mfp-scale 1e+30" in \
        rep.results[0].error, rep.summary()
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]
    assert not (tmp_path / "o.exr").exists()


def test_outputs_reach_the_disk_before_they_are_renamed_into_place(tmp_path, monkeypatch):
    """temp file + verified write + fsync + rename + the folder's fsync: a power loss after
    the rename cannot leave an empty file where the old output was."""
    from bdipole_cl import durable
    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        return real_fsync(fd)

    def replace(a, b):
        events.append(("replace", str(b)))
        return real_replace(a, b)
    monkeypatch.setattr(durable.os, "fsync", fsync)
    monkeypatch.setattr(durable.os, "replace", replace)
    write(tmp_path / "a.exr", ramp(4, 4))
    out = tmp_path / "o.exr"
    assert process_textures(str(tmp_path / "a.exr"), mfp=1.0, output=str(out)).exit_code == 0
    kinds = [(k, p) for k, p in events]
    i = kinds.index(("replace", str(out)))
    assert kinds[i - 1][0] == "fsync" and ".partial-" in kinds[i - 1][1]   # the data first
    assert kinds[i + 1] == ("fsync", str(tmp_path))                       # then the rename


def test_a_truncated_file_fails_on_one_line(tmp_path):
    """OpenImageIO's error for a truncated EXR holds several lines, one repeating another:
    the file's row says it on one line, each part once."""
    write(tmp_path / "a.exr", ramp(8, 8))
    (tmp_path / "t.exr").write_bytes((tmp_path / "a.exr").read_bytes()[:300])
    rep = process_textures(str(tmp_path / "t.exr"), mfp=1.0, output=str(tmp_path / "o.exr"))
    error = rep.results[0].error
    assert rep.exit_code == 1 and "\n" not in error and "t.exr" in error, error
    parts = error.split("; ")
    assert len(parts) == len(set(parts))
    assert len([ln for ln in rep.summary().splitlines() if "t.exr" in ln]) == 1


def test_an_output_under_a_file_names_the_file(tmp_path):
    """-o a.exr/x.exr (a file where the output's folder would be): the job fails naming that
    file, not with [Errno 17] File exists."""
    write(tmp_path / "a.exr", ramp(4, 4))
    rep = process_textures(str(tmp_path / "a.exr"), mfp=1.0,
                           output=str(tmp_path / "a.exr" / "sub" / "x.exr"), force=True)
    error = rep.results[0].error
    assert rep.exit_code == 1 and f"{tmp_path / 'a.exr'} is a file, not a folder" in error, error


def test_a_failed_write_on_a_nearly_full_disk_says_so(tmp_path, monkeypatch):
    """OpenEXR's "Failed to write pixel data" names the temporary file only: where the disk
    is (nearly) full the failure says how much is free."""
    from collections import namedtuple
    from bdipole_cl.io import images
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(images.shutil, "disk_usage", lambda p: usage(1 << 30, 1 << 30, 3 << 19))
    assert images.low_space(tmp_path / "o.exr") == " (the disk has only 1.5 MiB free)"
    monkeypatch.setattr(images.shutil, "disk_usage", lambda p: usage(1 << 40, 0, 1 << 39))
    assert images.low_space(tmp_path / "o.exr") == ""


def test_a_fifo_in_a_demo_folder_is_not_the_demos(tmp_path):
    from bdipole_cl.apps.demo import claim_folder, record_folder
    folder = tmp_path / "dm"
    claim_folder(folder)
    record_folder(folder, complete=True)
    os.mkfifo(folder / "pipe")
    with pytest.raises(ValueError, match="is not a regular file or folder"):
        claim_folder(folder)


def test_a_float64_highlight_beyond_float32_is_named_as_such_or_kept_bright():
    """A finite 1e39 in a float64 irradiance is not "NaN or infinite": it is named as beyond
    float32's range, and under clamp it stays the brightest texel (it was made unlit, 0)."""
    from bdipole_cl import InvalidInputError, blur
    e = np.zeros((16, 16, 3))
    e[8, 8] = 1e39
    with pytest.raises(InvalidInputError, match="beyond float32's range") as exc:
        blur(e, albedo=0.8, mfp=2.0)
    assert exc.value.first_value == 1e39
    out = blur(e, albedo=0.8, mfp=2.0, on_invalid="clamp")
    assert np.all(np.isfinite(out)) and out[8, 8, 0] == out[..., 0].max() > 1e37


def test_a_replaced_output_keeps_its_permissions_and_group(tmp_path):
    """An output rewritten in a shared folder keeps its permission bits (and its group, where
    this user may set it): it was the umask's 644 and the user's group after a rerun."""
    write(tmp_path / "a.exr", ramp())
    out = tmp_path / "o.exr"
    argv = ["invert", str(tmp_path / "a.exr"), "-o", str(out), "--no-progress"]
    assert cli_main(argv) == 0
    groups = [g for g in os.getgroups() if g != os.stat(out).st_gid] or [os.stat(out).st_gid]
    os.chmod(out, 0o664)
    try:
        os.chown(out, -1, groups[0])
    except PermissionError:
        pass
    before = os.stat(out)
    assert cli_main(argv) == 0
    after = os.stat(out)
    assert after.st_ino != before.st_ino                      # replaced, not written in place
    assert (after.st_mode & 0o7777, after.st_gid) == (0o664, before.st_gid)


def test_a_tile_whose_mfp_covers_other_texels_cannot_run_in_the_plan(tmp_path):
    """The plan reads the headers: a tile whose mfp tile has another resolution is a job that
    cannot run, named, before any bake (the plan listed it 'to run'; the bake failed it)."""
    for tile, size in (("1001", 16), ("1002", 8)):
        write(tmp_path / f"a.{tile}.exr", ramp())
        write(tmp_path / f"m.{tile}.exr", np.ones((size, 12 if size == 16 else 6, 1)), ["Y"])
    path = scene(tmp_path, '[[material]]\nname = "m"\nalbedo = "a.<UDIM>.exr"\n'
                           'mfp = "m.<UDIM>.exr"\noutput = "out/o.<UDIM>.exr"\n')
    plan = scenes.load(path).plan()
    bad, = [j for j in plan.jobs if j.problem]
    assert bad.udim == "1002" and "data windows and resolutions must match" in bad.problem
    assert [j.udim for j in plan.jobs if not j.problem] == ["1001"]
