#!/usr/bin/env bash
# System packages the test suite needs beyond the Python ones (called by test.sh).
# Each block is idempotent and installs only what is missing, and only as root;
# in CI (CI=true) a package still missing afterwards is an error.
set -euo pipefail

apt_install() {
    if [ "$(id -u)" -ne 0 ] || ! command -v apt-get >/dev/null 2>&1; then
        return 1
    fi
    if [ -z "${_APT_UPDATED:-}" ]; then
        apt-get update -qq >/dev/null
        _APT_UPDATED=1
    fi
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null
}

# CalculiX (issue 7): the `ccx` solver of the CalculiX tests (tests/solvers, marker calculix).
install_calculix() {
    command -v ccx >/dev/null 2>&1 && return 0
    echo "system-packages: installing calculix-ccx"
    apt_install calculix-ccx || true
    if ! command -v ccx >/dev/null 2>&1; then
        if [ "${CI:-}" = "true" ]; then
            echo "system-packages: ccx is missing and CI requires it (apt-get install calculix-ccx as root)" >&2
            return 1
        fi
        echo "system-packages: ccx not installed (not root?); the CalculiX tests will skip" >&2
    fi
}

install_calculix
