"""MAT-files as MATLAB's default ``save`` (-v7) writes them: MATLAB 5 format, each variable a
zlib-compressed element. scipy.io.savemat serialises the variables; they are compressed here, one
at a time, at a chosen zlib level (scipy's fixed level is several times slower on a gigabyte of
float32, and the reader does not care: ``scipy.io.loadmat`` and MATLAB read any level)."""

from __future__ import annotations

import io
import struct
import zlib
from pathlib import Path

import numpy as np

HEADER_BYTES = 128
MI_COMPRESSED = 15


def save(path: Path, variables: dict[str, np.ndarray], level: int = 1) -> None:
    """Write ``variables`` (name → array or cell array) to ``path``; ``level`` 0: uncompressed."""
    from scipy.io import savemat

    with path.open("wb") as out:
        for i, (name, value) in enumerate(variables.items()):
            buf = io.BytesIO()
            savemat(buf, {name: value}, do_compression=False, format="5")
            data = buf.getbuffer()
            if i == 0:
                out.write(data[:HEADER_BYTES])
                tag = "<II" if bytes(data[HEADER_BYTES - 2 : HEADER_BYTES]) == b"IM" else ">II"
            element = data[HEADER_BYTES:]
            if level:
                packed = zlib.compress(element, level)
                out.write(struct.pack(tag, MI_COMPRESSED, len(packed)))
                out.write(packed)
                del packed
            else:
                out.write(element)
            del element, data
            buf.close()
