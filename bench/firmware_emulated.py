"""Figures of the firmware in the AVR emulator: flash, RAM, stack, frame rate per grid.

    python bench/firmware_emulated.py            # prints a Markdown table

For each grid the emulated board (the real firmware in simavr, an emulated FT5x06 that scans
in 1 ms) streams binary frames to a host for two wall seconds; the rate is frames per
*emulated* second. The emulator's I2C moves a byte in 9 us; a real 400 kHz bus needs 22.5 us
(9 bit times). The last column adds that difference for every byte the firmware put on the bus
per frame (counted by the harness): an estimate for a real Uno at 400 kHz, with the same 1 ms
scan; a real FT5x06's scan time and clock stretching are not modelled.
"""

from __future__ import annotations

import sys
import time

from skinloc.sim.emulated_board import EmulatedBoard, build_firmware

GRIDS = [(1, 1), (8, 8), (21, 12)]
EMULATED_BYTE_US = 9.0  # simavr 1.6: one TWI byte (address or data) per 9 us
REAL_BYTE_US = 9 / 400e3 * 1e6  # 22.5 us at 400 kHz


def measure(build, n_tx: int, n_rx: int, seconds: float = 2.0) -> dict[str, float]:
    import serial

    with EmulatedBoard(build, speed=0) as board:
        ser = serial.Serial(board.path, 1_000_000, timeout=0.05)
        time.sleep(0.3)
        ser.write(f"l {'1' * n_tx} {'1' * n_rx}\n".encode())
        ser.read(100_000)
        time.sleep(0.3)
        ser.read(1_000_000)
        a = board.snapshot()
        end = time.monotonic() + seconds
        n_bytes = 0
        while time.monotonic() < end:
            n_bytes += len(ser.read(100_000))
        b = board.snapshot()
        ser.close()
    scans = b["scans"] - a["scans"]
    emulated_s = b["emulated_s"] - a["emulated_s"]
    bus_per_frame = (b["bus_bytes"] - a["bus_bytes"]) / scans
    frame_s = emulated_s / scans
    real_s = frame_s + bus_per_frame * (REAL_BYTE_US - EMULATED_BYTE_US) * 1e-6
    return {
        "rate": scans / emulated_s,
        "bus_bytes": bus_per_frame,
        "real_rate": 1 / real_s,
        "speed": emulated_s / (b["wall_s"] - a["wall_s"]),
        "headroom": b["stack_headroom"],
        "fault": b["fault"],
    }


def main() -> int:
    build = build_firmware()
    print(build.size_line)
    print()
    print(
        "| grid | frames/s, emulated | bus bytes per frame | frames/s at 400 kHz (estimate) "
        "| emulated s per wall s |"
    )
    print("|---|---|---|---|---|")
    headroom = []
    for n_tx, n_rx in GRIDS:
        m = measure(build, n_tx, n_rx)
        headroom.append(m["headroom"])
        assert m["fault"] == "none", m
        print(
            f"| {n_tx} x {n_rx} | {m['rate']:.0f} | {m['bus_bytes']:.0f} | {m['real_rate']:.0f} "
            f"| {m['speed']:.1f} |"
        )
    print()
    print(f"stack headroom (lowest stack pointer above .bss), bytes: {min(headroom)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
