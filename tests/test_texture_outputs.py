"""Texture outputs (``--texture`` / ``texture = true``): tiled, mip-mapped OpenEXR written by
the one writer (bdipole_cl/io/images.py ``Writer``, ``write_texture``) for every entry point."""
import os
import signal
import subprocess
import sys
import time

import numpy as np
import OpenImageIO as oiio
import pytest

from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.apps.demo import write_exr
from bdipole_cl.io import images  # noqa: F401  (patched below)
from bdipole_cl.io.batch import process_textures
from bdipole_cl.io.images import TextureError, Writer, output_spec
from bdipole_cl.io.mipmaps import TEXTURE_REWRITES, mip_levels
from bdipole_cl.io.colour import resolve_working_space
from bdipole_cl.io.scene import load

#: the default working space (the outputs' colour tags)
WORKING = resolve_working_space()

#: every test here runs once per working OpenCL device (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("on_device")

W, H = 100, 70          # not powers of two: the mip chain rounds down (100x70 -> ... -> 1x1)


def albedo_rgba(seed=0):
    rng = np.random.default_rng(seed)
    rgb = rng.uniform(0.05, 0.9, (H, W, 3))
    alpha = (rng.uniform(size=(H, W, 1)) > 0.3).astype(np.float64)
    return np.concatenate([rgb, alpha], -1).astype(np.float32)


def levels(path):
    """(the spec of every mip level, level 0's pixels, the header of level 0)."""
    buf = oiio.ImageBuf(str(path))
    specs = []
    for m in range(buf.nmiplevels):
        b = oiio.ImageBuf(str(path), 0, m)
        specs.append(b.spec())
    return specs, buf.get_pixels(oiio.FLOAT), buf.spec()


def header(spec):
    return {a.name: a.value for a in spec.extra_attribs if a.name not in TEXTURE_REWRITES}


@pytest.mark.parametrize("half", [False, True], ids=["float", "half"])
def test_texture_output_is_mipmapped_tiled_and_level0_is_the_plain_output(tmp_path, half):
    write_exr(tmp_path / "skin.exr", albedo_rgba(), ("R", "G", "B", "A"))
    common = dict(mfp=(1.2, 0.6, 0.3), eta=1.4, outputs=("sigma_a", "sigma_s"), half=half)
    plain = process_textures(str(tmp_path / "skin.exr"), output=str(tmp_path / "plain.exr"),
                             **common)
    tex = process_textures(str(tmp_path / "skin.exr"), output=str(tmp_path / "tex.exr"),
                           texture=True, **common)
    assert plain.exit_code == 0 and tex.exit_code == 0, (plain.summary(), tex.summary())
    specs, px, spec0 = levels(tmp_path / "tex.exr")
    _, plain_px, plain_spec = levels(tmp_path / "plain.exr")
    assert len(specs) == mip_levels(W, H) == 7 > 1, len(specs)
    assert [(s.width, s.height) for s in specs][-2:] == [(3, 2), (1, 1)]
    assert all((s.tile_width, s.tile_height) == (64, 64) for s in specs)
    assert plain_spec.tile_width == 0                       # the plain output is scanline
    assert tuple(spec0.channelnames) == tuple(plain_spec.channelnames)
    assert "sigma_a.R" in spec0.channelnames and spec0.format == plain_spec.format
    assert spec0.format == (oiio.HALF if half else oiio.FLOAT)
    # bdipole:*, colour, everything but the settings' digest (texture=True is a setting)
    want = {k: v for k, v in header(plain_spec).items() if k != "bdipole:params_digest"}
    assert {k: header(spec0).get(k) for k in want} == want
    assert want["bdipole:eta"] and "bdipole:model" in want
    assert np.array_equal(px, plain_px), np.max(np.abs(px - plain_px))   # bit for bit
    assert sorted(os.listdir(tmp_path)) == ["plain.exr", "skin.exr", "tex.exr"]  # no leftovers


def test_a_data_window_is_filled_to_the_display_window_exactly(tmp_path):
    spec = oiio.ImageSpec(40, 30, 3, "float")
    spec.x, spec.y, spec.full_width, spec.full_height = 5, 7, 50, 40
    spec.channelnames = ("sigma_a.R", "sigma_a.G", "sigma_a.B")
    px = np.random.default_rng(1).uniform(0.1, 9.0, (30, 40, 3)).astype(np.float32)
    w = Writer(tmp_path / "win.exr", output_spec(spec, spec.channelnames, -1, False, {}, working=WORKING),
               texture=True)
    w.write_band(0, 30, px)
    w.commit()
    _, level0, spec0 = levels(tmp_path / "win.exr")
    assert (spec0.width, spec0.height) == (50, 40)
    assert np.array_equal(level0[7:37, 5:45], px)           # no resampling of the data
    outside = np.ones((40, 50), bool)
    outside[7:37, 5:45] = False
    assert np.all(level0[outside] == 0)


@pytest.mark.parametrize("window", [(0, 0, 40, 40, 0, 0, 32, 32), (-4, -3, 40, 40, 0, 0, 32, 32),
                                    (20, 20, 20, 20, 0, 0, 32, 32), (0, 0, 32, 32, -8, -8, 32, 32)],
                         ids=["larger", "negative origin", "overlapping", "display moved"])
def test_a_data_window_outside_the_display_window_is_refused_before_any_work(tmp_path, window):
    """A texture spans its display window: texels outside it would be lost, so such a file's
    texture output fails, named with both windows and the remedy, before it is computed, and
    nothing is left; its plain output is written as usual."""
    x, y, w, h, fx, fy, fw, fh = window
    spec = oiio.ImageSpec(w, h, 3, "float")
    spec.x, spec.y, spec.full_x, spec.full_y, spec.full_width, spec.full_height = window[:2] + (
        fx, fy, fw, fh)
    path = tmp_path / "alb.exr"
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    out.write_image(np.full((h, w, 3), 0.4, np.float32))
    out.close()
    tex = process_textures(str(path), mfp=1.0, output=str(tmp_path / "tex.exr"), texture=True)
    assert tex.exit_code == 1
    error = tex.results[0].error
    assert "display window" in error and f"{w}x{h} at {x},{y}" in error and "--fullpixels" in error
    assert sorted(os.listdir(tmp_path)) == ["alb.exr"]
    assert process_textures(str(path), mfp=1.0, output=str(tmp_path / "o.exr")).exit_code == 0


@pytest.mark.parametrize("where, why", [(0, "level 0 differs"), (2, "mip level 2")],
                         ids=["level0", "level2-mean"])
def test_a_texture_that_does_not_verify_is_not_written(tmp_path, monkeypatch, where, why):
    """The verification can fail: a texture build that changes a texel of level 0, or moves a
    smaller level's mean from its parent's, is refused and the target is not created."""
    from bdipole_cl.io import mipmaps
    real = mipmaps.write_levels

    def corrupt(levels, texture, spec, options):
        levels = [v.copy() for v in levels]
        levels[where][0, 0, 0] += 0.25
        return real(levels, texture, spec, options)

    monkeypatch.setattr(mipmaps, "write_levels", corrupt)
    spec = oiio.ImageSpec(20, 10, 3, "float")
    spec.channelnames = ("R", "G", "B")
    w = Writer(tmp_path / "bad.exr", output_spec(spec, spec.channelnames, -1, False, {}, working=WORKING),
               texture=True)
    w.write_band(0, 10, np.full((10, 20, 3), 0.5, np.float32))
    with pytest.raises(TextureError, match=why):
        w.commit()
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("suffix", [".tx", ".tif"])
def test_a_tiff_texture_output_is_refused_with_its_reason(tmp_path, capsys, suffix):
    write_exr(tmp_path / "a.exr", albedo_rgba()[..., :3], ("R", "G", "B"))
    rc = cli_main(["invert", str(tmp_path / "a.exr"), "--texture", "--no-progress",
                   "-o", str(tmp_path / f"a{suffix}")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert "TIFF" in err and "channel names" in err and suffix in err
    assert not (tmp_path / f"a{suffix}").exists()


def test_sigterm_during_the_texture_write_leaves_nothing_partial(tmp_path):
    """A real SIGTERM, sent once the texture build has started (its temporary exists): the
    process exits 143, and neither the output nor any temporary is left."""
    write_exr(tmp_path / "big.exr", np.random.default_rng(0).uniform(
        0.05, 0.9, (1024, 1024, 3)).astype(np.float32), ("R", "G", "B"))
    out_dir = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "bdipole_cl", "invert",
                             str(tmp_path / "big.exr"), "--texture", "--no-progress",
                             "-o", str(out_dir / "{stem}.exr")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None:
        if out_dir.exists() and any(".partial-" in p and ".tx." in p
                                    for p in os.listdir(out_dir)):
            break
        time.sleep(0.002)
    assert proc.poll() is None, "the batch ended before the texture write began"
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 143, (stdout, stderr)
    assert "Traceback" not in stderr and "cancelled" in stdout
    assert os.listdir(out_dir) == [], os.listdir(out_dir)


SCENE = """
[defaults]
texture = true

[[material]]
name = "skin"
albedo = "tex/skin.<UDIM>.exr"
mfp = [1.2, 0.6, 0.3]
output = "out/skin.<UDIM>.exr"
half = true

[[blur]]
name = "skin_tsd"
material = "skin"
irradiance = "light/irr.<UDIM>.exr"
texel_size = 0.1
output = "out/exitance.<UDIM>.exr"
"""


def test_scene_texture_true_bakes_textures_that_stay_up_to_date(tmp_path):
    (tmp_path / "tex").mkdir()
    (tmp_path / "light").mkdir()
    write_exr(tmp_path / "tex" / "skin.1001.exr", albedo_rgba()[:32, :48], ("R", "G", "B", "A"))
    light = np.zeros((32, 48, 3), np.float32)
    light[10:13] = 2.0
    write_exr(tmp_path / "light" / "irr.1001.exr", light, ("R", "G", "B"))
    path = tmp_path / "scene.toml"
    path.write_text(SCENE)
    report = load(path).plan().run()
    assert report.exit_code == 0, report.summary()
    for name in ("skin.1001.exr", "exitance.1001.exr"):
        specs, _, spec0 = levels(tmp_path / "out" / name)
        assert len(specs) == mip_levels(48, 32) and spec0.tile_width == 64, name
        assert spec0.getattribute("bdipole:params_digest"), name   # the up-to-date record
    again = load(path).plan()
    assert all(j.up_to_date for j in again.jobs), again.describe()
    path.write_text(SCENE.replace("texture = true", "texture = false"))
    changed = load(path).plan()
    assert not any(j.up_to_date for j in changed.jobs), changed.describe()


def test_what_a_killed_texture_write_leaves_is_recognised_as_partial(tmp_path):
    """SIGKILL cannot be caught: the texture's temporaries (the writer's and maketx's own)
    are what ``partial_files`` finds (the Dask runner removes them before a retry)."""
    from bdipole_cl.io.mipmaps import build_files
    from bdipole_cl.io.partials import alive, partial_files, remove_partial_files
    dead = next(pid for pid in range(4_000_000, 4_100_000) if not alive(pid))
    target = tmp_path / "skin.1001.exr"
    left = [tmp_path / f".skin.1001.partial-{dead}-34.exr",
            tmp_path / f".skin.1001.partial-{dead}-34.tx.exr",
            tmp_path / f".skin.1001.partial-{dead}-34.tx.5e47e508.temp.exr"]
    for p in left:
        p.write_bytes(b"")
    live = tmp_path / f".skin.1001.partial-{os.getppid()}-34.exr"    # a running writer's
    live.write_bytes(b"")
    (tmp_path / "skin.1002.exr").write_bytes(b"")
    assert partial_files(target) == sorted(left + [live])
    assert build_files(left[1]) == [left[2]]           # OpenImageIO 3's {stem}.{hex}.temp{ext}
    assert remove_partial_files(target) == 3
    assert sorted(os.listdir(tmp_path)) == sorted([live.name, "skin.1002.exr"])


def test_a_write_removes_what_a_stopped_earlier_write_left(tmp_path):
    """An earlier run stopped during a texture build (its thread still writing when the process
    ended) leaves maketx's temporary: the next write of that output removes it, whatever the
    path (it did only on the Dask path, and its glob missed OpenImageIO 3's name)."""
    from bdipole_cl.io.partials import alive
    dead = next(pid for pid in range(4_000_000, 4_100_000) if not alive(pid))
    write_exr(tmp_path / "a.exr", albedo_rgba()[..., :3], ("R", "G", "B"))
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    left = out_dir / f".a.partial-{dead}-7.tx.0123abcd.temp.exr"
    left.write_bytes(b"x" * 1000)
    assert cli_main(["invert", str(tmp_path / "a.exr"), "--texture", "--no-progress",
                     "-o", str(out_dir / "{stem}.exr")]) == 0
    assert sorted(os.listdir(out_dir)) == ["a.exr"]


def test_a_texture_without_the_space_for_it_fails_its_file_and_leaves_nothing(
        tmp_path, capsys, monkeypatch):
    """OpenImageIO's texture build can hang on a full disk (seen with 3.2 on a full tmpfs):
    the space it may need is checked first, and the file fails, named, with nothing left."""
    from collections import namedtuple
    from bdipole_cl.io import mipmaps
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(mipmaps.shutil, "disk_usage", lambda path: usage(1 << 30, 1 << 30, 4096))
    write_exr(tmp_path / "a.exr", albedo_rgba()[..., :3], ("R", "G", "B"))
    out_dir = tmp_path / "out"
    rc = cli_main(["invert", str(tmp_path / "a.exr"), "--texture", "--no-progress",
                   "-o", str(out_dir / "{stem}.exr")])
    out = capsys.readouterr().out
    assert rc == 1 and "not enough space for the texture" in out and "a.exr" in out, out
    assert os.listdir(out_dir) == []


def test_a_stop_during_a_hung_texture_build_is_heard(tmp_path, monkeypatch):
    """A texture build that never returns (a full disk) is abandoned on a stop request within
    ~0.1 s plus ABANDON_WAIT: Cancelled, nothing left, and builds_running says so."""
    import threading
    from bdipole_cl.io import mipmaps
    from bdipole_cl.io.images import Cancelled
    release = threading.Event()

    def hung(levels, texture, spec, options):
        open(texture, "wb").close()                       # what the writer makes first
        release.wait(30)
        return "hung"

    monkeypatch.setattr(mipmaps, "write_levels", hung)
    monkeypatch.setattr(mipmaps, "ABANDON_WAIT", 0.2)
    cancel = threading.Event()
    spec = oiio.ImageSpec(20, 10, 3, "float")
    spec.channelnames = ("R", "G", "B")
    w = Writer(tmp_path / "t.exr", output_spec(spec, spec.channelnames, -1, False, {},
                                               working=WORKING), texture=True, cancel=cancel)
    w.write_band(0, 10, np.full((10, 20, 3), 0.5, np.float32))
    threading.Timer(0.3, cancel.set).start()
    t0 = time.monotonic()
    try:
        with pytest.raises(Cancelled):
            w.commit()
        assert time.monotonic() - t0 < 5
        assert mipmaps.builds_running()
        assert os.listdir(tmp_path) == []
    finally:
        release.set()
        mipmaps.ABANDONED.clear()


def test_partial_files_of_an_output_with_glob_characters_are_its_own(tmp_path):
    """An output named m[1].exr or *.exr: only its own temporaries are found and removed (a
    glob of its raw name matched another output's, which a cluster job would have deleted
    from under a live writer)."""
    from bdipole_cl.io.partials import alive, partial_files, remove_partial_files
    dead = next(pid for pid in range(4_000_000, 4_100_000) if not alive(pid))
    others = [tmp_path / f".m1.partial-{dead}-1.exr", tmp_path / f".other.partial-{dead}-2.exr",
              tmp_path / f".m1.partial-{dead}-1.tx.exr"]
    own = tmp_path / f".m[1].partial-{dead}-6.exr"
    for p in [*others, own]:
        p.write_bytes(b"")
    assert partial_files(tmp_path / "m[1].exr") == [own]
    assert partial_files(tmp_path / "*.exr") == []
    assert remove_partial_files(tmp_path / "m[1].exr") == 1
    assert all(p.exists() for p in others)


def test_mip_levels_of_values_near_flt_max_stay_finite(tmp_path, capsys):
    """Finite values above ~FLT_MAX / 4 overflowed OpenImageIO's mip filter (it sums, then
    divides: every level below 0 held inf, the file failed). Each level is now a convex
    combination of its parent's texels, in float64: every level is finite, its mean its
    parent's."""
    e = np.random.default_rng(1).uniform(1e38, 3e38, (32, 32, 3)).astype(np.float32)
    write_exr(tmp_path / "irr.exr", e, ("R", "G", "B"))
    rc = cli_main(["blur", str(tmp_path / "irr.exr"), "--albedo", "0.8", "--mfp", "1",
                   "--texture", "--no-progress", "-o", str(tmp_path / "t.exr")])
    assert rc == 0, capsys.readouterr()
    px = [oiio.ImageBuf(str(tmp_path / "t.exr"), 0, m).get_pixels(oiio.FLOAT)
          for m in range(mip_levels(32, 32))]
    assert all(np.all(np.isfinite(p)) for p in px)
    assert px[-1].mean(dtype=np.float64) == pytest.approx(px[0].mean(dtype=np.float64), rel=1e-6)


def test_a_texture_with_a_cut_off_mip_level_is_not_complete(tmp_path):
    """--skip-existing and a scene's up-to-date check read every level: a texture whose last
    bytes (its smallest levels) are gone is rebuilt, not skipped."""
    from bdipole_cl.io.verify import is_complete
    write_exr(tmp_path / "a.exr", albedo_rgba()[..., :3], ("R", "G", "B"))
    out = tmp_path / "out.exr"
    assert process_textures(str(tmp_path / "a.exr"), output=str(out), mfp=1.0,
                            texture=True).exit_code == 0
    assert is_complete(out)
    data = out.read_bytes()
    out.write_bytes(data[:-150])
    assert not is_complete(out)
    stamp = os.stat(tmp_path / "a.exr").st_mtime + 10
    os.utime(out, (stamp, stamp))                  # newer than its input, as a skip needs
    rep = process_textures(str(tmp_path / "a.exr"), output=str(out), mfp=1.0, texture=True,
                           skip_existing=True)
    assert rep.results[0].status == "ok" and is_complete(out), rep.summary()


@pytest.mark.parametrize("border, wrap", [("wrap", "periodic"), ("clamp", "clamp"),
                                          ("zero", "black")])
def test_a_blur_texture_wraps_as_its_border_rule(tmp_path, border, wrap):
    write_exr(tmp_path / "irr.exr", np.full((16, 24, 3), 0.5, np.float32), ("R", "G", "B"))
    assert cli_main(["blur", str(tmp_path / "irr.exr"), "--albedo", "0.8", "--mfp", "1",
                     "--border", border, "--texture", "--no-progress",
                     "-o", str(tmp_path / "t.exr")]) == 0
    assert oiio.ImageInput.open(str(tmp_path / "t.exr")).spec().getattribute(
        "wrapmodes") == f"{wrap},{wrap}"


# {{{ as a renderer reads them: OpenImageIO's TextureSystem (what OSL and many renderers use)

#: float32 rounding: a level texel is a convex combination rounded once (u = 2^-24), a lookup
#: blends up to 8 texels (trilinear) in float: a constant reads back within ~8 u
LOOKUP_REL = 8 * 2.0 ** -24
#: lookup positions across a tile: its edges, 0.5% in, its middle
EDGES = (0.0, 0.005, 0.5, 0.995, 0.99999)
#: filter widths (texture space): a texel, a few, a fifth of the tile, the whole, wider than
#: the tile (the 1x1 level)
WIDTHS = (1e-4, 0.01, 0.2, 1.0, 4.0)


def lookup(path, s, t, width, nch=1):
    """A TextureSystem lookup (the shared cache, as a renderer's), width x width footprint."""
    ts = oiio.TextureSystem(shared=True)
    return np.array(ts.texture(str(path), oiio.TextureOpt(), s, t, width, 0.0, 0.0, width,
                               nch))


def cache_level(path, m):
    """Mip level ``m`` of a texture as the TextureSystem's own image cache holds it."""
    ic = oiio.ImageCache(shared=True)
    spec = ic.get_imagespec(str(path), 0)
    x, y, w, h = spec.x, spec.y, spec.width, spec.height
    for _ in range(m):                         # each level halves, rounded down, origin 0
        x, y, w, h = 0, 0, max(w // 2, 1), max(h // 2, 1)
    px = ic.get_pixels(str(path), 0, m, x, x + w, y, y + h, 0, 1, oiio.FLOAT)
    assert px is not None, (path, m, ic.geterror())
    return np.asarray(px, np.float64).reshape(h, w, -1)


#: a UDIM set of three tiles (1001, 1002 right of it, 1011 above) at an odd size
UDIM_TILES = {"1001": (0, 0), "1002": (1, 0), "1011": (0, 1)}


@pytest.mark.parametrize("kind", ["udim", "single"])
def test_a_constant_texture_reads_constant_at_every_border_and_corner(tmp_path, kind, capsys):
    """A constant albedo's coefficient textures read the constant through TextureSystem
    lookups at every tile border, corner and 0.5% in, at every filter width (down to the 1x1
    level), across UDIM tiles: wrap clamp, mips that keep the mean. With wrap black (the
    earlier default) the same lookups read 50% low at a border, 27% low 0.5% in."""
    names = UDIM_TILES if kind == "udim" else {"one": (0, 0)}
    for name in names:
        write_exr(tmp_path / f"alb.{name}.exr", np.full((23, 37, 3), 0.5, np.float32),
                  ("R", "G", "B"))
    src = tmp_path / ("alb.<UDIM>.exr" if kind == "udim" else "alb.one.exr")
    out = tmp_path / ("o.<UDIM>.exr" if kind == "udim" else "o.exr")
    for wrap in ("clamp", "black"):
        target = tmp_path / wrap / out.name
        assert cli_main(["invert", str(src), "--outputs", "sigma_t", "--texture",
                         "--texture-wrap", wrap, "--no-progress", "-o", str(target)]) == 0, \
            capsys.readouterr()
        first = target.parent / target.name.replace("<UDIM>", "1001")
        c = oiio.ImageBuf(str(first)).get_pixels(oiio.FLOAT)[0, 0, 0]
        worst = 0.0
        for (u, v) in names.values():
            for s in EDGES:
                for t in EDGES:
                    for width in WIDTHS:
                        got = lookup(target, u + s, v + t, width)[0]
                        worst = max(worst, abs(got / c - 1))
        if wrap == "clamp":
            assert worst <= LOOKUP_REL, (kind, worst)
        else:                                           # the check can fail: black seams
            assert worst > 0.25, (kind, worst)


@pytest.mark.parametrize("half", [False, True], ids=["float", "half"])
@pytest.mark.parametrize("size", [(100, 37), (37, 100), (1, 7), (33, 1), (5, 3), (64, 64)],
                         ids=lambda s: f"{s[0]}x{s[1]}")
def test_every_mip_level_keeps_its_parents_mean(tmp_path, size, half):
    """Each level as the TextureSystem's cache holds it has its parent's mean within the area
    filter's bound (mipmaps.mean_bound: one rounding to the stored type), at odd sizes; a
    whole-texture lookup (the 1x1 level) reads level 0's mean. OpenImageIO's maketx filter
    picked texels at odd sizes: a 100x37 texture's levels were 1.3% off, its 1x1 level 11%
    on a ramp."""
    from bdipole_cl.io.mipmaps import mean_bound
    w, h = size
    ramp = np.linspace(0.05, 0.95, w * h, dtype=np.float32).reshape(h, w, 1)
    rng = np.random.default_rng(w * h)
    alb = np.concatenate([ramp ** 2, rng.uniform(0.05, 0.95, (h, w, 2))], -1)
    write_exr(tmp_path / "a.exr", alb.astype(np.float32), ("R", "G", "B"))
    rep = process_textures(str(tmp_path / "a.exr"), output=str(tmp_path / "t.exr"), mfp=1.0,
                           outputs=("alpha",), half=half, texture=True)
    assert rep.exit_code == 0, rep.summary()
    levels = [cache_level(tmp_path / "t.exr", m) for m in range(mip_levels(w, h))]
    assert levels[-1].shape[:2] == (1, 1)
    total = 0.0
    for m in range(1, len(levels)):
        off = np.abs(levels[m].mean((0, 1)) - levels[m - 1].mean((0, 1)))
        bound = mean_bound(levels[m - 1], half)
        assert np.all(off <= bound), (size, m, off, bound)
        total = total + bound
    whole = lookup(tmp_path / "t.exr", 0.5, 0.5, 4.0, 3)    # wider than it: the 1x1 level
    assert np.all(np.abs(whole - levels[0].mean((0, 1))) <= total + LOOKUP_REL * whole), \
        (size, whole, levels[0].mean((0, 1)))


def test_wrap_tile_and_resize_are_the_users_choice(tmp_path, capsys):
    """--texture-wrap, --texture-tile, --texture-resize (maketx --wrap/--tile/--resize,
    txmake -mode/-resize) and a scene's texture_wrap, texture_tile, texture_resize keys (each
    implies texture = true); bad values are one-line errors."""
    alb = np.random.default_rng(3).uniform(0.1, 0.9, (37, 100, 3)).astype(np.float32)
    write_exr(tmp_path / "a.exr", alb, ("R", "G", "B"))
    rc = cli_main(["invert", str(tmp_path / "a.exr"), "--outputs", "alpha", "--no-progress",
                   "--texture-wrap", "periodic", "--texture-tile", "32",
                   "--texture-resize", "up", "-o", str(tmp_path / "t.exr")])
    assert rc == 0, capsys.readouterr()
    spec = oiio.ImageInput.open(str(tmp_path / "t.exr")).spec()
    assert (spec.width, spec.height, spec.tile_width) == (128, 64, 32)
    assert spec.getattribute("wrapmodes") == "periodic,periodic"
    plain = process_textures(str(tmp_path / "a.exr"), output=str(tmp_path / "p.exr"),
                             mfp=1.0, outputs=("alpha",))
    assert plain.exit_code == 0
    mean0 = oiio.ImageBuf(str(tmp_path / "p.exr")).get_pixels(oiio.FLOAT).mean((0, 1), np.float64)
    resized_mean = cache_level(tmp_path / "t.exr", 0).mean((0, 1))
    assert np.allclose(resized_mean, mean0, rtol=2 * 2.0 ** -24), (resized_mean, mean0)
    # periodic: just left of s = 0 reads the right edge, as the texture repeats
    right = lookup(tmp_path / "t.exr", 1 - 1 / 256, 0.5, 1e-5, 3)
    assert np.allclose(lookup(tmp_path / "t.exr", -1 / 256, 0.5, 1e-5, 3), right, rtol=1e-6)
    for bad, value in (("--texture-wrap", "seamless"), ("--texture-resize", "nearest"),
                       ("--texture-tile", "0")):
        with pytest.raises(SystemExit) as stop:
            cli_main(["invert", str(tmp_path / "a.exr"), bad, value, "-o", str(tmp_path / "x.exr")])
        err = capsys.readouterr().err
        assert stop.value.code == 2 and bad in err and value in err, err
    (tmp_path / "s.toml").write_text(
        '[[material]]\nname = "m"\nalbedo = "a.exr"\noutput = "s.exr"\noutputs = ["alpha"]\n'
        'texture_wrap = "mirror"\ntexture_tile = 16\ntexture_resize = "round"\n')
    report = load(tmp_path / "s.toml").plan().run()
    assert report.exit_code == 0, report.summary()
    spec = oiio.ImageInput.open(str(tmp_path / "s.exr")).spec()
    assert (spec.width, spec.height, spec.tile_width) == (128, 32, 16)
    assert spec.getattribute("wrapmodes") == "mirror,mirror"
    (tmp_path / "s.toml").write_text(
        '[[material]]\nname = "m"\nalbedo = "a.exr"\noutput = "s.exr"\n'
        'texture = true\ntexture_wrap = "repeat"\n')
    with pytest.raises(ValueError, match="texture_wrap"):
        load(tmp_path / "s.toml")

# }}}
