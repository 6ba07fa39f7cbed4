"""The real firmware, built for the Uno, in the emulator: commands, frames, line selection, faults.

The emulated FT5x06 serves the harness's pattern ``(scan & 0xFF) << 8 | (tx * 12 + rx)``, so
every value of every frame says which scan, TX line and RX line it came from: a frame is checked
value for value against what the controller held (``_link.BoardModel``).
"""

from __future__ import annotations

import re
import subprocess

import numpy as np
import pytest

from skinloc.sim.emulated_board import EmulatedBoard, firmware_dir

from ._link import HELP, VERSION, BoardModel, Item, Link


def stop_clean(board: EmulatedBoard) -> dict:
    """Stop the board and check the emulator saw no fault and no misuse of the controller."""
    stats = board.stop()
    assert stats["returncode"] == 0, stats
    assert stats["fault"] == "none", stats
    assert stats["early_reads"] == stats["bad_tx"] == stats["reads_while_scanning"] == 0, stats
    assert stats["stack_headroom"] > 256, stats
    return stats


def boot(board: EmulatedBoard, model: BoardModel | None = None) -> tuple[Link, BoardModel]:
    """Open the port (which resets the board) and read its start-up line and a first frame."""
    link = Link(board.path)
    model = model or BoardModel()
    got = link.wait_for(lambda s: sum(i.kind != "line" for i in s) >= 2)
    assert got[0].kind == "line" and got[0].line == f"{VERSION} ready"
    model.check(got[1:])
    return link, model


def run(link: Link, model: BoardModel, lines: list[bytes], n_frames: int = 1) -> None:
    """Send ``lines`` at once; check every reply and every frame up to ``n_frames`` after."""
    n_replies = sum(model.expect(line) for line in lines)
    link.send(b"".join(line + b"\n" for line in lines))
    start = model.n_replies

    def done(items) -> bool:
        replies = sum(i.kind == "line" for i in items)
        if replies < n_replies:
            return False
        last = max((k for k, i in enumerate(items) if i.kind == "line"), default=-1)
        return sum(i.kind != "line" for i in items[last + 1 :]) >= n_frames

    model.check(link.wait_for(done))
    assert model.n_replies - start == n_replies


# ------------------------------------------------------------------------------- the build
def test_build_reports_flash_and_ram_within_budget(fw_build):
    m = re.search(r"flash (\d+) of 32256 bytes, static RAM (\d+) of 2048", fw_build.size_line)
    assert m, fw_build.size_line
    flash, ram = int(m.group(1)), int(m.group(2))
    assert 2000 < flash < 32256 and 200 < ram <= 1536


def test_build_fails_over_the_ram_budget(fw_build):
    res = subprocess.run(
        [
            "make",
            "-s",
            "-C",
            str(firmware_dir()),
            f"BUILD={fw_build.elf.parent}",
            "size",
            "RAM_BUDGET=400",
        ],
        capture_output=True,
        text=True,
    )
    assert res.returncode != 0 and "over the budget of 400 B" in res.stderr


def test_firmware_uses_no_heap_and_keeps_strings_in_flash(fw_build):
    nm = subprocess.run(["avr-nm", "-C", str(fw_build.elf)], capture_output=True, text=True)
    assert nm.returncode == 0
    assert not re.search(r"\b(malloc|operator new)\b", nm.stdout), "the firmware uses the heap"
    data = subprocess.run(
        ["avr-objcopy", "-O", "binary", "-j", ".data", str(fw_build.elf), "/dev/stdout"],
        capture_output=True,
    ).stdout
    for text in (b"error", b"ok gain", b"commands", b"skinloc_muca"):
        assert text not in data, f"{text!r} sits in RAM (.data)"


# ------------------------------------------------------------------------------- commands
def test_boot_version_and_every_command(fw_build):
    board = EmulatedBoard(fw_build, speed=0)
    board.start()
    link, model = boot(board)
    try:
        link.send("v\n")
        got = link.wait_for(lambda s: any(i.kind == "line" for i in s))
        assert [i.line for i in got if i.kind == "line"] == [
            f"{VERSION} grid 8x8 format binary gain 8 controller ok"
        ]
        model.check([i for i in got if i.kind != "line"])
        for line in [
            b"?",
            b"g 1",
            b"g 31",
            b"c",
            b"l 1101 011",
            b"v",
            b"f text",
            b"v",
            b"l 111111111111111111111 111111111111",
            b"c",
            b"f binary",
            b"v",
        ]:
            run(link, model, [line], n_frames=2)
        assert model.gain == 31 and not model.text
    finally:
        link.close()
        stats = stop_clean(board)
    assert stats["gain"] == 31 and stats["gain_writes"] >= 3  # the gain reached the controller


BAD = [
    b"g 0",
    b"g 32",
    b"g 255",
    b"g -1",
    b"g",
    b"g ",
    b"g 1x",
    b"g  5",
    b"g 99999999",
    b"f",
    b"f txt",
    b"f text ",
    b"f binaryx",
    b"l",
    b"l 1",
    b"l 0 1",
    b"l 1 0",
    b"l 1 1 1",
    b"l 12 1",
    b"l 1111111111111111111111 1",
    b"l 1 1111111111111",
    b"l  1 1",
    b"x",
    b"vv",
    b"v 1",
    b"c 1",
    b"??",
    b"\x00\x01\x02",
    b"\xa5\x5a\x01\x08",
    b"V",
    b"l " + b"1" * 50,
]


def test_every_bad_command_gets_its_error_and_changes_nothing(fw_build):
    board = EmulatedBoard(fw_build, speed=0)
    board.start()
    link, model = boot(board)
    try:
        for line in BAD:
            run(link, model, [line], n_frames=1)
        run(link, model, [b"v"])
        assert model.gain == 8 and len(model.tx_lines) == 8 and not model.text
    finally:
        link.close()
        stop_clean(board)
    assert model.n_replies == len(BAD) + 1


def test_help_lists_the_commands(fw_build):
    with EmulatedBoard(fw_build, speed=0) as board:
        link, model = boot(board)
        run(link, model, [b"?"])
        link.close()
    assert HELP.startswith("commands: v")


# ------------------------------------------------------------------------------- frames
def test_exact_binary_and_text_frames(fw_build):
    """Frames, value for value, in both formats; the counter counts every frame sent."""
    board = EmulatedBoard(fw_build, speed=0)
    board.start()
    link, model = boot(board)
    try:
        run(link, model, [b"l 000000000000000000011 100000000001"], n_frames=5)
        run(link, model, [b"f text"], n_frames=5)
        run(link, model, [b"l 1 1"], n_frames=3)
        run(link, model, [b"f binary"], n_frames=3)
        # the last frames, by hand: TX 0, RX 0 of consecutive scans
        frames = [i for i in link.items if i.kind == "binary"][-3:]
        assert all(f.n_tx == f.n_rx == 1 for f in frames)
        scans = [int(f.values[0]) >> 8 for f in frames]
        assert np.all(np.diff(scans) % 256 == 1)
        assert all(int(f.values[0]) & 0xFF == 0 for f in frames)  # TX 0 x RX 0
    finally:
        link.close()
        stop_clean(board)


def test_line_selection_1x1_to_21x12_and_back_with_c(fw_build):
    """Grow the selection to the whole grid and shrink it again, recalibrating in between:
    the old firmware's 'c' left a grid sized for the lines of that moment behind."""
    board = EmulatedBoard(fw_build, speed=0)
    board.start()
    link, model = boot(board)
    sizes = [(t, min(12, max(1, (t * 12) // 21))) for t in range(1, 22)]
    sizes += sizes[::-1] + [(21, 1), (1, 12), (21, 12)]
    try:
        for k, (t, r) in enumerate(sizes):
            tx = "1" * t
            rx = "1" * r
            lines = [f"l {tx} {rx}".encode()]
            if k % 2 == 0:
                lines = [b"c", *lines, b"c"]
            run(link, model, lines, n_frames=2)
            if k % 7 == 3:
                run(link, model, [b"f text" if not model.text else b"f binary"], n_frames=1)
        assert (len(model.tx_lines), len(model.rx_lines)) == (21, 12)
    finally:
        link.close()
        stats = stop_clean(board)
    assert model.n_frames > 2 * len(sizes)
    assert stats["raw_reads"] > 0


def test_1000_random_command_sequences(fw_build):
    """1,000 random sequences of 'l' of every size, 'c', 'g', 'f', 'v', '?' and garbage in one
    session: every reply as specified, every frame after each intact and exact, no fault."""
    rng = np.random.default_rng(26)
    board = EmulatedBoard(fw_build, speed=0)
    board.start()
    link, model = boot(board)

    def mask(n: int) -> str:
        bits = rng.random(rng.integers(1, n + 1)) < rng.uniform(0.2, 1.0)
        return "".join("1" if b else "0" for b in bits)

    def one() -> bytes:
        kind = rng.choice(["l", "l", "c", "g", "f", "v", "?", "junk", "long"])
        if kind == "l":
            return f"l {mask(21 + int(rng.random() < 0.05))} {mask(12)}".encode()
        if kind == "g":
            return f"g {int(rng.integers(-2, 40))}".encode()
        if kind == "f":
            return rng.choice([b"f text", b"f binary", b"f binary", b"f nope"])
        if kind == "junk":
            junk = rng.integers(0, 256, int(rng.integers(1, 20)), dtype=np.uint8).tobytes()
            junk = junk.replace(b"\n", b"").replace(b"\r", b"")
            # a line starting like the bench finger's "touch"/"lift" would go to the bench
            return b"x" + junk
        if kind == "long":
            return b"l " + b"1" * int(rng.integers(46, 60))
        return kind.encode()

    try:
        for _ in range(1000):
            lines: list[bytes] = []
            while not lines or (rng.random() < 0.4 and len(lines) < 3):
                lines.append(one())
            # the firmware's serial buffer holds 64 bytes: a host sends less at once
            while sum(len(x) + 1 for x in lines) > 63:
                lines.pop()
            if lines:
                run(link, model, lines, n_frames=1)
    finally:
        link.close()
        stats = stop_clean(board)
    assert model.n_replies >= 1000 and model.n_frames >= 1000
    assert stats["scans"] >= model.n_frames


# ------------------------------------------------------------------------------- no controller
@pytest.mark.parametrize(
    "controller, error",
    [
        ("missing", "error no controller at I2C 0x38: check SDA, SCL, VCC and GND"),
        ("silent", "error controller answers but does not scan: check its supply, send c"),
    ],
)
def test_no_controller_is_reported_not_silent(fw_build, controller, error):
    board = EmulatedBoard(fw_build, controller=controller, speed=0)
    board.start()
    link = Link(board.path)
    model = BoardModel(controller=controller)
    try:
        got = link.wait_for(lambda s: any(i.kind == "line" for i in s))
        assert [i.line for i in got] == [error]
        link.send("v\n")
        got = link.wait_for(lambda s: any(i.kind == "line" for i in s))
        assert [i.line for i in got] == [model.version_line()]
        link.send("c\n")
        got = link.wait_for(lambda s: any(i.kind == "line" for i in s))
        assert [i.line for i in got] == [error]
        link.send("g 12\n")
        got = link.wait_for(lambda s: any(i.kind == "line" for i in s))
        assert [i.line for i in got] == ["ok gain 12"]
        assert not [i for i in link.items if i.kind != "line"], "frames without a controller"
    finally:
        link.close()
        stats = stop_clean(board)
    assert stats["scans"] == 0 and stats["raw_reads"] == 0


def test_gain_and_lines_survive_the_reset_of_opening_the_port(fw_build):
    """A host sets them, closes the port; opening it again resets the board, which keeps them."""
    board = EmulatedBoard(fw_build, speed=0)
    board.start()
    try:
        link, model = boot(board)
        run(link, model, [b"g 5", b"l 0011 101", b"f text"], n_frames=2)
        link.close()
        # the format is not kept: the board starts in binary again
        link, model = boot(board, BoardModel(tx_lines=[2, 3], rx_lines=[0, 2], gain=5))
        run(link, model, [b"v"], n_frames=2)
        link.close()
    finally:
        stats = stop_clean(board)
    assert stats["resets"] == 2 and stats["gain"] == 5


def test_the_virtual_skin_answers_as_the_firmware_does():
    """`skinloc virtual-skin` imitates the firmware in Python: word for word the replies of the
    model the real firmware is checked against above (its `v` adds `rate HZ virtual`, its `?`
    the scripted finger's commands, and its grid stays as it is after `l`)."""
    from skinloc.sim.virtual_device import VirtualSkin

    dev = VirtualSkin()
    model = BoardModel()
    good = [b"v", b"?", b"g 1", b"g 31", b"c", b"l 1101 011", b"f text", b"f binary", b"v"]
    for line in good + [x for x in BAD if x.isascii() and b"\0" not in x]:
        model.expect(line)
        want, effect = model.pending[0]
        if effect is not None and effect[0] == "v":
            want = model.version_line()
        got = dev.handle_command(line.decode())
        if line == b"v":
            grid = f"grid {len(model.tx_lines)}x{len(model.rx_lines)}"
            assert got.startswith(want.replace(grid, "grid 8x8") + " rate ")
        elif line == b"?":
            assert got.startswith(want)
        else:
            assert got == want, line
        model.check([Item("line", line=want)])  # the command's effect on the model
