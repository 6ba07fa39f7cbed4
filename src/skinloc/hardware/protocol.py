r"""The two wire formats a skin speaks over serial: their constants, frames and encoders.

* **text**: the paper's firmware prints one line of comma-separated decimal counts per frame,
  TX-major, ending in ``\r\n`` (``Serial.println``), at 115200 baud.
* **binary**: skinloc's framed format (``docs/protocol.md``): sync bytes ``A5 5A``, version,
  grid, a 16-bit frame counter, 16-bit little-endian counts and a CRC-32.

The parsers that read them are in ``hardware.framing``. The C twin of ``encode_binary`` is
``firmware/skinloc_muca/skinloc_wire.h``.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

__all__ = [
    "MAX_LINE_BYTES",
    "MAX_RX",
    "MAX_TX",
    "SYNC",
    "WIRE_VERSION",
    "RawFrame",
    "WireFormat",
    "binary_counts",
    "binary_frame_size",
    "encode_binary",
    "encode_binary_counts",
    "encode_text",
]

#: Largest grid of the FT5x06 on the Muca board.
MAX_TX, MAX_RX = 21, 12
#: Two sync bytes open every binary frame.
SYNC = b"\xa5\x5a"
#: Version byte of the binary layout this module reads and writes.
WIRE_VERSION = 1
HEADER = struct.Struct("<2sBBBH")  # sync, version, n_tx, n_rx, counter
HEADER_SIZE = HEADER.size  # 7
CRC_SIZE = 4
COUNT_MAX = 65535
#: Longest text line kept while waiting for its end: 21 x 12 five-digit values and commas.
MAX_LINE_BYTES = MAX_TX * MAX_RX * 6 + 16


class WireFormat(StrEnum):
    """Wire formats: ``auto`` detects ``text`` or ``binary`` from the bytes."""

    AUTO = "auto"
    TEXT = "text"
    BINARY = "binary"

    @classmethod
    def _missing_(cls, value: object) -> WireFormat:
        valid = ", ".join(m.value for m in cls)
        raise ValueError(f"unknown wire format {value!r}; choose one of: {valid}")


@dataclass(frozen=True)
class RawFrame:
    """One frame as it came off the wire.

    Attributes
    ----------
    values : (n_tx * n_rx,) uint16
        Raw counts, TX-major.
    n_tx, n_rx : int
        Grid the frame carries (text frames: the grid the parser was given).
    counter : int or None
        The device's 16-bit frame counter (binary), ``None`` for text.
    """

    values: np.ndarray
    n_tx: int
    n_rx: int
    counter: int | None = None


def check_grid(n_tx: int, n_rx: int) -> None:
    if not (isinstance(n_tx, int | np.integer) and 1 <= n_tx <= MAX_TX):
        raise ValueError(f"n_tx must be an int in 1-{MAX_TX} (the Muca board limit), got {n_tx!r}")
    if not (isinstance(n_rx, int | np.integer) and 1 <= n_rx <= MAX_RX):
        raise ValueError(f"n_rx must be an int in 1-{MAX_RX} (the Muca board limit), got {n_rx!r}")


def _as_counts(values: np.ndarray | list[int], n: int) -> np.ndarray:
    arr = np.asarray(values)
    if arr.shape != (n,):
        raise ValueError(f"values must have shape ({n},), got {arr.shape}")
    if arr.size and (
        not np.all(np.isfinite(arr))
        or np.any(arr != np.round(arr))
        or arr.min() < 0
        or arr.max() > COUNT_MAX
    ):
        raise ValueError("values must be whole counts in 0-65535")
    return arr.astype(np.uint16)


# --------------------------------------------------------------------------------------------
# encoders


def binary_frame_size(n_tx: int, n_rx: int) -> int:
    """Bytes of one binary frame: 7 header + 2 per sensor + 4 CRC.

    Examples
    --------
    >>> binary_frame_size(8, 8), binary_frame_size(21, 12)
    (139, 515)
    """
    return HEADER_SIZE + 2 * n_tx * n_rx + CRC_SIZE


def encode_binary(values: np.ndarray | list[int], n_tx: int, n_rx: int, counter: int) -> bytes:
    """One frame in skinloc's binary format.

    Parameters
    ----------
    values : (n_tx * n_rx,) int
        Counts in 0-65535, TX-major.
    n_tx, n_rx : int
        Grid, at most 21 x 12.
    counter : int
        Frame counter; only its low 16 bits are sent.

    Returns
    -------
    bytes
        ``A5 5A | version | n_tx | n_rx | counter u16 | values u16... | crc32 u32``, all
        little-endian; the CRC-32 (zlib's) covers version to the last value.

    Examples
    --------
    >>> encode_binary([1, 2], 1, 2, counter=3).hex(" ")
    'a5 5a 01 01 02 03 00 01 00 02 00 13 66 59 a6'
    """
    return encode_binary_counts(binary_counts(values, n_tx, n_rx), n_tx, n_rx, counter)


def binary_counts(values: np.ndarray | list[int], n_tx: int, n_rx: int) -> bytes:
    """The counts of a binary frame as sent (``u16`` little-endian), for ``encode_binary_counts``.

    A stream that sends the same images again (a benchmark's feeder) converts them once.
    """
    check_grid(n_tx, n_rx)
    return _as_counts(values, n_tx * n_rx).astype("<u2").tobytes()


def encode_binary_counts(counts: bytes, n_tx: int, n_rx: int, counter: int) -> bytes:
    """One binary frame from counts already converted by ``binary_counts`` (``encode_binary``).

    Raises
    ------
    ValueError
        When ``counts`` is not ``2 * n_tx * n_rx`` bytes.
    """
    if len(counts) != 2 * n_tx * n_rx:
        raise ValueError(
            f"counts must be {2 * n_tx * n_rx} bytes for a {n_tx} x {n_rx} grid, got {len(counts)}"
        )
    body = HEADER.pack(SYNC, WIRE_VERSION, n_tx, n_rx, counter & 0xFFFF)[2:] + counts
    return SYNC + body + struct.pack("<I", zlib.crc32(body))


def encode_text(values: np.ndarray | list[int]) -> bytes:
    r"""One frame in the paper's text format: decimal counts joined by commas, then CRLF.

    Examples
    --------
    >>> encode_text([9512, 0, 17])
    b'9512,0,17\r\n'
    """
    arr = _as_counts(values, len(np.asarray(values)))
    return ",".join(map(str, arr.tolist())).encode("ascii") + b"\r\n"
