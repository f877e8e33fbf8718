#!/usr/bin/env bash
# One-time (and idempotent) setup for `make demo` / `make test` on Debian/Ubuntu:
# system packages (PostgreSQL 15 + PostGIS + pgRouting, GDAL tools, browser for the UI tests),
# then the Python environment in .venv. Re-running it does nothing that is already done.
set -euo pipefail
cd "$(dirname "$0")/.."

# nginx: the front cache (`ugvmap serve --front-cache`, its test and bench/tiles.py run their
# own nginx with a generated config, never the system service).
APT_PACKAGES=(postgresql-15 postgresql-15-postgis-3 postgresql-15-pgrouting gdal-bin wrk osmium-tool
              nginx nodejs chromium chromium-driver fonts-liberation)
# Debian ships npm apart from nodejs; other nodejs builds (e.g. NodeSource) bundle it and
# conflict with Debian's npm package, so only ask for it when there is no npm command.
command -v npm >/dev/null || APT_PACKAGES+=(npm)

missing=()
for pkg in "${APT_PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if ! python3 -c 'import venv, ensurepip' >/dev/null 2>&1; then
    missing+=(python3-venv)
fi

if ((${#missing[@]})); then
    if [[ $(id -u) -eq 0 ]] && command -v apt-get >/dev/null; then
        echo "setup: installing ${missing[*]}"
        # We run our own cluster; don't let the package create and start a default one.
        if [[ ! -e /etc/postgresql-common/createcluster.conf ]]; then
            mkdir -p /etc/postgresql-common
            echo "create_main_cluster = false" > /etc/postgresql-common/createcluster.conf
        fi
        # Nor a system nginx (or any other service): we run our own, on our own ports. Where no
        # policy says otherwise, deny service starts for the duration of the install.
        if [[ ! -e /usr/sbin/policy-rc.d ]]; then
            printf '#!/bin/sh\nexit 101\n' > /usr/sbin/policy-rc.d
            chmod +x /usr/sbin/policy-rc.d
            trap 'rm -f /usr/sbin/policy-rc.d' EXIT
        fi
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq
        apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
    else
        echo "setup: missing system packages: ${missing[*]}" >&2
        echo "setup: run  sudo apt-get install ${missing[*]}  and re-run, or set DATABASE_URL" >&2
        echo "setup: to an existing PostGIS database (the packages are then only needed for tests)." >&2
        exit 1
    fi
fi

PYTHON=${PYTHON:-$(command -v python3.11 || command -v python3)}
stamp=.venv/.ugvmap-installed
want=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [[ ! -x .venv/bin/python ]]; then
    "$PYTHON" -m venv .venv
fi
if [[ ! -f $stamp || $(cat "$stamp") != "$want" ]]; then
    echo "setup: installing Python packages into .venv"
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -e ".[dev,train]"
    echo "$want" > "$stamp"
fi

# The web map's browser library (MapLibre GL JS), at the version pinned in the lockfile; the
# app serves it from app/web/node_modules, so nothing is fetched from a CDN at run time.
web_stamp=app/web/node_modules/.ugvmap-installed
web_want=$(sha256sum app/web/package-lock.json | cut -d' ' -f1)
if [[ ! -f $web_stamp || $(cat "$web_stamp") != "$web_want" ]]; then
    echo "setup: installing the web map's npm packages"
    (cd app/web && npm ci --omit=dev --no-audit --no-fund --loglevel=error)
    echo "$web_want" > "$web_stamp"
fi
# Test-only: the OSRM client libraries the routing tests run in node (osrm-text-instructions,
# Leaflet Routing Machine + Leaflet + jsdom), pinned by their own lockfile; never served.
clients_stamp=tests/osrm_clients/node_modules/.ugvmap-installed
clients_want=$(sha256sum tests/osrm_clients/package-lock.json | cut -d' ' -f1)
if [[ ! -f $clients_stamp || $(cat "$clients_stamp") != "$clients_want" ]]; then
    echo "setup: installing the OSRM client libraries for the routing tests"
    (cd tests/osrm_clients && npm ci --no-audit --no-fund --loglevel=error)
    echo "$clients_want" > "$clients_stamp"
fi
echo "setup: ok"
