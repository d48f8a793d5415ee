// The memo's own functions (Hery, Pixar TM 12-11, p. 2), as a user kernel for
// `bdipole-cl crosscheck --user-kernel`. Only changes: the parameter types the printed code
// leaves out (twoC1, threeC2 are floats) and f-suffixed literals.
//
//   bdipole-cl crosscheck --user-kernel tools/examples/memo_hery_tm_12_11.cl \
//       --function computeRd --against rd
//   bdipole-cl crosscheck --user-kernel tools/examples/memo_hery_tm_12_11.cl \
//       --function computeAlphaPrime --against invert

float computeRd(float alpha_prime, float twoC1, float threeC2)
{
    float Cphi = 0.25f * (1.0f - twoC1);
    float Ce = 0.5f * (1.0f - threeC2);
    float fourA = (1.0f + threeC2) / Cphi;
    float mu_tr_D = sqrt((1.0f - alpha_prime) * (2.0f - alpha_prime) / 3.0f);
    float myexp = exp(-fourA * mu_tr_D);
    float Rd = 0.5f * alpha_prime * alpha_prime
               * exp(-sqrt(3.0f * (1.0f - alpha_prime) / (2.0f - alpha_prime)))
               * (Ce * (1.0f + myexp) + Cphi / mu_tr_D * (1.0f - myexp));
    return Rd;
}

float computeAlphaPrime(float Rd, float twoC1, float threeC2)
{
    int i, niter = 50;
    float x0 = 0, x1 = 1;
    float xmid, fmid;
    for (i = 0; i < niter; i += 1) {
        xmid = 0.5f * (x0 + x1);
        fmid = computeRd(xmid, twoC1, threeC2);
        if (fmid < Rd) {
            x0 = xmid;
        } else {
            x1 = xmid;
        }
    }
    return xmid;
}
