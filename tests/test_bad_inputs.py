"""Bad inputs to the CLI and the API: each asserts the exit code, the message and the files left.

Usage errors exit 2 and failed files 1, with one line on stderr and no traceback; signals stop
a batch cleanly (exit 128 + signal). Run in-process where only the exit code and message
matter, as subprocesses where signals do."""
import os
import signal
import subprocess
import sys
import time

import numpy as np
import OpenImageIO as oiio
import pytest

from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.io.batch import process_textures


def write_exr(path, pixels, names=None):
    pixels = np.ascontiguousarray(pixels, np.float32)
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, "float")
    if names:
        spec.channelnames = tuple(names)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(pixels)
    out.close()


def read_exr(path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    px = inp.read_image(oiio.FLOAT)
    names = inp.spec().channelnames
    inp.close()
    return np.asarray(px), names


def albedo(h=8, w=10, value=0.5):
    return np.full((h, w, 3), value, np.float32)


def files_in(d):
    return sorted(p.name for p in d.rglob("*") if p.is_file())


def one_line_error(err):
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


# {{{ outputs never collide, never overwrite an input, never lose channels

def test_udim_tiles_keep_distinct_outputs_with_stem(tmp_path):
    for tile, v in (("1001", 0.3), ("1002", 0.6)):
        write_exr(tmp_path / f"diffuse.{tile}.exr", albedo(value=v))
    out = tmp_path / "out"
    rep = process_textures(str(tmp_path / "diffuse.<UDIM>.exr"), mfp=1.0,
                           output=str(out / "{stem}.exr"))
    assert rep.exit_code == 0, rep.summary()
    assert files_in(out) == ["diffuse.1001.exr", "diffuse.1002.exr"]
    a, _ = read_exr(out / "diffuse.1001.exr")
    b, _ = read_exr(out / "diffuse.1002.exr")
    assert not np.array_equal(a, b)


def test_two_inputs_one_output_fail_both_and_write_nothing(tmp_path, capsys):
    for name in ("a.exr", "b.exr"):
        write_exr(tmp_path / name, albedo())
    out = tmp_path / "out"
    rc = cli_main(["invert", str(tmp_path / "a.exr"), str(tmp_path / "b.exr"), "--no-progress",
                   "-o", str(out / "fixed.exr")])
    text = capsys.readouterr().out
    assert rc == 1
    assert text.count("is also the output of") == 2 and "0 done, 2 failed" in text
    assert not out.exists() or files_in(out) == []


def test_output_that_is_another_files_mfp_input_is_refused(tmp_path):
    write_exr(tmp_path / "a.exr", albedo())
    write_exr(tmp_path / "a_mfp.exr", np.ones((8, 10, 1), np.float32))
    before = (tmp_path / "a_mfp.exr").read_bytes()
    rep = process_textures(str(tmp_path / "a.exr"), mfp=str(tmp_path / "{stem}_mfp.exr"),
                           output=str(tmp_path / "{stem}_mfp.exr"))
    assert rep.exit_code == 1 and "would overwrite an input" in rep.results[0].error
    assert (tmp_path / "a_mfp.exr").read_bytes() == before


@pytest.mark.parametrize("command", [["invert"], ["blur", "--albedo", "0.5", "--mfp", "1"]])
def test_an_empty_output_path_is_named_as_such(tmp_path, capsys, command):
    write_exr(tmp_path / "a.exr", albedo())
    rc = cli_main([command[0], str(tmp_path / "a.exr"), *command[1:], "--no-progress",
                   "-o", ""])
    line = one_line_error(capsys.readouterr().err)
    assert rc == 2 and "output '': an empty path; name an .exr file" in line, line
    assert files_in(tmp_path) == ["a.exr"]


@pytest.mark.parametrize("suffix", [".jpg", ".png", ".tif", ""])
def test_formats_that_cannot_hold_the_result_are_refused(tmp_path, capsys, suffix):
    write_exr(tmp_path / "a.exr", albedo())
    rc = cli_main(["invert", str(tmp_path / "a.exr"), "--no-progress",
                   "-o", str(tmp_path / f"out{suffix}")])
    line = one_line_error(capsys.readouterr().err)
    assert rc == 2 and "output must be an OpenEXR file (.exr)" in line
    assert files_in(tmp_path) == ["a.exr"]


def test_blur_output_equal_to_its_input_is_refused(tmp_path, capsys):
    path = tmp_path / "irr.exr"
    write_exr(path, np.ones((8, 8, 3), np.float32))
    before = path.read_bytes()
    rc = cli_main(["blur", str(path), "--albedo", "0.5", "--mfp", "1", "-o", str(path)])
    line = one_line_error(capsys.readouterr().err)
    assert rc == 2 and "would overwrite an input" in line
    assert path.read_bytes() == before and files_in(tmp_path) == ["irr.exr"]


def test_blur_output_equal_to_a_parameter_texture_is_refused(tmp_path, capsys):
    write_exr(tmp_path / "irr.exr", np.ones((8, 8, 3), np.float32))
    write_exr(tmp_path / "alb.exr", np.full((8, 8, 3), 0.5, np.float32))
    before = (tmp_path / "alb.exr").read_bytes()
    rc = cli_main(["blur", str(tmp_path / "irr.exr"), "--albedo", str(tmp_path / "alb.exr"),
                   "--mfp", "1", "-o", str(tmp_path / "alb.exr")])
    assert rc == 2 and "would overwrite an input" in capsys.readouterr().err
    assert (tmp_path / "alb.exr").read_bytes() == before

# }}}


# {{{ half floats: values out of range are invalid, never written as "ok"

def test_half_overflow_fails_the_file_naming_the_texel(tmp_path, capsys):
    write_exr(tmp_path / "a.exr", albedo())
    out = tmp_path / "out"
    rc = cli_main(["invert", str(tmp_path / "a.exr"), "--mfp", "1e-6", "--half",
                   "--no-progress", "-o", str(out / "{stem}.exr")])
    text = capsys.readouterr().out
    assert rc == 1
    assert "outside the half-float range" in text and "x=0, y=0" in text
    assert "--on-invalid clamp" in text
    assert not out.exists() or files_in(out) == []


def test_half_overflow_clamped_and_counted(tmp_path):
    write_exr(tmp_path / "a.exr", albedo())
    rep = process_textures(str(tmp_path / "a.exr"), mfp=1e-6, half=True, on_invalid="clamp",
                           output=str(tmp_path / "out" / "{stem}.exr"))
    r = rep.results[0]
    assert rep.exit_code == 0 and r.invalid["half range"] > 0, rep.summary()
    px, _ = read_exr(r.output)
    assert np.all(np.isfinite(px)) and np.all(px > 0)
    assert "half range" in rep.summary()


def test_half_in_range_is_unchanged(tmp_path):
    write_exr(tmp_path / "a.exr", albedo())
    rep = process_textures(str(tmp_path / "a.exr"), mfp=1.0, half=True,
                           output=str(tmp_path / "out" / "{stem}.exr"))
    assert rep.exit_code == 0 and not rep.results[0].invalid.get("half range")

# }}}


# {{{ usage errors: exit 2, one line, no traceback

USAGE = [
    (["invert", "X", "--eta", "abc"], "argument --eta: 'abc': expected a number"),
    (["invert", "X", "--colorspace", "bogus"], "colorspace 'bogus' is unknown to OCIO config"),
    (["blur", "X", "--albedo", "0.5", "--mfp", "1", "--tol", "2", "-o", "y.exr"],
     "argument --tol: '2': expected a number in (0, 1)"),
    (["blur", "X", "--albedo", "0.5", "--mfp", "1", "--texel-size", "-1", "-o", "y.exr"],
     "argument --texel-size: '-1': expected a number > 0"),
    (["invert", "X", "--outputs", "sigma_a,sigmas"], "sigmas not allowed; choose from"),
    (["invert", "X", "--outputs", "alpha,alpha"], "'alpha,alpha': alpha given more than once"),
    (["invert", "X", "--max-memory", "12Q"], "'12Q': expected a size such as 512M"),
    (["invert", "X", "--max-memory", "-5M"], "'-5M': expected a size such as 512M"),
    (["blur", "X", "--albedo", "0.5", "--mfp", "1", "--max-memory", "-1e3", "-o", "y.exr"],
     "'-1e3': expected a size such as 512M"),
    (["blur", "X", "--albedo", "0.5", "--mfp", "1", "--tol", "-1e-3", "-o", "y.exr"],
     "argument --tol: '-1e-3': expected a number in (0, 1)"),
    (["invert", "X", "--mfp-scale", "0"], "argument --mfp-scale: '0': expected a number > 0"),
    (["invert", "X", "--mfp-scale", "nan"], "argument --mfp-scale: 'nan': expected a number"),
    (["invert", "X", "--mfp", "0"], "argument --mfp: '0': expected mfp in [1e-20, 3.4e+38]"),
    (["invert", "X", "--mfp", "1,nan,1"], "argument --mfp: '1,nan,1': expected mfp in"),
    (["invert", "X", "--mfp", "inf"], "argument --mfp: 'inf': expected mfp in [1e-20, 3.4e+38]"),
    (["blur", "X", "--albedo", "1.5", "--mfp", "1", "-o", "y.exr"],
     "argument --albedo: '1.5': expected albedo in (0, 1)"),
    (["blur", "X", "--albedo", "0.5", "--mfp", "-2", "-o", "y.exr"],
     "argument --mfp: '-2': expected mfp in [1e-20, 3.4e+38]"),
    (["blur", "X", "--alpha-prime", "1", "--sigma-t", "1", "-o", "y.exr"],
     "argument --alpha-prime: '1': expected alpha in [0, 1)"),
    (["blur", "X", "--alpha-prime", "0.5", "--sigma-t", "0", "-o", "y.exr"],
     "argument --sigma-t: '0': expected sigma_t in (0, inf)"),
    (["invert", "X", "--jobs", "0"], "'0': expected a whole number >= 1"),
    (["crosscheck", "--n", "0"], "'0': expected a whole number >= 1"),
    (["invert", "X", "--method", "auto", "--tol", "1e-9"], "--double on the command line"),
    (["blur", "X", "-o", "y.exr"], "give --albedo and --mfp"),
    (["blur", "X", "--alpha-prime", "0.9", "-o", "y.exr"], "--alpha-prime needs --sigma-t"),
    (["invert", "X", "--mfp", "1e300"], "'1e300': expected mfp in [1e-20, 3.4e+38]"),
    (["blur", "X", "--albedo", "0.5", "--mfp", "1e-30", "-o", "y.exr"],
     "'1e-30': expected mfp in [1e-20, 3.4e+38]"),
    (["invert", "X", "--mfp", "1", "--mfp-scale", "1e40"], "mfp 1 x mfp_scale 1e+40 = 1e+40"),
    (["invert", "X", "--table-size", "100000000"],
     "table_size=100000000: expected an integer from 1 to 65536"),
    (["invert", "X", "--method", "secant", "--tol", "inf"], "tol=inf: expected a finite number"),
]


@pytest.mark.parametrize("argv, message", USAGE, ids=[" ".join(a[:3]) for a, _ in USAGE])
def test_usage_errors_are_one_line_with_exit_2(argv, message, capsys, tmp_path):
    argv = [str(tmp_path / "in.exr") if a == "X" else a for a in argv]
    try:
        rc = cli_main(argv)
    except SystemExit as exc:          # argparse's own usage errors
        rc = exc.code
    line = one_line_error(capsys.readouterr().err)
    assert rc == 2 and message in line, line
    assert files_in(tmp_path) == []


def test_an_output_twice_is_refused_by_the_api(tmp_path):
    write_exr(tmp_path / "a.exr", albedo())
    with pytest.raises(ValueError, match="sigma_a given more than once"):
        process_textures(str(tmp_path / "a.exr"), outputs=("sigma_a", "rho", "sigma_a"),
                         output=str(tmp_path / "o.exr"))
    assert files_in(tmp_path) == ["a.exr"]


def test_eta_out_of_range_is_a_usage_error(tmp_path, capsys):
    write_exr(tmp_path / "a.exr", albedo())
    rc = cli_main(["invert", str(tmp_path / "a.exr"), "--eta", "10", "--no-progress"])
    line = one_line_error(capsys.readouterr().err)
    assert rc == 2 and "eta" in line and "10" in line

# }}}


# {{{ signals: stop cleanly, keep finished files, remove temporaries, exit 128 + signal

def _slow_batch(tmp_path, n=3):
    """Files big enough, in bands small enough, that a signal lands mid-batch."""
    for i in range(n):
        write_exr(tmp_path / f"t{i}.exr", np.random.default_rng(i).uniform(
            0.05, 0.9, (256, 512, 3)).astype(np.float32))
    return [sys.executable, "-m", "bdipole_cl", "invert", str(tmp_path / "t*.exr"),
            "--max-memory", "64K", "--no-progress", "-o", str(tmp_path / "out" / "{stem}.exr")]


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)],
                         ids=["SIGTERM", "SIGINT"])
def test_signal_stops_the_batch_cleanly(tmp_path, sig, code):
    argv = _slow_batch(tmp_path)
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out_dir = tmp_path / "out"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if out_dir.exists() and any(".partial-" in p for p in os.listdir(out_dir)):
            break
        time.sleep(0.01)
    assert proc.poll() is None, "the batch ended before a signal could be sent"
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == code, (stdout, stderr)
    assert "Traceback" not in stderr and "interrupted by signal" in stderr
    assert "cancelled" in stdout                      # the summary is printed
    left = os.listdir(out_dir)
    assert not [p for p in left if ".partial-" in p], left
    for name in left:                                 # finished files are complete
        px, names = read_exr(out_dir / name)
        assert px.shape == (256, 512, 6) and np.all(np.isfinite(px))



@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)],
                         ids=["SIGTERM", "SIGINT"])
def test_a_signal_while_the_command_loads_is_one_line(sig, code):
    """In the command (``signals.is_command``), a signal that lands while the library loads
    (before the command's own handling exists) ends it with 128 + the signal and one line,
    not a traceback. The signal is sent by the process to itself just before the package's
    imports, so it lands among them every time."""
    script = (f"import os, signal, sys; sys.argv[0] = 'bdipole-cl'; "
              f"from bdipole_cl.signals import quiet_startup; quiet_startup(); "
              f"os.kill(os.getpid(), {int(sig)}); import bdipole_cl.apps.cli; "
              f"print('loaded')")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == code and "loaded" not in proc.stdout, proc
    assert proc.stderr.strip() == (f"bdipole-cl: interrupted by signal {int(sig)} while "
                                   f"starting: nothing was read or written"), proc.stderr


@pytest.mark.parametrize("argv, orig, expected", [
    (["/venv/bin/bdipole-cl", "invert"], [], True),
    (["-m"], ["python3", "-m", "bdipole_cl", "invert"], True),
    (["-m"], ["python3", "-m", "pytest"], False),
    (["/x/bdipole_cl/__main__.py", "blur"], ["python3", "-m", "bdipole_cl", "blur"], True),
    (["script.py"], ["python3", "script.py"], False),
    (["/home/me/bdipole-cl.py"], ["python3", "/home/me/bdipole-cl.py"], False),
    (["bdipole-cl.test.py"], ["python3", "bdipole-cl.test.py"], False),
    (["bdipole-cl-tools"], [], False),
    # a worker spawned by the command, importing the command's script before it knows its
    # parent: its startup handler stayed for its life (a memory-limit kill said "interrupted
    # while starting")
    (["/venv/bin/bdipole-cl", "invert"], ["python3", "-c", "from multiprocessing.spawn import "
                                          "spawn_main; spawn_main(tracker_fd=5, pipe_handle=7)",
                                          "--multiprocessing-fork"], False),
    ([], [], False)])
def test_is_command_knows_the_command_only(argv, orig, expected):
    """The startup handling is the command's alone: a program that imports the library keeps
    Python's own handling of SIGINT and SIGTERM."""
    from bdipole_cl.signals import is_command
    assert is_command(argv, orig) is expected


def test_a_worker_the_command_spawned_is_not_the_command(monkeypatch):
    """multiprocessing gives a spawned worker the command's argv: it keeps Python's own
    signal handling (nothing would end its startup handling)."""
    import multiprocessing
    from bdipole_cl.signals import is_command
    monkeypatch.setattr(multiprocessing, "parent_process", lambda: object())
    assert not is_command(["/venv/bin/bdipole-cl", "invert"], [])


def test_after_startup_sigint_is_a_keyboard_interrupt(monkeypatch):
    """``end_startup``: SIGINT raises KeyboardInterrupt again (which the command reports as
    one line), also where it was ignored when the command started (a script's background
    job), and SIGTERM gets its handler from before."""
    from bdipole_cl import signals as sg
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    monkeypatch.setattr(sg, "_startup_handlers", {})
    monkeypatch.setattr(sg, "is_command", lambda: True)
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        sg.quiet_startup()
        assert signal.getsignal(signal.SIGINT) is sg._startup_exit
        assert signal.getsignal(signal.SIGTERM) is sg._startup_exit
        sg.end_startup()
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        assert signal.getsignal(signal.SIGTERM) is before[1]
    finally:
        signal.signal(signal.SIGINT, before[0])
        signal.signal(signal.SIGTERM, before[1])

# }}}


# {{{ channels, parameter textures, unclear messages

def test_only_colour_channels_are_inverted(tmp_path):
    px = np.concatenate([albedo(), np.ones((8, 10, 1)), np.full((8, 10, 1), 7.0)], axis=-1)
    write_exr(tmp_path / "rgbaz.exr", px, names=["R", "G", "B", "A", "Z"])
    rep = process_textures(str(tmp_path / "rgbaz.exr"), mfp=1.0,
                           output=str(tmp_path / "out" / "{stem}.exr"))
    assert rep.exit_code == 0, rep.summary()
    _, names = read_exr(rep.results[0].output)
    assert not any(n.endswith(".Z") or n.endswith(".A") for n in names), names
    assert "A" in names and "not colour, left out: Z" in rep.summary()


def test_grey_plus_alpha_is_one_colour(tmp_path):
    px = np.concatenate([np.full((8, 10, 1), 0.4), np.ones((8, 10, 1))], axis=-1)
    write_exr(tmp_path / "ya.exr", px, names=["Y", "A"])
    rep = process_textures(str(tmp_path / "ya.exr"), mfp=1.0,
                           output=str(tmp_path / "out" / "{stem}.exr"))
    _, names = read_exr(rep.results[0].output)
    assert sorted(names) == ["A", "sigma_a.Y", "sigma_s.Y"], names   # EXR sorts channels


def test_bad_parameter_texture_is_named_with_its_texel(tmp_path, capsys):
    write_exr(tmp_path / "irr.exr", np.ones((8, 8, 3), np.float32))
    alb = np.full((8, 8, 3), 0.5, np.float32)
    alb[3, 5, 1] = 1.0
    write_exr(tmp_path / "alb.exr", alb)
    rc = cli_main(["blur", str(tmp_path / "irr.exr"), "--albedo", str(tmp_path / "alb.exr"),
                   "--mfp", "1", "-o", str(tmp_path / "out.exr")])
    line = one_line_error(capsys.readouterr().err)
    assert rc == 1 and line.startswith(f"bdipole-cl blur: error: {tmp_path / 'alb.exr'}:")
    assert "x=5, y=3, channel G: 1" in line and "np.float32" not in line
    assert not (tmp_path / "out.exr").exists()


def test_directory_as_input_is_named_clearly(tmp_path):
    (tmp_path / "dir.exr").mkdir()
    rep = process_textures(str(tmp_path / "dir.exr"), mfp=1.0,
                           output=str(tmp_path / "out" / "{stem}.x.exr"))
    assert rep.exit_code == 1 and "is a directory" in rep.results[0].error


def test_udim_pattern_matching_nothing_says_so(tmp_path):
    rep = process_textures(str(tmp_path / "none.<UDIM>.exr"), mfp=1.0,
                           output=str(tmp_path / "out" / "{stem}.exr"))
    assert rep.exit_code == 1 and "no file matches" in rep.results[0].error


def test_a_pattern_matching_only_own_outputs_says_so(tmp_path):
    """A glob whose only matches are this tool's outputs (left out, so that a run never
    inverts its own outputs) says that, not that nothing matches."""
    from bdipole_cl.apps.demo import write_exr
    write_exr(tmp_path / "a.exr", np.full((4, 4, 3), 0.5, np.float32), ("R", "G", "B"))
    assert process_textures(str(tmp_path / "a.exr"), mfp=1.0,
                            output=str(tmp_path / "out" / "a.exr")).exit_code == 0
    rep = process_textures(str(tmp_path / "out" / "*.exr"), mfp=1.0,
                           output=str(tmp_path / "again" / "{stem}.exr"))
    error = rep.results[0].error
    assert rep.exit_code == 1 and "only this tool's own outputs" in error, error
    assert "out/a.exr" in error or "out\\a.exr" in error


def test_demo_in_an_unwritable_place_is_one_line(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    rc = cli_main(["demo", "--dir", str(blocker / "sub"), "--no-progress"])
    line = one_line_error(capsys.readouterr().err)
    assert rc == 1 and str(blocker) in line


def test_blur_of_an_empty_array_is_a_clear_error():
    from bdipole_cl import blur
    with pytest.raises(ValueError, match="irradiance is empty"):
        blur(np.zeros((0, 0, 3), np.float32), albedo=0.5, mfp=1.0)

# }}}


def test_more_bad_arguments_are_one_line_value_errors():
    import numpy as np
    from bdipole_cl import blur, invert_albedo
    rd = np.float32([0.5])
    with pytest.raises(ValueError, match="eta must be a scalar or one value per channel"):
        invert_albedo(rd, eta=[])
    with pytest.raises(ValueError, match="no texels or no channels"):
        blur(np.ones((4, 5, 0), np.float32), albedo=0.8, mfp=2.0)
    for tol in (0, float("nan"), 2):
        with pytest.raises(ValueError, match="takes 0 < tol < 1"):
            invert_albedo(rd, 1.4, method="auto", tol=tol)


def test_an_invalid_value_is_shown_in_the_digits_that_make_it_invalid():
    import numpy as np
    from bdipole_cl import InvalidInputError, invert_albedo
    with pytest.raises(InvalidInputError, match=r": 1\.000000001 \("):
        invert_albedo(np.array([1 + 1e-9]), 1.4)
    with pytest.raises(InvalidInputError, match=r"> 1\); first at index \(0,\): 2 \("):
        invert_albedo(np.array([2.0]), 1.4)


def test_a_uniform_texture_blurs_without_numpy_warnings():
    """Its kernel within the near field leaves a far part of 0: no 0 / 0 in the fit."""
    import warnings
    import numpy as np
    from bdipole_cl import blur
    e = np.random.default_rng(0).random((32, 30, 3), dtype=np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        out = blur(e, albedo=np.full((32, 30, 3), (0.8, 0.6, 0.4), np.float32), mfp=0.5)
    np.testing.assert_allclose(out, blur(e, albedo=(0.8, 0.6, 0.4), mfp=0.5), atol=1e-6)


@pytest.mark.parametrize("keywords", [{"mfp": 1.0, "texel_size": 1e-300}, {"mfp": 1e30}])
def test_a_kernel_beyond_float64_is_refused_not_blurred_to_zero(keywords):
    """An mfp of more than ~1e6 texels (mfp / texel_size) has a kernel far wider than any
    max_radius, whose radius no longer computes (1/sigma_t' overflows): it was blurred with a
    radius-0 plan to all zeros, 'ok'. It is refused, named."""
    from bdipole_cl import blur
    with pytest.raises(ValueError, match="an mfp of over a million texels"):
        blur(np.ones((4, 4, 1), np.float32), albedo=0.5, **keywords)


def test_a_masked_array_is_refused_not_unmasked_silently():
    """numpy.ma arrays lost their mask in np.asarray: the masked texels' data was blurred as
    if valid. A masked value is now a clear error naming the parameter (none masked: used)."""
    from bdipole_cl import blur
    e = np.ones((6, 7, 1), np.float32)
    albedo = np.ma.masked_array(np.full((6, 7), 0.5), mask=np.zeros((6, 7), bool))
    blur(e, albedo=albedo, mfp=1.0)                      # nothing masked: fine
    albedo[2, 3] = np.ma.masked
    for kw in ({"albedo": albedo, "mfp": 1.0}, {"albedo": 0.5, "mfp": albedo + 1.0}):
        with pytest.raises(ValueError, match="masked array with 1 masked value"):
            blur(e, **kw)
    with pytest.raises(ValueError, match="irradiance is a masked array"):
        blur(np.ma.masked_array(e, mask=e > 0), albedo=0.5, mfp=1.0)


def test_a_one_row_map_has_a_range():
    """value_range splits rows over the FFT threads: a map of one row left one thread no rows
    (np.min of nothing raised)."""
    from bdipole_cl.ops.blur.fft import value_range
    v = np.linspace(-3.0, 5.0, 1 << 17, dtype=np.float32).reshape(1, -1)
    assert value_range(v) == (-3.0, 5.0)


@pytest.mark.parametrize("dtype", [np.complex64, object, "U3"])
def test_blur_refuses_arrays_that_are_not_real_numbers(dtype):
    """A complex irradiance lost its imaginary part with only NumPy's ComplexWarning, and an
    object array was taken: refused, naming the dtype; float16, int and bool are numbers."""
    from bdipole_cl import blur
    with pytest.raises(ValueError, match="irradiance has dtype"):
        blur(np.ones((4, 4, 3)).astype(dtype), albedo=0.5, mfp=1.0)
    with pytest.raises(ValueError, match="albedo has dtype"):
        blur(np.ones((4, 4, 3), np.float32), albedo=np.ones((4, 4, 3)).astype(dtype), mfp=1.0)
    for ok in (np.float16, np.int32, bool):
        assert np.all(np.isfinite(blur(np.ones((4, 4, 3)).astype(ok), albedo=0.5, mfp=1.0)))


def test_a_bit_rotted_header_or_a_latin1_name_fails_only_its_file(tmp_path, capsys):
    """A tile whose header has 4 flipped bytes (OpenImageIO's message then quotes bytes that
    are not UTF-8, which its bindings could not decode) and a file whose name is Latin-1 (which
    they refuse): each fails its own job, named, and the other files are inverted, exit 1 (a
    codec error or TypeError stopped the whole batch, exit 2, no file named)."""
    for tile in (1001, 1002, 1003):
        write_exr(tmp_path / f"t.{tile}.exr", albedo())
    data = bytearray((tmp_path / "t.1002.exr").read_bytes())
    for offset, value in ((37, 243), (77, 102), (165, 154), (333, 121)):
        data[offset] = value
    (tmp_path / "t.1002.exr").write_bytes(bytes(data))
    latin1 = os.path.join(os.fsencode(str(tmp_path)), b"caf\xe9.1004.exr")
    with open(latin1, "wb") as f:
        f.write((tmp_path / "t.1001.exr").read_bytes())
    p = subprocess.run([sys.executable, "-m", "bdipole_cl", "invert", str(tmp_path / "*.exr"),
                        "-o", str(tmp_path / "o" / "{stem}.exr"), "--no-progress"],
                       capture_output=True, timeout=300, env=dict(os.environ, LC_ALL="C"))
    out = p.stdout.decode("utf-8", "replace")
    assert p.returncode == 1, out + p.stderr.decode("utf-8", "replace")
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["t.1001.exr", "t.1003.exr"]
    assert "t.1002.exr: cannot read albedo:" in out
    assert "caf\\xe9.1004.exr: a file name that is not UTF-8" in out


def test_skip_existing_sees_a_link_re_pointed_at_an_older_file(tmp_path):
    """--skip-existing with alb.exr -> v1.exr baked, then re-pointed at v2.exr, an older file
    (a "latest" link rolled back): the link is a new input, so the job runs again (it was
    skipped: only the file's own times were compared with the output's)."""
    write_exr(tmp_path / "v2.exr", albedo(value=0.2))
    os.utime(tmp_path / "v2.exr", (1e9, 1e9))                   # 2001: older than any output
    write_exr(tmp_path / "v1.exr", albedo(value=0.6))
    link = tmp_path / "alb.exr"
    link.symlink_to("v1.exr")
    out = tmp_path / "out.exr"
    argv = ["invert", str(link), "-o", str(out), "--skip-existing", "--no-progress"]
    assert cli_main(argv) == 0
    first = read_exr(out)[0]
    time.sleep(0.01)
    link.unlink()
    link.symlink_to("v2.exr")
    assert cli_main(argv) == 0
    second = read_exr(out)[0]
    assert cli_main(["invert", str(tmp_path / "v2.exr"), "-o", str(tmp_path / "v2_out.exr"),
                     "--no-progress"]) == 0
    assert np.array_equal(second, read_exr(tmp_path / "v2_out.exr")[0])    # v2's, not v1's
    assert not np.array_equal(second, first)
    assert cli_main(argv) == 0 and np.array_equal(read_exr(out)[0], second)


def test_blur_says_which_channels_it_leaves_out_and_names_a_maps_own_channel(tmp_path, capsys):
    """A blur of R, G, B, weird.x, Z says Z and weird.x are left out (as invert does; they were
    dropped unsaid); a bad texel of a one-channel Y mfp map is named in channel Y, its own (it
    was named by the irradiance's channel, R)."""
    rng = np.random.default_rng(0)
    write_exr(tmp_path / "five.exr", rng.uniform(0.1, 0.9, (8, 10, 5)),
              ["R", "G", "B", "weird.x", "Z"])
    with pytest.warns(UserWarning, match=r"five\.exr: not colour, left out: weird\.x, Z|"
                                         r"five\.exr: not colour, left out: Z, weird\.x"):
        assert cli_main(["blur", str(tmp_path / "five.exr"), "--albedo", "0.8", "--mfp", "1",
                         "-o", str(tmp_path / "b.exr"), "--no-progress"]) == 0
    mfp = np.ones((8, 10, 1), np.float32)
    mfp[2, 3] = np.nan
    write_exr(tmp_path / "mfp_y.exr", mfp, ["Y"])
    assert cli_main(["blur", str(tmp_path / "five.exr"), "--albedo", "0.8", "--mfp",
                     str(tmp_path / "mfp_y.exr"), "-o", str(tmp_path / "c.exr"),
                     "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "mfp_y.exr: 1 invalid mfp value(s)" in err and "x=3, y=2, channel Y: nan" in err
