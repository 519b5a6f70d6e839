"""Reading image files, and telling a complete image from a truncated one.

OpenCV decodes the first half of a truncated JPEG without an error: it fills the rest with grey and
prints a libjpeg warning that names no file. A dataset image cut short by an interrupted copy would then
be scored as if it were whole. :func:`image_defect` therefore checks the file's structure before it is
decoded, from its bytes alone, recognising the format by its signature (not by the file's extension,
which real downloads sometimes get wrong):

* **JPEG** -- the marker segments are walked from the start-of-image marker, skipping each segment by its
  length (so an end-of-image marker inside an embedded EXIF thumbnail is not mistaken for the file's
  end) and each entropy-coded scan up to the next marker, until the end-of-image marker ``FF D9``.
  Bytes after it are allowed (some cameras append data);
* **PNG** -- the signature, then every chunk: its length must fit in the file and its CRC must match,
  up to the ``IEND`` chunk;
* **BMP** -- the pixel array that the header describes (offset + row stride x height) must fit in the file.

Other formats are only decoded. :func:`decode_image` checks, then decodes with OpenCV;
:func:`read_image` does so for a file.
"""

from __future__ import annotations

import re
import zlib
from pathlib import Path

import numpy as np

__all__ = ["image_defect", "decode_image", "read_image"]

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# The end of an entropy-coded JPEG scan: 0xFF followed by a byte that is neither a stuffed zero, a
# restart marker (D0-D7) nor a fill byte (FF).
_JPEG_SCAN_END = re.compile(rb"\xff[^\x00\xd0-\xd7\xff]")


def _jpeg_defect(data: bytes) -> str | None:
    n = len(data)
    truncated = f"truncated JPEG: its {n} bytes end before the end-of-image marker FF D9"
    pos = 2
    while True:
        if pos >= n:
            return truncated
        if data[pos] != 0xFF:
            return f"corrupt JPEG: expected a marker at byte {pos}, found 0x{data[pos]:02X}"
        while pos < n and data[pos] == 0xFF:  # fill bytes may precede a marker
            pos += 1
        if pos >= n:
            return truncated
        marker = data[pos]
        pos += 1
        if marker == 0xD9:  # end of image
            return None
        if marker == 0x01 or 0xD0 <= marker <= 0xD8:  # markers without a length
            continue
        if pos + 2 > n:
            return truncated
        length = int.from_bytes(data[pos : pos + 2], "big")
        if length < 2:
            return f"corrupt JPEG: segment 0xFF{marker:02X} at byte {pos - 2} has length {length}"
        pos += length
        if pos > n:
            return truncated
        if marker == 0xDA:  # start of scan: entropy-coded data up to the next marker
            m = _JPEG_SCAN_END.search(data, pos)
            if m is None:
                return truncated
            pos = m.start()


def _png_defect(data: bytes) -> str | None:
    n = len(data)
    pos = 8
    while True:
        if pos + 12 > n:
            return f"truncated PNG: its {n} bytes end before the IEND chunk"
        length = int.from_bytes(data[pos : pos + 4], "big")
        kind = data[pos + 4 : pos + 8]
        end = pos + 12 + length
        if end > n:
            return f"truncated PNG: its {n} bytes end inside the {kind!r} chunk at byte {pos}"
        if zlib.crc32(data[pos + 4 : end - 4]) != int.from_bytes(data[end - 4 : end], "big"):
            return f"corrupt PNG: the {kind!r} chunk at byte {pos} fails its CRC check"
        if kind == b"IEND":
            return None
        pos = end


def _bmp_defect(data: bytes) -> str | None:
    n = len(data)
    if n < 18:
        return f"truncated BMP: {n} bytes, shorter than its file header"
    offset = int.from_bytes(data[10:14], "little")
    header = int.from_bytes(data[14:18], "little")
    if n < 14 + header or header < 12:
        return f"truncated BMP: {n} bytes, shorter than its headers"
    if header == 12:  # OS/2 BITMAPCOREHEADER
        width = int.from_bytes(data[18:20], "little")
        height = int.from_bytes(data[20:22], "little")
        bpp, compression = int.from_bytes(data[24:26], "little"), 0
    else:
        width = int.from_bytes(data[18:22], "little", signed=True)
        height = int.from_bytes(data[22:26], "little", signed=True)
        bpp = int.from_bytes(data[28:30], "little")
        compression = int.from_bytes(data[30:34], "little")
    if compression in (0, 3, 6):  # uncompressed pixels (BI_RGB, BI_BITFIELDS, BI_ALPHABITFIELDS)
        need = offset + (abs(width) * bpp + 31) // 32 * 4 * abs(height)
    else:  # run-length or embedded JPEG/PNG: the header gives the size of the pixel data
        need = offset + int.from_bytes(data[34:38], "little")
    if n < need:
        return f"truncated BMP: {n} bytes, but its header describes {need}"
    return None


# (signature, check) of the formats whose structure is checked
_CHECKS = ((b"\xff\xd8", _jpeg_defect), (_PNG_SIGNATURE, _png_defect), (b"BM", _bmp_defect))


def image_defect(data: bytes) -> str | None:
    """What is structurally wrong with the bytes of an image file, or ``None`` if nothing is found.

    JPEG, PNG and BMP data (recognised by their signatures) are checked for truncation and corruption as
    the module docstring describes; anything else is left to the decoder (``None``).

    Parameters
    ----------
    data
        The whole file.

    Returns
    -------
    ``None``, or a sentence such as ``"truncated JPEG: its 4096 bytes end before the end-of-image
    marker FF D9"``.
    """
    if not data:
        return "empty file (0 bytes)"
    for signature, check in _CHECKS:
        if data.startswith(signature):
            return check(data)
    return None


def decode_image(data: bytes, flags: int | None = None, name: str = "image data") -> np.ndarray:
    """Check (:func:`image_defect`), then decode the bytes of an image file with OpenCV.

    Parameters
    ----------
    data
        The whole file.
    flags
        OpenCV ``imread`` flags (default ``cv2.IMREAD_COLOR``: BGR, 3 channels).
    name
        What to call it in messages (the file's path).

    Raises
    ------
    ValueError
        If the data is truncated or corrupt, or does not decode, naming ``name``.
    """
    import cv2

    defect = image_defect(data)
    if defect is not None:
        raise ValueError(f"{defect}: {name}")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR if flags is None else flags)
    if img is None:
        raise ValueError(f"unreadable image file (not a decodable image): {name}")
    return img


def read_image(path: str | Path, flags: int | None = None) -> np.ndarray:
    """Decode an image file with OpenCV after checking it is complete (:func:`decode_image`).

    Parameters
    ----------
    path
        The file.
    flags
        OpenCV ``imread`` flags (default ``cv2.IMREAD_COLOR``: BGR, 3 channels).

    Returns
    -------
    numpy.ndarray
        As ``cv2.imread`` returns it (BGR channel order).

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If it cannot be read, is truncated or corrupt, or does not decode; the message names the file.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise FileNotFoundError(f"image file missing: {path}") from None
    except OSError as err:
        raise ValueError(f"cannot read image file {path}: {err}") from err
    return decode_image(data, flags, str(path))
