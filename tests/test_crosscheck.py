"""``bdipole-cl crosscheck`` (bdipole_cl/crosscheck.py): built-in table and user kernels."""
import pytest

from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.apps.crosscheck import run_crosscheck
from bdipole_cl.apps.user_kernel import (ALPHA_ULPS, RD_RANGES, UserKernelError,
                                         check_user_kernel, sorted_sweep)

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


#: a correct (if slow) user inversion: bisection on a stable residual in double, returning
#: alpha', rho or both (OUT is replaced)
GOOD = """
    float good(float rd, float two_c1, float three_c2 OUTARGS) {
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
        RETURN
    }"""
FORMS = {"invert": ("", "return (float)(1.0 - q * q);"),
         "invert-rho": ("", "return (float)(q * q);"),
         "invert-both": (", float *alpha, float *rho",
                         "*alpha = (float)(1.0 - q * q); *rho = (float)(q * q);")}


def good_kernel(tmp_path, form):
    args, ret = FORMS[form]
    path = tmp_path / f"good_{form.replace('-', '_')}.cl"
    path.write_text(GOOD.replace("OUTARGS", args).replace("RETURN", ret).replace(
        "float good(", "void good(" if form == "invert-both" else "float good("))
    return str(path)


def by_kind(rows):
    """The per-range rows: alpha' (judged in ulps) and rho (relative)."""
    ranged = [r for r in rows if "Rd in" in r.function]
    return {"alpha'": [r for r in ranged if r.unit == "ulp"],
            "rho": [r for r in ranged if r.unit == "rel"]}


def test_memo_alpha_is_judged_in_ulps_and_its_rho_shown_per_range():
    rows = check_user_kernel(MEMO_CL, "computeAlphaPrime", "invert", eta=1.4, n=100)
    groups = by_kind(rows)
    assert len(groups["alpha'"]) == len(RD_RANGES) == len(groups["rho"])
    # alpha' within a few ulps of the correctly rounded one everywhere: it passes ...
    assert all(r.status == "PASS" and r.unit == "ulp" for r in groups["alpha'"])
    # ... and rho = 1 - alpha' is shown, not judged: it is off by 100% near Rd = 1
    assert all(r.status == "INFO" for r in groups["rho"])
    assert groups["rho"][-1].max_error > 0.5 and groups["rho"][0].max_error < 1e-6
    assert all("NaN 0; non-monotone steps" in r.where for r in rows if "Rd in" in r.function)


@pytest.mark.parametrize("form", ["invert", "invert-rho", "invert-both"])
def test_a_correct_kernel_passes_in_every_form(tmp_path, form):
    rows = check_user_kernel(good_kernel(tmp_path, form), "good", form, eta=1.4, n=60)
    groups = by_kind(rows)
    judged = [r for r in rows if r.status != "INFO"]
    assert judged and all(r.status == "PASS" for r in judged), [(r.function, r.max_error)
                                                                  for r in judged]
    if form != "invert":                 # rho returned: judged, within the contract
        assert all(r.status == "PASS" for r in groups["rho"])
    if form != "invert-rho":             # alpha' returned: within ALPHA_ULPS
        assert max(r.max_error for r in groups["alpha'"]) <= ALPHA_ULPS


def test_n_sets_the_sweep_and_the_worst_point_shows_all_digits():
    assert len(sorted_sweep(50)) < len(sorted_sweep(200))
    rows = check_user_kernel(MEMO_CL, "computeAlphaPrime", "invert", eta=1.4, n=50)
    last = [r for r in rows if "[0.99, 1)" in r.function][-1]
    assert "Rd=0.9" in last.where and "Rd=1;" not in last.where


def test_jensens_dipole_is_named(tmp_path):
    # Jensen's dipole inverted (Rd = a/2 (1 + e^{-4/3 A s}) e^{-s}, s = sqrt(3 (1 - a))): a
    # different model, which the check must say rather than only fail
    path = tmp_path / "jensen.cl"
    path.write_text("""
        float jensen(float rd, float two_c1, float three_c2) {
            double fdr = 0.5 * (two_c1 + three_c2) ;  // any A: the shape is what differs
            double A = (1.0 + fdr) / (1.0 - fdr), lo = 0.0, hi = 1.0;
            for (int i = 0; i < 80; ++i) {
                double a = 0.5 * (lo + hi), s = sqrt(3.0 * (1.0 - a));
                double r = 0.5 * a * (1.0 + exp(-4.0 / 3.0 * A * s)) * exp(-s);
                if (r < rd) lo = a; else hi = a;
            }
            return (float)(0.5 * (lo + hi));
        }""")
    rows = check_user_kernel(path, "jensen", "invert", eta=1.4, n=60)
    assert any("follows Jensen's dipole" in r.function for r in rows)
    assert not any("follows Jensen" in r.function
                   for r in check_user_kernel(MEMO_CL, "computeAlphaPrime", "invert", n=40))


def test_user_kernel_errors_state_the_signature_and_the_users_line(tmp_path, capsys):
    bad = tmp_path / "bad.cl"
    bad.write_text("float ok(float x) { return x; }\n\nfloat broken(float rd, float a, "
                   "float b)\n{\n    return rd * undefined_thing;\n}\n")
    assert cli_main(["crosscheck", "--user-kernel", str(bad), "--function", "broken",
                     "--against", "invert"]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:5:" in err and "expected: float broken(float rd, float two_c1" in err
    assert err.count("\n") == 1
    with pytest.raises(UserKernelError, match=r"no function named missing \(expected: float "
                                              r"missing\(float alpha_prime"):
        check_user_kernel(bad, "missing", "rd")


def test_a_kernel_that_never_ends_is_stopped(tmp_path, capsys):
    spin = tmp_path / "spin.cl"
    spin.write_text("float spin(float rd, float a, float b) {\n"
                    "    float x = rd;\n    while (x >= 0.0f) { x = x * 1.0000001f + 1.0f; }\n"
                    "    return x;\n}\n")
    assert cli_main(["crosscheck", "--user-kernel", str(spin), "--function", "spin",
                     "--against", "invert", "--timeout", "3"]) == 1
    assert "did not finish within 3 s" in capsys.readouterr().err


def test_user_kernel_cli_exit_codes(tmp_path, capsys):
    # the memo's alpha' passes and its rho is not judged: exit 0; a wrong kernel exits 1
    assert cli_main(["crosscheck", "--user-kernel", MEMO_CL, "--function", "computeAlphaPrime",
                     "--against", "invert", "--eta", "1.4", "--n", "50"]) == 0
    out = capsys.readouterr().out
    assert "INFO" in out and "ulps from the correctly rounded" in out
    wrong = tmp_path / "wrong.cl"
    wrong.write_text("float wrong(float rd, float a, float b) { return sqrt(rd); }")
    assert cli_main(["crosscheck", "--user-kernel", str(wrong), "--function", "wrong",
                     "--against", "invert-rho", "--n", "50"]) == 1


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
