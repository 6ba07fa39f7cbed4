#!/usr/bin/env sh
# Best effort: install the Debian packages some tests need, by group (default: all of them).
#
#   chromium   Debian's chromium, for the browser test (tests/app/test_app_browser.py)
#   firmware   gcc-avr avr-libc arduino-core-avr simavr libsimavr-dev, to build the firmware and
#              run it in the AVR emulator (tests/firmware)
#
#   sh scripts/ensure-packages.sh [chromium] [firmware]
#
# Never fails (make test goes on either way). When another apt or dpkg process holds apt's lock,
# waits for it, at most SKINLOC_APT_WAIT_S seconds in all (default 300). When a group cannot be
# had, the reason goes to build/GROUP-status.txt, which its tests quote in their skip.
STATUS_DIR=build
WAIT_S="${SKINLOC_APT_WAIT_S:-300}"
DEADLINE=$(($(date +%s) + WAIT_S))
LOG="$(mktemp)"
trap 'rm -f "$LOG"' EXIT
UPDATED=no

# apt-get "$@", retried while apt's lock is held by someone else, until DEADLINE.
apt_retry() {
    while :; do
        left=$((DEADLINE - $(date +%s)))
        [ "$left" -gt 0 ] || left=1
        # DPkg::Lock::Timeout makes apt itself wait for the dpkg lock; the loop covers the
        # lists lock of `apt-get update` and any apt without that option.
        if DEBIAN_FRONTEND=noninteractive apt-get -o DPkg::Lock::Timeout="$left" "$@" \
            >"$LOG" 2>&1; then
            return 0
        fi
        if grep -qiE 'could not get lock|unable to lock|lock-frontend' "$LOG" \
            && [ "$(date +%s)" -lt "$DEADLINE" ]; then
            echo "apt is busy (another apt/dpkg process holds its lock); waiting..."
            sleep 2
            continue
        fi
        return 1
    done
}

# What each group needs, whether it is there, and what skips without it.
packages() {
    case "$1" in
        chromium) echo "chromium" ;;
        firmware) echo "gcc-avr avr-libc arduino-core-avr simavr libsimavr-dev" ;;
    esac
}
present() {
    case "$1" in
        chromium)
            for name in chromium chromium-browser google-chrome; do
                command -v "$name" >/dev/null 2>&1 && return 0
            done
            return 1 ;;
        firmware)
            command -v avr-gcc >/dev/null 2>&1 && command -v avr-g++ >/dev/null 2>&1 \
                && [ -e /usr/share/arduino/hardware/arduino/avr/cores/arduino/Arduino.h ] \
                && [ -e /usr/include/simavr/sim_avr.h ] ;;
    esac
}
skips() {
    case "$1" in
        chromium) echo "the browser test will skip" ;;
        firmware) echo "the firmware tests will skip" ;;
    esac
}
purpose() {
    case "$1" in
        chromium) echo "the browser test" ;;
        firmware) echo "the firmware tests" ;;
    esac
}

ensure() {
    group="$1"
    status="$STATUS_DIR/$group-status.txt"
    give_up() {
        mkdir -p "$STATUS_DIR" 2>/dev/null && printf '%s\n' "$1" >"$status" 2>/dev/null
        echo "$1: $(skips "$group")"
    }
    if present "$group"; then
        rm -f "$status"
        return 0
    fi
    pkgs="$(packages "$group")"
    if ! command -v apt-get >/dev/null 2>&1; then
        give_up "$group is not installed and there is no apt-get to install it ($pkgs)"
        return 0
    fi
    if [ "$(id -u)" != "0" ]; then
        give_up "$group is not installed and apt-get needs root (sudo apt-get install $pkgs)"
        return 0
    fi
    echo "installing Debian's $pkgs for $(purpose "$group") (waiting up to ${WAIT_S} s for apt)..."
    if { [ "$UPDATED" = yes ] || apt_retry update -qq; } && UPDATED=yes \
        && apt_retry install -y -qq $pkgs && present "$group"; then
        echo "$group installed: $pkgs"
        rm -f "$status"
        return 0
    fi
    why="$(grep -E '^(E|W):' "$LOG" | tail -n 1)"
    if grep -qiE 'could not get lock|unable to lock' "$LOG"; then
        give_up "$group not installed: apt's lock was still held after ${WAIT_S} s (${why})"
        return 0
    fi
    give_up "$group not installed: apt-get failed (${why:-$(tail -n 1 "$LOG")})"
}

[ "$#" -gt 0 ] || set -- chromium firmware
for group in "$@"; do
    case "$group" in
        chromium | firmware) ensure "$group" ;;
        *) echo "ensure-packages.sh: unknown group '$group' (chromium, firmware)" ;;
    esac
done
exit 0
