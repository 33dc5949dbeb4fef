#!/usr/bin/env bash
# Install the JavaScript libraries Foxglove opens MCAP files with (tests/peers/foxglove, pinned
# by its package-lock.json) for tests/io/test_foxglove_peer.py. Needs Node.js and npm: Debian's
# nodejs/npm are installed when missing and we are root (CI); elsewhere it says what to run and
# the test skips with that reason. Does nothing when the installed tree matches the lock file.
set -euo pipefail
cd "$(dirname "$0")/../tests/peers/foxglove"

if ! command -v node >/dev/null 2>&1 || ! command -v npm >/dev/null 2>&1; then
    if [ "$(id -u)" -ne 0 ] || ! command -v apt-get >/dev/null 2>&1; then
        echo "ensure-node-peers: node/npm missing; the Foxglove reader test needs them (apt-get install nodejs npm)." >&2
        exit 0
    fi
    echo "ensure-node-peers: installing Debian's nodejs and npm for the Foxglove reader test (apt-get) ..."
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq >/dev/null
    apt-get install -y -qq --no-install-recommends nodejs npm >/dev/null
fi
if [ -f node_modules/.package-lock.json ] && [ ! package-lock.json -nt node_modules/.package-lock.json ]; then
    exit 0
fi
echo "ensure-node-peers: npm ci in tests/peers/foxglove (Foxglove's MCAP and ROS 2 readers, ~14 MB) ..."
npm ci --no-audit --no-fund --loglevel=error
