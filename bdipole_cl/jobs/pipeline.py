"""Bands streamed through read -> compute -> write with the I/O overlapped: band k+1 is read
and band k-1 written (one helper thread each) while band k is computed, so that a file job's
time is near the largest of the three, not their sum (EXR decoding and zip compression, the
host FFTs and the device kernels all release the GIL). Writes stay in order, one at a time;
an error in any step stops the stream at the next band and is raised here."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

#: bands in memory at once besides the one computed: the one read ahead and the one written
BANDS_IN_FLIGHT = 2


def stream_bands(bands, read, compute, write):
    """For each band, in order: ``write(band, compute(band, read(band)))``, overlapped."""
    bands = list(bands)
    if not bands:
        return
    with ThreadPoolExecutor(1, "bdipole-read") as reads, \
            ThreadPoolExecutor(1, "bdipole-write") as writes:
        pending, written = reads.submit(read, bands[0]), None
        try:
            for k, band in enumerate(bands):
                data = pending.result()
                if k + 1 < len(bands):
                    pending = reads.submit(read, bands[k + 1])
                block = compute(band, data)
                if written is not None:
                    written.result()            # in order, one at a time; its error here
                written = writes.submit(write, band, block)
            written.result()
        finally:
            pending.cancel()
