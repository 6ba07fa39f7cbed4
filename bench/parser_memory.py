"""Parser memory under endless garbage: resident memory while the parsers eat random bytes.

Two cases: one long-lived parser of each kind fed --megabytes of random bytes in 20 kB reads (a
reader on a noisy line for hours), and --fresh new parsers each fed one random input of up to
400 bytes (what a fuzzer does). Prints the resident memory after each tenth of each case; flat
means nothing accumulates.

    python bench/parser_memory.py --megabytes 60 --fresh 200000
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

from skinloc.hardware.framing import AutoParser, BinaryParser, TextParser


def rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--megabytes", type=int, default=60)
    ap.add_argument("--fresh", type=int, default=200_000)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    parsers = [TextParser(8, 8), BinaryParser(8, 8), AutoParser(8, 8), BinaryParser()]
    reads = args.megabytes * 50  # 20 kB each
    long_lived = []
    for k in range(reads):
        data = rng.integers(0, 256, 20_000, dtype=np.uint8).tobytes()
        for p in parsers:
            p.feed(data)
        if (k + 1) % max(1, reads // 10) == 0:
            long_lived.append([round((k + 1) * 0.02, 1), round(rss_mb(), 2)])
    fresh = []
    for k in range(args.fresh):
        data = rng.integers(0, 256, int(rng.integers(0, 400)), dtype=np.uint8).tobytes()
        for cls in (TextParser, BinaryParser, AutoParser):
            cls(2, 2).feed(data)
        if (k + 1) % max(1, args.fresh // 10) == 0:
            fresh.append([k + 1, round(rss_mb(), 2)])
    result = {
        "command": " ".join(["python", "bench/parser_memory.py", *sys.argv[1:]]),
        "long_lived_mb_fed_vs_rss_mb": long_lived,
        "fresh_parsers_vs_rss_mb": fresh,
        "chatter_dropped_corrupted_of_long_lived": [
            {k: v for k, v in p.stats.as_dict().items() if v} for p in parsers
        ],
    }
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
