"""The CLI's exit code comes from the error's type, never from its message: a usage error
whose text happens to say "died" or "did not finish" (words of a run that failed) still exits
2, a failure 1 (``main``'s contract: usage 2, failure 1). No device needed: these fail before
any kernel is built."""
import pytest

from bdipole_cl.apps.cli import main as cli_main


def test_a_missing_function_named_like_a_failed_run_is_a_usage_error(tmp_path, capsys):
    source = tmp_path / "kernel.cl"
    source.write_text("float ok(float rd, float a, float b) { return rd; }\n")
    assert cli_main(["crosscheck", "--user-kernel", str(source), "--function", "died",
                     "--against", "invert"]) == 2
    assert "no function named died" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["did not finish.cl", "it died.cl"])
def test_a_missing_file_named_like_a_failed_run_is_a_usage_error(tmp_path, capsys, name):
    assert cli_main(["crosscheck", "--user-kernel", str(tmp_path / name), "--function", "f",
                     "--against", "invert"]) == 2
    assert name in capsys.readouterr().err


@pytest.mark.parametrize("variable, value", [("BDIPOLE_CL_GATHER_WIDTH", "3"),
                                             ("BDIPOLE_CL_TABLE_WIDTH", "sixteen")])
def test_a_bad_width_variable_is_a_usage_error_before_any_file(tmp_path, capsys, monkeypatch,
                                                                 variable, value):
    # it names the variable, not the input file that first reached a kernel, and no output
    # is written (the check runs before the command)
    monkeypatch.setenv(variable, value)
    out = tmp_path / "out.exr"
    assert cli_main(["invert", str(tmp_path / "albedo.exr"), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert variable in err and repr(value) in err and "albedo.exr" not in err
    assert not out.exists()


def test_an_eta_outside_the_model_is_a_usage_error_in_blur_as_in_invert(tmp_path, capsys):
    """blur --eta 3 failed each file (exit 1) where invert and profile exit 2: the model's
    range is an option's, checked before any file is read; the message names the CLI flag."""
    assert cli_main(["blur", str(tmp_path / "irr.exr"), "--albedo", "0.5", "--mfp", "1",
                     "--eta", "3", "-o", str(tmp_path / "o.exr")]) == 2
    err = capsys.readouterr().err
    assert "eta=3.0 is outside" in err and "--exact" in err and "irr.exr" not in err, err


@pytest.mark.parametrize("args, named", [
    (["--unit", "furlong"], "--unit: 'furlong'"),
    (["--radius", "1e30"], "--radius: '1e30': expected radius in [1e-20, 1e+20]"),
    (["--radius", "0.001", "--radius-scale", "1e-30"], "radius 0.001 x radius_scale 1e-30"),
], ids=["unit", "radius", "radius-scale"])
def test_convert_options_are_usage_errors_before_any_file(tmp_path, capsys, args, named):
    # --unit furlong wrote the EXR, then failed the materials (exit 1); a constant radius out
    # of the texels' range [1e-20, 1e20] (the parser took up to 3.4e38) failed each file as
    # "ok.exr: 60 invalid radius value(s)", naming the colour file for a constant
    import numpy as np
    import OpenImageIO as oiio
    spec = oiio.ImageSpec(4, 4, 3, "float")
    out = oiio.ImageOutput.create(str(tmp_path / "ok.exr"))
    assert out.open(str(tmp_path / "ok.exr"), spec)
    out.write_image(np.full((4, 4, 3), 0.5, np.float32))
    out.close()
    try:
        rc = cli_main(["convert", str(tmp_path / "ok.exr"), "--target", "openpbr", *args])
    except SystemExit as exc:            # the parser's own usage errors
        rc = exc.code
    err = capsys.readouterr().err
    assert rc == 2 and named in err and "ok.exr" not in err, (rc, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ok.exr"]
