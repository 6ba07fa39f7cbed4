#!/usr/bin/env sh
# Best effort: make Debian's chromium available for the browser test (tests/app/test_app_browser.py).
# The work is done by ensure-packages.sh (its group "chromium"); see there.
exec sh "$(dirname "$0")/ensure-packages.sh" chromium
