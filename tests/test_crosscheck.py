"""``bdipole-cl crosscheck`` (bdipole_cl/crosscheck.py): built-in table and user kernels."""
import pytest

from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.apps.crosscheck import check_user_kernel, run_crosscheck

MEMO_CL = "tools/examples/memo_hery_tm_12_11.cl"


#: every test here runs once per working OpenCL device (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("on_device")


def test_every_builtin_kernel_meets_its_bound(capsys):
    rows = run_crosscheck((1.4,), n=100)
    assert {r.status for r in rows} <= {"PASS", "INFO"}, [r for r in rows if r.status == "FAIL"]
    names = " ".join(r.function for r in rows)
    for f in ("rd", "1 - rd", "profile", "profile_cdf", "profile_tail", "invert table",
              "invert secant", "invert bisection", "blur direct", "blur gaussians", "blur fft"):
        assert f in names, f
    assert cli_main(["crosscheck", "--eta", "1.4", "--n", "100"]) == 0
    out = capsys.readouterr().out
    print(out)                                  # the table, in CI's log
    assert "0 over their bound" in out


def test_user_kernel_memo_code_is_caught_losing_rho():
    rows = check_user_kernel(MEMO_CL, "computeAlphaPrime", "invert", eta=1.4, n=300)
    by = {r.function.split()[-1]: r for r in rows}
    assert by["alpha"].status == "PASS"           # alpha' itself is fine ...
    assert by["rho"].status == "FAIL" and by["rho"].max_error > 1e-2   # ... rho is not (docs/model.md "Stiffness")


def test_user_kernel_cli_exit_codes(tmp_path, capsys):
    assert cli_main(["crosscheck", "--user-kernel", MEMO_CL, "--function", "computeAlphaPrime",
                     "--against", "invert", "--eta", "1.4"]) == 1
    assert "FAIL" in capsys.readouterr().out
    good = tmp_path / "good.cl"
    # a correct (if slow) user inversion: float bisection on a stable residual in double
    good.write_text("""
        float myInvert(float rd, float two_c1, float three_c2) {
            double cphi = 0.25 * (1.0 - two_c1), ce = 0.5 * (1.0 - three_c2);
            double a4 = 4.0 * (1.0 + three_c2) / (1.0 - two_c1);
            double lo = 0.0, hi = 1.0;
            for (int i = 0; i < 80; ++i) {
                double q = 0.5 * (lo + hi), rho = q * q, a = 1.0 - rho;
                double m = sqrt(rho * (1.0 + rho) / 3.0), x = a4 * m;
                double p1 = x > 0.0 ? -expm1(-x) / x : 1.0;
                double rd_q = 0.5 * a * a * exp(-sqrt(3.0 * rho / (1.0 + rho)))
                              * (ce * (1.0 + exp(-x)) + cphi * a4 * p1);
                if (rd_q > rd) lo = q; else hi = q;
            }
            double q = 0.5 * (lo + hi);
            return (float)(1.0 - q * q);
        }""")
    rows = {r.function.split()[-1]: r for r in check_user_kernel(good, "myInvert", "invert",
                                                                  eta=1.4, n=300)}
    # alpha' passes; rho from a float32 alpha' cannot (the reason bdipole_cl returns rho)
    assert rows["alpha"].status == "PASS" and rows["rho"].status == "FAIL"
    bad = tmp_path / "bad.cl"
    bad.write_text("float broken(float x { return x; }")
    assert cli_main(["crosscheck", "--user-kernel", str(bad), "--function", "broken",
                     "--against", "rd"]) == 2
    assert "building broken failed" in capsys.readouterr().err


def test_user_rd_and_profile_kernels_are_checked(tmp_path):
    # the memo's computeRd has a 0/0 at alpha' = 1: caught
    (row,) = check_user_kernel(MEMO_CL, "computeRd", "rd", eta=1.4, n=200)
    assert row.status == "FAIL"
    # memo eq. 1 written literally in float: fine near the source, cancels far out
    lit = tmp_path / "profile.cl"
    lit.write_text("""
        float literalR(float r, float a, float st, float two_c1, float three_c2) {
            float cphi = 0.25f * (1.0f - two_c1), ce = 0.5f * (1.0f - three_c2);
            float A = (1.0f + three_c2) / (1.0f - two_c1);
            float sa = st * (1.0f - a), D = (2.0f * sa + st * a) / (3.0f * st * st);
            float mu = sqrt(sa / D), zr = 1.0f / st, zv = -zr - 4.0f * A * D;
            float dr = sqrt(r * r + zr * zr), dv = sqrt(r * r + zv * zv);
            return a * a / (4.0f * M_PI_F) * (
                (ce * zr * (mu * dr + 1.0f) / (dr * dr) + cphi / D) * exp(-mu * dr) / dr
              - (ce * zv * (mu * dv + 1.0f) / (dv * dv) + cphi / D) * exp(-mu * dv) / dv);
        }""")
    (row,) = check_user_kernel(lit, "literalR", "profile", eta=1.4, n=400)
    assert row.status == "FAIL" and row.max_error > 1e-4, row
