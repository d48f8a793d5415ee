"""A host-backed stand-in of bdipole_cl.ops.device_fft (testing the plumbing only)."""
import sys, types
import numpy as np
import pyopencl as cl

def device_fft_len(n):
    import scipy.fft as sfft
    m = sfft.next_fast_len(n, real=True)
    while m % 2 or any(f not in (2, 3, 5) for f in _factors(m)):
        m += 1
    return m

def _factors(m):
    out, p = [], 2
    while m > 1:
        while m % p == 0:
            out.append(p); m //= p
        p += 1
    return out

class DeviceFFT:
    def __init__(self, rt, shape, batch, double):
        self.rt, self.shape, self.batch = rt, shape, batch
        self.dtype = np.float64 if double else np.float32
        self.cdtype = np.complex128 if double else np.complex64
    def forward(self, src, dst, wait_for=None):
        q = self.rt.queue
        n0, n1 = self.shape
        x = np.empty((self.batch, n0, n1), self.dtype)
        cl.enqueue_copy(q, x, src, wait_for=wait_for)
        y = np.fft.rfft2(x.astype(np.float64)).astype(self.cdtype)
        return cl.enqueue_copy(q, dst, np.ascontiguousarray(y), is_blocking=True)
    def inverse(self, src, dst, rows=None, wait_for=None):
        q = self.rt.queue
        n0, n1 = self.shape
        y = np.empty((self.batch, n0, n1 // 2 + 1), self.cdtype)
        cl.enqueue_copy(q, y, src, wait_for=wait_for)
        x = np.fft.irfft2(y.astype(np.complex128), (n0, n1)).astype(self.dtype)
        if rows is not None:
            x = x[:, rows[0]:rows[1]]
        return cl.enqueue_copy(q, dst, np.ascontiguousarray(x), is_blocking=True)

