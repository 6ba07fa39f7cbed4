"""Parser throughput for 64-sensor frames: text, binary, auto, and a naive readline baseline.

Encodes N random 8 x 8 frames in both formats, then times feeding them to the parsers in 4 KiB
chunks (as a serial read would deliver them), against the naive text reader most scripts use:
`io.BytesIO(data).readline().split(b',')` with `int()` per value, no validation. Best of
--repeat interleaved rounds; `vs_naive` is the speed relative to the naive reader in the same run.

    python bench/parser_throughput.py --frames 200000 --repeat 5
"""

from __future__ import annotations

import argparse
import io
import json
import platform
import sys
import time

import numpy as np

from skinloc.hardware.framing import AutoParser, BinaryParser, TextParser
from skinloc.hardware.protocol import encode_binary, encode_text


def naive(data: bytes) -> int:
    buf = io.BytesIO(data)
    n = 0
    while True:
        line = buf.readline()
        if not line:
            return n
        values = [int(v) for v in line.split(b",")]
        if len(values) == 64:
            n += 1


def chunked(parser, data: bytes, chunk: int) -> int:
    n = 0
    for i in range(0, len(data), chunk):
        n += len(parser.feed(data[i : i + chunk]))
    return n


def best_of(cases: dict, repeat: int) -> dict[str, tuple[float, int]]:
    """Best time of each case over ``repeat`` rounds; rounds interleave the cases, so a noisy
    neighbour on a shared machine slows them alike."""
    times: dict[str, list[float]] = {name: [] for name in cases}
    counts: dict[str, int] = {}
    for _ in range(repeat):
        for name, fn in cases.items():
            t0 = time.perf_counter()
            counts[name] = fn()
            times[name].append(time.perf_counter() - t0)
    return {name: (min(times[name]), counts[name]) for name in cases}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=200_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--chunk", type=int, default=4096)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    vals = rng.integers(3000, 12000, (args.frames, 64))
    text = b"\r\n" + b"".join(encode_text(v) for v in vals)
    binary = b"".join(encode_binary(v, 8, 8, k) for k, v in enumerate(vals))
    rows = {}
    cases = {
        "naive readline().split(',') (text)": lambda: naive(text[2:]),
        "TextParser (text)": lambda: chunked(TextParser(8, 8), text, args.chunk),
        "BinaryParser (binary)": lambda: chunked(BinaryParser(8, 8), binary, args.chunk),
        "AutoParser (text)": lambda: chunked(AutoParser(8, 8), text, args.chunk),
        "AutoParser (binary)": lambda: chunked(AutoParser(8, 8), binary, args.chunk),
    }
    naive_name = next(iter(cases))
    timed = best_of(cases, args.repeat)
    for name, (dt, n) in timed.items():
        assert n == args.frames, (name, n)
        rows[name] = {
            "frames_per_s": round(n / dt),
            "mb_per_s": round((len(binary) if "binary" in name else len(text)) / dt / 1e6, 1),
            "vs_naive": round(timed[naive_name][0] / dt, 2),
        }
    result = {
        "command": " ".join(["python", "bench/parser_throughput.py", *sys.argv[1:]]),
        "frames": args.frames,
        "bytes_per_frame": {
            "text": round(len(text) / args.frames, 1),
            "binary": len(binary) // args.frames,
        },
        "python": platform.python_version(),
        "machine": platform.processor() or platform.machine(),
        "results": rows,
    }
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
