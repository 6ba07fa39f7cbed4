#!/usr/bin/env sh
# Best effort: make Debian's chromium available for the browser test (tests/test_app_browser.py).
# Never fails: without apt-get or root, the browser test skips and says why.
if command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1; then
    exit 0
fi
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = "0" ]; then
    echo "installing Debian's chromium for the browser test..."
    if apt-get update -qq >/dev/null 2>&1 \
        && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null 2>&1; then
        echo "chromium installed: $(command -v chromium)"
        exit 0
    fi
fi
echo "chromium not available (no apt-get, not root, or the install failed): the browser test will skip"
exit 0
