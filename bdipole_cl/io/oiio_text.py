"""What OpenImageIO is given and says, as text (I/O): its Python bindings take a path only as
UTF-8 and decode their error messages as UTF-8, so a file name in another encoding (Latin-1
from an SMB share) or a corrupt header's bytes quoted in a message raise TypeError or
UnicodeDecodeError where the caller expects a result. ``oiio_error`` reads a message whatever
its bytes (``images.oiio_path`` names such a file in one line)."""
from __future__ import annotations

import OpenImageIO as oiio

from ..errors import one_line

#: said for a message OpenImageIO holds whose bytes are not UTF-8
NOT_TEXT = "OpenImageIO's message is not text (bytes of a corrupt header?)"


def oiio_error(source=None) -> str:
    """The pending error of ``source`` (an ImageInput, ImageOutput, ImageBuf or ColorConfig),
    else OpenImageIO's global one, as one line ("" when none); both are taken (cleared)."""
    texts = []
    for get in ((source.geterror,) if source is not None else ()) + (oiio.geterror,):
        try:
            texts.append(get())
        except UnicodeDecodeError:
            texts.append(NOT_TEXT)
    return one_line(next((t for t in texts if t), ""))

