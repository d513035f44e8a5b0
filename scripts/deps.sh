#!/usr/bin/env bash
# Install what is missing, quietly when nothing is: Debian packages from
# scripts/apt-packages.txt, then the web client's npm packages (npm ci).
set -euo pipefail
cd "$(dirname "$0")/.."
want=$(grep -v '^\s*#' scripts/apt-packages.txt | grep -v '^\s*$')
missing=()
for p in $want; do
  # node/npm may come from elsewhere (e.g. NodeSource); a working binary is enough
  case $p in nodejs) command -v node >/dev/null && continue ;; npm) command -v npm >/dev/null && continue ;; esac
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "deps: installing ${missing[*]}" >&2
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO=sudo
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi
if [ -f web/package-lock.json ]; then
  stamp=web/node_modules/.oceand-stamp
  if [ ! -f $stamp ] || [ web/package-lock.json -nt $stamp ]; then
    echo "deps: npm ci in web/" >&2
    (cd web && npm ci --no-audit --no-fund --loglevel=error >/dev/null)
    touch $stamp
  fi
fi
