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
