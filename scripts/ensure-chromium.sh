#!/usr/bin/env bash
# Make sure Debian's Chromium is installed for the HMI's end-to-end browser tests (tests/hmi).
# The tests drive /usr/bin/chromium with Playwright; we never download a browser of our own
# (no `playwright install`). Does nothing when Chromium is already there. Installing needs root
# (CI runs as root); elsewhere it says what to run and leaves the decision to you -- the e2e tests
# then skip with that reason (or fail when CI is set).
set -euo pipefail

CHROMIUM=/usr/bin/chromium
if [ -x "$CHROMIUM" ]; then
    exit 0
fi
if [ "$(id -u)" -ne 0 ]; then
    echo "ensure-chromium: $CHROMIUM is missing; the HMI browser tests need it." >&2
    echo "ensure-chromium: install it with: sudo apt-get install --no-install-recommends chromium" >&2
    exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "ensure-chromium: $CHROMIUM is missing and apt-get is not available; install Chromium by hand." >&2
    exit 0
fi
echo "ensure-chromium: installing Debian's chromium for the HMI browser tests (apt-get, a few minutes) ..."
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq >/dev/null
apt-get install -y -qq --no-install-recommends chromium >/dev/null
if [ -x "$CHROMIUM" ]; then
    echo "ensure-chromium: $("$CHROMIUM" --version 2>/dev/null || echo chromium) installed"
else
    echo "ensure-chromium: apt-get finished but $CHROMIUM is still missing" >&2
    exit 1
fi
