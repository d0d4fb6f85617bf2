#!/usr/bin/env bash
# System packages the tests use with real components (Debian 12). Idempotent:
# each block installs its packages only when they are missing, and only as root;
# without root it prints what is missing and the tests that need it skip (in CI,
# CI=true, they fail instead). One block per component, so others can add theirs.
set -euo pipefail

APT_GET=(apt-get -o DPkg::Lock::Timeout=600 -y -q --no-install-recommends)
_apt_updated=0

_apt_install() {
    # _apt_install PACKAGE... : install as root, or say why not.
    if [ "$(id -u)" != 0 ]; then
        echo "system-packages: not root; missing: $* (install them, or those tests skip)" >&2
        return 0
    fi
    if ! command -v apt-get >/dev/null; then
        echo "system-packages: no apt-get; install $* by hand" >&2
        return 0
    fi
    if [ "$_apt_updated" = 0 ]; then
        DEBIAN_FRONTEND=noninteractive "${APT_GET[@]}" update >/dev/null
        _apt_updated=1
    fi
    echo "system-packages: installing $*"
    DEBIAN_FRONTEND=noninteractive "${APT_GET[@]}" install "$@" >/dev/null
}

# -- PostgreSQL: throwaway servers for the multi-worker tests ------------------------
postgresql_block() {
    local found=""
    for dir in "$(dirname "$(command -v initdb 2>/dev/null || echo /nonexistent/x)")" \
        /usr/lib/postgresql/*/bin; do
        if [ -x "$dir/initdb" ] && [ -x "$dir/pg_ctl" ] && [ -x "$dir/postgres" ]; then
            found=$dir
            break
        fi
    done
    if [ -z "$found" ]; then
        _apt_install postgresql
    fi
}

# -- Chromium: the headless-browser test of the dashboard ----------------------------
chromium_block() {
    if ! command -v chromium >/dev/null && ! [ -x /usr/bin/chromium ]; then
        _apt_install chromium
    fi
}

# -- CalculiX: the `ccx` solver of the CalculiX tests (tests/solvers, marker calculix) --
calculix_block() {
    if ! command -v ccx >/dev/null; then
        _apt_install calculix-ccx
    fi
    if ! command -v ccx >/dev/null && [ "${CI:-}" = "true" ]; then
        echo "system-packages: ccx is missing and CI requires it (apt-get install calculix-ccx as root)" >&2
        return 1
    fi
}

# -- Slurm and munge: a real single-node Slurm for the cluster tests (tests/cluster, marker
# slurm; the tests start and stop their own munged, slurmctld and slurmd, as root) -------
slurm_block() {
    if ! [ -x /usr/sbin/slurmctld ] || ! [ -x /usr/sbin/slurmd ] || ! [ -x /usr/sbin/munged ] \
        || ! command -v sbatch >/dev/null; then
        _apt_install slurm-wlm munge
    fi
    if ! command -v sbatch >/dev/null && [ "${CI:-}" = "true" ]; then
        echo "system-packages: Slurm is missing and CI requires it (apt-get install slurm-wlm munge as root)" >&2
        return 1
    fi
}

postgresql_block
chromium_block
calculix_block
slurm_block
