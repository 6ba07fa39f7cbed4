"""Asking a board what it runs (skinloc.hardware.board), against scripted ports."""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.hardware.board import (
    BoardError,
    configure,
    detect,
    parse_lines,
)
from skinloc.hardware.protocol import encode_binary, encode_text

V = b"skinloc_muca 1.1.0 grid 8x8 format binary gain 8 controller ok\r\n"


class FakePort:
    """A port that streams ``stream`` (at one baud, garbage at others) and answers commands."""

    def __init__(self, stream: bytes, baud: int, answers: dict[bytes, bytes], at: int) -> None:
        self.stream = stream if baud == at else bytes(range(256)) * (len(stream) // 256)
        self.answers = answers if baud == at else {}
        self.out = bytearray()
        self.pos = 0

    def read(self, n: int) -> bytes:
        chunk = self.stream[self.pos : self.pos + min(n, 200)]
        self.pos += len(chunk)
        if not chunk and self.out:
            chunk, self.out = bytes(self.out), bytearray()
        return chunk

    def write(self, data: bytes) -> None:
        for line in data.split(b"\n"):
            self.out += self.answers.get(line, b"")

    def close(self) -> None:
        pass


def opener(stream: bytes, answers: dict[bytes, bytes], at: int):
    return lambda port, baud: FakePort(stream, baud, answers, at)


def frames(n: int = 10) -> bytes:
    return b"".join(encode_binary(np.full(64, 9000 + k), 8, 8, k) for k in range(n))


def test_skinloc_firmware_answers_v_at_1000000():
    info = detect("P", opener=opener(frames(), {b"v": V}, 1_000_000), timeout_s=1)
    assert info.is_skinloc and info.baud == 1_000_000 and (info.n_tx, info.n_rx) == (8, 8)
    assert info.controller == "ok" and info.n_values == 64
    assert "skinloc_muca 1.1.0, grid 8x8" in info.describe()


def test_the_papers_text_firmware_is_found_at_115200_by_its_framing():
    text = b"".join(encode_text(np.full(64, 9000 + k)) for k in range(20))
    info = detect("P", opener=opener(text, {}, 115_200), timeout_s=2)
    assert not info.is_skinloc and info.baud == 115_200 and info.format == "text"
    assert info.n_values == 64 and "does not answer 'v'" in info.describe()


def test_a_silent_board_and_a_board_at_another_baud_say_what_to_check():
    with pytest.raises(BoardError, match="no answer from P at 1000000 or 115200 baud.*cable"):
        detect("P", opener=opener(b"", {}, 1_000_000), timeout_s=0.5)
    with pytest.raises(BoardError, match="neither frames nor replies: give --baud"):
        detect("P", opener=opener(frames(), {}, 57_600), timeout_s=0.5)


def test_no_controller_is_one_line_with_what_to_check():
    missing = V.replace(b"controller ok", b"controller missing")
    info = detect("P", opener=opener(b"", {b"v": missing}, 1_000_000), timeout_s=1)
    with pytest.raises(BoardError, match="no touch controller .* SDA/SCL wiring") as e:
        info.check_controller()
    assert "\n" not in str(e.value)


def test_configure_sends_the_settings_and_quotes_a_refusal():
    answers = {
        b"v": V.replace(b"grid 8x8", b"grid 4x3").replace(b"gain 8", b"gain 12"),
        b"g 12": b"ok gain 12\r\n",
        b"l 1111 111": b"ok lines 4x3\r\n",
    }
    info = detect("P", opener=opener(b"", answers, 1_000_000), timeout_s=1)
    new = configure(
        info, gain=12, lines=parse_lines("1111,111"), opener=opener(b"", answers, 1_000_000)
    )
    assert (new.n_tx, new.n_rx, new.gain) == (4, 3, 12)
    refuse = {**answers, b"g 12": b"error gain must be 1-31\r\n"}
    with pytest.raises(BoardError, match="refused a setting: error gain must be 1-31"):
        configure(info, gain=12, opener=opener(b"", refuse, 1_000_000))
    with pytest.raises(BoardError, match="1-31"):
        configure(info, gain=32)


@pytest.mark.parametrize("text", ["1111", "1111,0000", "2,1", "1" * 22 + ",1", "1,1,1", ""])
def test_bad_lines_are_refused(text):
    with pytest.raises(ValueError, match="TXMASK,RXMASK"):
        parse_lines(text)
