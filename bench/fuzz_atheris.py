"""Coverage-guided fuzzing of the wire parsers with atheris (libFuzzer).

Each input drives one of three checks, chosen by the input itself:
0. arbitrary bytes, fed in arbitrary chunks to the text, binary and auto parsers: no exception;
1. valid binary frames of a random grid, then random inserts, deletes, byte flips and
   duplications: every delivered frame equals one that was sent (counter and values);
2. valid text frames with the structural faults the format can detect (garbage that leaves a
   non-data byte in every line it touches, a lost line end, a line end inserted next to a
   comma, truncation; one fault per line, none on neighbouring lines): exactly the untouched
   lines come out, in order. (Other faults can turn one text line into another valid one; the
   format has no checksum. See docs/reliability.md.)

    python bench/fuzz_atheris.py -runs=2000000
"""

from __future__ import annotations

import sys

import atheris
import numpy  # noqa: F401 - imported first so that only skinloc.hardware.framing is instrumented

with atheris.instrument_imports(include=["skinloc"]):
    from skinloc.hardware.framing import AutoParser, BinaryParser, TextParser
    from skinloc.hardware.protocol import encode_binary, encode_text


def feed(parser, data: bytes, fdp) -> list:
    out, i = [], 0
    while i < len(data):
        step = fdp.ConsumeIntInRange(1, 600)
        out += parser.feed(data[i : i + step])
        i += step
    return out


def one_input(raw: bytes) -> None:
    fdp = atheris.FuzzedDataProvider(raw)
    mode = fdp.ConsumeIntInRange(0, 2)
    if mode == 0:
        data = fdp.ConsumeBytes(fdp.ConsumeIntInRange(0, 4000))
        for parser in (TextParser(2, 2), BinaryParser(2, 2), AutoParser(2, 2), BinaryParser()):
            for f in feed(parser, data, fdp):
                assert f.values.dtype == "uint16" and f.values.shape == (f.n_tx * f.n_rx,)
        return
    n_tx = fdp.ConsumeIntInRange(1, 21 if mode == 1 else 4)
    n_rx = fdp.ConsumeIntInRange(1 if mode == 1 else 2, 12 if mode == 1 else 4)
    n = n_tx * n_rx
    frames = [
        [fdp.ConsumeIntInRange(0, 65535) for _ in range(n)]
        for _ in range(fdp.ConsumeIntInRange(1, 4))
    ]
    if mode == 1:
        data = bytearray(b"".join(encode_binary(v, n_tx, n_rx, k) for k, v in enumerate(frames)))
        sent = {(k, tuple(v)) for k, v in enumerate(frames)}
        for _ in range(fdp.ConsumeIntInRange(1, 6)):
            op, at = fdp.ConsumeIntInRange(0, 3), fdp.ConsumeIntInRange(0, len(data))
            if op == 0:
                data[at:at] = fdp.ConsumeBytes(fdp.ConsumeIntInRange(1, 40))
            elif op == 1:
                del data[at : at + fdp.ConsumeIntInRange(1, 20)]
            elif op == 2 and at < len(data):
                data[at] ^= fdp.ConsumeIntInRange(1, 255)
            else:
                data[at:at] = data[max(0, at - 30) : at]
        for f in feed(BinaryParser(n_tx, n_rx), bytes(data), fdp):
            assert (f.counter, tuple(f.values.tolist())) in sent, "wrong binary frame"
        return
    # Text: the fault model of test_framing.py::faulted_text_streams; each fault hits one
    # line, no two hit neighbouring lines; exactly the untouched lines must come out.
    lines = [bytearray(encode_text(v)) for v in frames]
    destroyed: set[int] = set()
    last_hit = -2
    for k in range(len(lines)):
        if k == last_hit + 1 or not fdp.ConsumeBool():
            continue
        last_hit, line = k, lines[k]
        op = fdp.ConsumeIntInRange(0, 2)
        if op == 0:  # garbage that leaves a non-data byte in every line it touches
            junk = fdp.ConsumeBytes(fdp.ConsumeIntInRange(1, 20))
            if not junk or not garbage_changes_every_line(junk):
                continue
            at = fdp.ConsumeIntInRange(0, len(line) - 1)
            line[at:at] = junk
            destroyed.add(k)
        elif op == 1:  # the line end lost: this line and the next run together
            del line[-fdp.ConsumeIntInRange(1, 2) :]
            destroyed |= {k, k + 1}
        else:  # a line end inserted next to a comma
            commas = [i for i in range(1, len(line) - 2) if 44 in (line[i - 1], line[i])]
            at = commas[fdp.ConsumeIntInRange(0, len(commas) - 1)]
            line[at:at] = b"\r\n"
            destroyed.add(k)
    data = bytearray(b"\r\n")
    ends = []
    for line in lines:
        data += line
        ends.append(len(data))
    cut = fdp.ConsumeIntInRange(0, len(data)) if fdp.ConsumeBool() else len(data)
    expected = [v for k, v in enumerate(frames) if k not in destroyed and ends[k] <= cut]
    got = feed(TextParser(n_tx, n_rx), bytes(data[:cut]), fdp)
    assert [f.values.tolist() for f in got] == expected, "text frames != untouched lines"


def garbage_changes_every_line(junk: bytes) -> bool:
    """As in tests/hardware/test_framing.py: junk that cannot complete or form a data line."""
    pieces = junk.split(b"\n")
    ends, middle = {pieces[0], pieces[-1]}, pieces[1:-1]
    return not any(_data_like(p) for p in ends) and not any(
        _data_like(p) and p.strip(b"\r") for p in middle
    )


def _data_like(piece: bytes) -> bool:
    return all(c in b"0123456789,\r" for c in piece)


if __name__ == "__main__":
    atheris.Setup(sys.argv, one_input)
    atheris.Fuzz()
