#!/usr/bin/env sh
# Best effort: make Debian's chromium available for the browser test (tests/app/test_app_browser.py).
# Never fails (make test goes on either way). When another apt or dpkg process holds apt's lock,
# waits for it, at most SKINLOC_APT_WAIT_S seconds (default 300). When chromium cannot be had,
# the reason goes to build/chromium-status.txt, which the browser test quotes in its skip.
STATUS_DIR=build
STATUS="$STATUS_DIR/chromium-status.txt"
WAIT_S="${SKINLOC_APT_WAIT_S:-300}"

give_up() {
    mkdir -p "$STATUS_DIR" 2>/dev/null && printf '%s\n' "$1" >"$STATUS" 2>/dev/null
    echo "$1: the browser test will skip"
    exit 0
}

for name in chromium chromium-browser google-chrome; do
    if command -v "$name" >/dev/null 2>&1; then
        rm -f "$STATUS"
        exit 0
    fi
done
command -v apt-get >/dev/null 2>&1 \
    || give_up "chromium is not installed and there is no apt-get to install it"
[ "$(id -u)" = "0" ] \
    || give_up "chromium is not installed and apt-get needs root (sudo apt-get install chromium)"

LOG="$(mktemp)"
trap 'rm -f "$LOG"' EXIT
DEADLINE=$(($(date +%s) + WAIT_S))

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

echo "installing Debian's chromium for the browser test (waiting up to ${WAIT_S} s for apt)..."
if apt_retry update -qq && apt_retry install -y -qq chromium; then
    echo "chromium installed: $(command -v chromium)"
    rm -f "$STATUS"
    exit 0
fi
why="$(grep -E '^(E|W):' "$LOG" | tail -n 1)"
if grep -qiE 'could not get lock|unable to lock' "$LOG"; then
    give_up "chromium not installed: apt's lock was still held after ${WAIT_S} s (${why})"
fi
give_up "chromium not installed: apt-get failed (${why:-$(tail -n 1 "$LOG")})"
