"""Tests of the wire-format parsers and encoders (skinloc.hardware.framing) and of the C encoder."""

from __future__ import annotations

import os
import shutil
import subprocess
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skinloc.hardware.framing import AutoParser, BinaryParser, TextParser, make_parser
from skinloc.hardware.protocol import (
    MAX_LINE_BYTES,
    WireFormat,
    binary_frame_size,
    encode_binary,
    encode_text,
)

ROOT = Path(__file__).resolve().parents[2]
#: Examples per property; docs/reliability.md runs them with SKINLOC_FUZZ_EXAMPLES=20000.
FUZZ = settings(
    max_examples=int(os.environ.get("SKINLOC_FUZZ_EXAMPLES", "150")),
    deadline=None,
    suppress_health_check=list(HealthCheck),
)


def feed_chunks(parser, data: bytes, cuts: list[int]) -> list:
    out = []
    bounds = sorted({0, len(data), *[c % (len(data) + 1) for c in cuts]})
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        out += parser.feed(data[a:b])
    return out


@st.composite
def grids_and_frames(draw, max_frames: int = 6):
    n_tx = draw(st.integers(1, 21))
    n_rx = draw(st.integers(1, 12))
    n = n_tx * n_rx
    k = draw(st.integers(1, max_frames))
    values = draw(
        st.lists(st.lists(st.integers(0, 65535), min_size=n, max_size=n), min_size=k, max_size=k)
    )
    return n_tx, n_rx, values


# -------------------------------------------------------------------------------- encoders
def test_binary_layout():
    data = encode_binary([1, 2], 1, 2, counter=0x1234)
    assert data[:2] == b"\xa5\x5a" and data[2] == 1 and data[3:5] == bytes([1, 2])
    assert data[5:7] == b"\x34\x12" and data[7:11] == b"\x01\x00\x02\x00"
    assert int.from_bytes(data[11:], "little") == zlib.crc32(data[2:11])
    assert len(data) == binary_frame_size(1, 2) == 15
    assert binary_frame_size(21, 12) == 515


@pytest.mark.parametrize(
    "values, grid, msg",
    [
        ([1, 2, 3], (1, 2), "shape"),
        ([70000, 1], (1, 2), "0-65535"),
        ([-1, 1], (1, 2), "0-65535"),
        ([1.5, 1], (1, 2), "whole"),
        ([1] * 22, (22, 1), "n_tx"),
        ([1] * 13, (1, 13), "n_rx"),
    ],
)
def test_encoders_reject_bad_values(values, grid, msg):
    with pytest.raises(ValueError, match=msg):
        encode_binary(values, *grid, counter=0)


def test_text_encoding_is_the_paper_format():
    assert encode_text([9512, 0, 65535]) == b"9512,0,65535\r\n"


def test_wire_format_lists_choices():
    with pytest.raises(ValueError, match="auto, text, binary"):
        WireFormat("csv")


# -------------------------------------------------------------------------------- text parser
def test_text_skips_chatter_and_the_first_partial_line():
    p = TextParser(2, 2)
    data = b"4,5,6\r\nRX active lines: 11111111\r\nTX active lines: 1111\r\n1,2,3,4\r\n5,6,7,8\r\n"
    frames = p.feed(data)
    assert [f.values.tolist() for f in frames] == [[1, 2, 3, 4], [5, 6, 7, 8]]
    assert p.stats.n_chatter == 2 and p.stats.n_dropped == 1  # the first line may be partial
    assert all(f.counter is None and (f.n_tx, f.n_rx) == (2, 2) for f in frames)


@pytest.mark.parametrize(
    "line",
    [
        b"1,2,3",
        b"1,2,3,4,5",
        b"1,,3,4",
        b"1,2,3,x",
        b"1,2,3,65536",
        b"1,2,3,123456",
        b",1,2,3",
        b"1 ,2,3,4",
        b"+1,2,3,4",
        b"1,2,3,4\x00",
        b"1_0,2,3,4",
        b"\xff\xfe,1,2,3",
    ],
)
def test_text_drops_malformed_lines(line):
    p = TextParser(2, 2, synced=True)
    assert p.feed(line + b"\r\n1,2,3,4\n") and p.stats.n_frames == 1
    assert p.stats.n_dropped + p.stats.n_chatter == 1


def test_text_accepts_lf_trailing_comma_and_zero():
    p = TextParser(1, 3, synced=True)
    assert [f.values.tolist() for f in p.feed(b"0,1,2\n3,4,5,\r\n")] == [[0, 1, 2], [3, 4, 5]]


def test_text_merged_and_split_lines_are_dropped():
    p = TextParser(1, 3, synced=True)
    # merged (line end lost) and split (newline inserted): all three are dropped
    assert p.feed(b"1,2,31,2,3\r\n4,5\r\n,6\r\n7,8,9\r\n")[0].values.tolist() == [7, 8, 9]
    assert p.stats.n_dropped == 3


def test_text_overlong_line_is_bounded():
    p = TextParser(1, 2, synced=True)
    assert p.feed(b"1," * (MAX_LINE_BYTES // 2 + 10)) == []
    assert len(p._buf) == 0 and p.stats.n_dropped == 1
    assert p.feed(b"9,9,9\r\n5,6\r\n")[0].values.tolist() == [5, 6]  # tail skipped, then fine
    assert p.stats.n_dropped == 1


# -------------------------------------------------------------------------------- binary parser
def test_binary_counts_lost_frames_across_wraparound():
    p = BinaryParser(1, 1)
    data = b"".join(encode_binary([c], 1, 1, c) for c in (65533, 65534, 1, 2))
    assert [f.counter for f in p.feed(data)] == [65533, 65534, 1, 2]
    assert p.stats.n_lost == 2  # 65535 and 0


def test_binary_wrong_grid_is_counted_not_delivered():
    p = BinaryParser(8, 8)
    frames = p.feed(encode_binary([1] * 4, 2, 2, 0) + encode_binary([2] * 64, 8, 8, 1))
    assert frames[0].counter == 1
    assert p.stats.n_wrong_grid == 1


def test_binary_any_grid_when_unconstrained():
    p = BinaryParser()
    frames = p.feed(encode_binary(list(range(252)), 21, 12, 7))
    assert (frames[0].n_tx, frames[0].n_rx, frames[0].values[-1]) == (21, 12, 251)


def test_binary_corrupted_byte_is_counted_and_resynced():
    good = [encode_binary([k, k + 1, k + 2], 1, 3, k) for k in range(3)]
    bad = bytearray(good[1])
    bad[9] ^= 0x40
    p = BinaryParser(1, 3)
    frames = p.feed(good[0] + bytes(bad) + good[2])
    assert [f.counter for f in frames] == [0, 2]
    assert p.stats.n_corrupted >= 1 and p.stats.n_lost == 1


def test_binary_reads_of_one_frame_each_equal_one_read_of_all():
    """A read of one whole frame (the live port's usual read) gives what the general path does:
    the same frames and counters, a lost counter counted, and a damaged, partial or other-grid
    frame handled by the general path as before."""
    good = [encode_binary([k, 2 * k, 3 * k], 1, 3, k) for k in (0, 1, 3, 4, 5)]
    bad = bytearray(good[3])
    bad[9] ^= 0x40
    other = encode_binary([1, 2, 3, 4, 5, 6], 2, 3, 9)
    reads = [good[0], good[1], good[2], bytes(bad), other, good[4][:5], good[4][5:]]
    one, every = BinaryParser(1, 3), BinaryParser(1, 3)
    got = [f for r in reads for f in one.feed(r)]
    want = every.feed(b"".join(reads))
    assert [(f.counter, f.values.tolist()) for f in got] == [
        (f.counter, f.values.tolist()) for f in want
    ]
    assert [f.counter for f in got] == [0, 1, 3, 5]
    assert got[0].values.dtype == np.uint16
    assert one.stats.as_dict() == every.stats.as_dict()
    assert one.stats.n_lost == 2 and one.stats.n_corrupted >= 1 and one.stats.n_wrong_grid == 1


def test_binary_false_sync_in_garbage_does_not_hide_the_next_frame():
    # A fake header announcing a 21 x 12 frame swallows the real frame's bytes until the CRC
    # check fails; the parser must then rescan and still find it.
    fake = b"\xa5\x5a\x01\x15\x0c\x00\x00"
    frame = encode_binary([1, 2], 1, 2, 0)
    p = BinaryParser(1, 2)
    assert p.feed(fake + frame) == []  # waiting for 515 bytes
    frames = p.feed(bytes(600))
    assert [f.values.tolist() for f in frames] == [[1, 2]]


# -------------------------------------------------------------------------------- auto
def test_auto_detects_text_after_chatter():
    p = AutoParser(1, 2)
    assert p.feed(b"RX active lines: 11\r\n") == [] and p.format is WireFormat.AUTO
    p.feed(b"1,2\r\n")
    assert p.format is WireFormat.TEXT and p.stats.n_chatter == 1


def test_auto_redetects_after_a_format_switch():
    p = AutoParser(1, 2, relock_bytes=64)
    assert p.feed(b"x\r\n" + encode_binary([1, 2], 1, 2, 0)) and p.format is WireFormat.BINARY
    p.feed(b"ok format text\r\n" + b"3,4\r\n" * 30)
    assert p.format is WireFormat.TEXT
    assert p.feed(b"5,6\r\n")[0].values.tolist() == [5, 6]


def test_make_parser():
    assert isinstance(make_parser("text", 2, 3), TextParser)
    assert isinstance(make_parser("binary"), BinaryParser)
    assert isinstance(make_parser("auto"), AutoParser)


# -------------------------------------------------------------------------------- properties
@FUZZ
@given(grids_and_frames(), st.lists(st.integers(0, 10**6), max_size=12), st.booleans())
def test_round_trip_in_any_chunking(gf, cuts, binary):
    n_tx, n_rx, values = gf
    if binary:
        data = b"".join(encode_binary(v, n_tx, n_rx, k) for k, v in enumerate(values))
        parser = BinaryParser(n_tx, n_rx)
    else:
        data = b"\r\n" + b"".join(encode_text(v) for v in values)
        parser = TextParser(n_tx, n_rx)
    frames = feed_chunks(parser, data, cuts)
    assert [f.values.tolist() for f in frames] == values
    assert parser.stats.n_dropped == parser.stats.n_corrupted == parser.stats.n_lost == 0


@FUZZ
@given(
    st.binary(max_size=3000),
    st.lists(st.integers(0, 10**6), max_size=8),
    st.sampled_from(["text", "binary", "auto"]),
)
def test_arbitrary_bytes_never_raise(data, cuts, fmt):
    parser = make_parser(fmt, 2, 2)
    for f in feed_chunks(parser, data, cuts):
        assert f.values.dtype == np.uint16 and f.values.shape == (4,)
    s = parser.stats
    assert s.n_bytes == len(data) and s.n_bytes_skipped <= len(data)


@st.composite
def mutated_binary_streams(draw):
    n_tx, n_rx, values = draw(grids_and_frames(max_frames=5))
    frames = [encode_binary(v, n_tx, n_rx, k) for k, v in enumerate(values)]
    data = bytearray(b"".join(frames))
    for _ in range(draw(st.integers(1, 6))):
        kind = draw(st.sampled_from(["insert", "delete", "flip", "dup"]))
        at = draw(st.integers(0, len(data)))
        if kind == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=40))
        elif kind == "delete":
            del data[at : at + draw(st.integers(1, 20))]
        elif kind == "flip" and at < len(data):
            data[at] ^= draw(st.integers(1, 255))
        elif kind == "dup":
            data[at:at] = data[max(0, at - 30) : at]
    return n_tx, n_rx, values, bytes(data)


@FUZZ
@given(mutated_binary_streams(), st.lists(st.integers(0, 10**6), max_size=8))
def test_binary_never_delivers_a_wrong_frame(stream, cuts):
    n_tx, n_rx, values, data = stream
    sent = {(k & 0xFFFF, tuple(v)) for k, v in enumerate(values)}
    for f in feed_chunks(BinaryParser(n_tx, n_rx), data, cuts):
        assert (f.counter, tuple(f.values.tolist())) in sent


TEXT_DATA_BYTES = b"0123456789,\r"


def is_data_like(piece: bytes) -> bool:
    """Whether ``piece`` holds only bytes a data line holds (so it could complete one)."""
    return all(c in TEXT_DATA_BYTES for c in piece)


def garbage_changes_every_line(junk: bytes) -> bool:
    """Whether ``junk``, inserted anywhere in a line, leaves that line and its own lines invalid.

    Its text before its first line end joins the line it lands in and its text after its last
    line end joins the rest of that line: each needs a byte no data line has, or the pieces could
    still form a line of the right length (``b"\\n"`` inside ``45`` leaves ``4`` and ``5,...``).
    Lines wholly inside it must be empty or not data, or it could be a line of its own.
    """
    pieces = junk.split(b"\n")
    ends, middle = {pieces[0], pieces[-1]}, pieces[1:-1]
    return not any(is_data_like(p) for p in ends) and not any(
        is_data_like(p) and p.strip(b"\r") for p in middle
    )


@st.composite
def faulted_text_streams(draw):
    """Text lines hit by the faults the format can detect, with the frames that must survive.

    The text format has no checksum: digits inserted into or dropped from a number, or a line
    end inserted inside a number, leave a line of the right length that no parser can tell from
    a real one (``docs/reliability.md`` measures how often that happens). The faults here are the
    structural ones that must be caught: garbage that ``garbage_changes_every_line``, a lost line
    end (two lines run together), a line end inserted next to a comma, and truncation. Each hits
    one line and no two hit neighbouring lines (a line end lost from one line and inserted into
    the next could rebuild a line of the right length).

    Returns ``n_tx, n_rx, sent, expected, data``: ``expected`` are the frames of the lines no
    fault touched, in order; exactly these must come out.
    """
    n_tx = draw(st.integers(1, 4))
    n_rx = draw(st.integers(2, 4))  # n >= 2: two lines run together have 2n - 1 != n fields
    n = n_tx * n_rx
    values = draw(
        st.lists(st.lists(st.integers(0, 65535), min_size=n, max_size=n), min_size=1, max_size=8)
    )
    lines = [bytearray(encode_text(v)) for v in values]
    hit: list[int] = []
    for k in sorted(draw(st.sets(st.integers(0, len(lines) - 1), max_size=4))):
        if not hit or k > hit[-1] + 1:
            hit.append(k)
    destroyed: set[int] = set()
    junk = st.binary(min_size=1, max_size=20).filter(garbage_changes_every_line)
    for k in hit:
        line = lines[k]
        kind = draw(st.sampled_from(["garbage", "lose_eol", "insert_eol"]))
        if kind == "garbage":
            at = draw(st.integers(0, len(line) - 1))  # anywhere before its "\n"
            line[at:at] = draw(junk)
            destroyed.add(k)
        elif kind == "lose_eol":
            del line[-draw(st.sampled_from([1, 2])) :]  # "\n" or "\r\n"
            destroyed |= {k, k + 1}
        else:
            body = len(line) - 2
            commas = [i for i in range(1, body) if line[i - 1] == 44 or line[i] == 44]
            at = draw(st.sampled_from(commas))
            line[at:at] = b"\r\n"
            destroyed.add(k)
    data = bytearray(b"\r\n")  # the parser drops what precedes its first line end
    ends = []
    for line in lines:
        data += line
        ends.append(len(data))
    cut = draw(st.one_of(st.just(len(data)), st.integers(0, len(data))))
    expected = [v for k, v in enumerate(values) if k not in destroyed and ends[k] <= cut]
    return n_tx, n_rx, values, expected, bytes(data[:cut])


@FUZZ
@given(faulted_text_streams(), st.lists(st.integers(0, 10**6), max_size=8))
def test_text_delivers_exactly_the_untouched_lines(stream, cuts):
    n_tx, n_rx, _, expected, data = stream
    frames = feed_chunks(TextParser(n_tx, n_rx), data, cuts)
    assert [f.values.tolist() for f in frames] == expected


def test_text_faults_the_format_cannot_see():
    """A digit lost inside a number, or a line end inside the first one, goes unnoticed."""
    p = TextParser(1, 3)
    assert [f.values.tolist() for f in p.feed(b"\r\n9512,9603,9488\r\n")] == [[9512, 9603, 9488]]
    assert [f.values.tolist() for f in p.feed(b"952,9603,9488\r\n")] == [[952, 9603, 9488]]
    assert [f.values.tolist() for f in p.feed(b"9\r\n512,9603,9488\r\n")] == [[512, 9603, 9488]]


# -------------------------------------------------------------------------------- the C encoder
@pytest.fixture(scope="module")
def c_encoder(tmp_path_factory) -> Path:
    gcc = shutil.which("gcc")
    if gcc is None:
        pytest.skip("gcc not found: the C encoder test needs it")
    exe = tmp_path_factory.mktemp("host_c") / "wire_test"
    subprocess.run(
        [
            gcc,
            "-std=c99",
            "-O2",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-pedantic",
            f"-I{ROOT / 'firmware' / 'skinloc_muca'}",
            str(ROOT / "tests" / "host_c" / "wire_test.c"),
            "-o",
            str(exe),
        ],
        check=True,
        capture_output=True,
        text=True,
    )
    return exe


def test_c_encoder_matches_python_byte_for_byte(c_encoder):
    rng = np.random.default_rng(0)
    cases = [(1, 1, 0, [0]), (1, 2, 3, [1, 2]), (21, 12, 65535, [65535] * 252)]
    for _ in range(300):
        n_tx, n_rx = int(rng.integers(1, 22)), int(rng.integers(1, 13))
        vals = rng.integers(0, 65536, n_tx * n_rx).tolist()
        cases.append((n_tx, n_rx, int(rng.integers(0, 70000)), vals))
    lines = ["crc"] + [" ".join(map(str, [t, r, c, *v])) for t, r, c, v in cases]
    res = subprocess.run(
        [str(c_encoder)], input="\n".join(lines) + "\n", capture_output=True, text=True, check=True
    )
    out = res.stdout.split()
    assert out[0] == "cbf43926"  # the standard CRC-32 check value
    parser = BinaryParser()
    for (n_tx, n_rx, counter, vals), hexed in zip(cases, out[1:], strict=True):
        c_bytes = bytes.fromhex(hexed)
        assert c_bytes == encode_binary(vals, n_tx, n_rx, counter)
        (frame,) = parser.feed(c_bytes)
        assert frame.values.tolist() == vals and frame.counter == counter & 0xFFFF


def test_c_encoder_rejects_bad_grids(c_encoder):
    res = subprocess.run(
        [str(c_encoder)],
        input="22 1 0 " + "1 " * 22 + "\n0 5 0\n",
        capture_output=True,
        text=True,
        check=True,
    )
    assert res.stdout.split("\n")[:2] == ["", ""]


def test_a_frame_from_counts_converted_once_is_the_same_frame():
    from skinloc.hardware.protocol import binary_counts, encode_binary, encode_binary_counts

    rng = np.random.default_rng(0)
    for n_tx, n_rx in ((8, 8), (1, 2), (21, 12)):
        values = rng.integers(0, 65536, n_tx * n_rx)
        counts = binary_counts(values, n_tx, n_rx)
        for counter in (0, 3, 65535, 70000):
            assert encode_binary_counts(counts, n_tx, n_rx, counter) == encode_binary(
                values, n_tx, n_rx, counter
            )
    with pytest.raises(ValueError, match="counts must be 128 bytes"):
        encode_binary_counts(b"\0" * 126, 8, 8, 1)
