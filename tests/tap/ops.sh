#!/usr/bin/env bash
# test-ops: the operator's side, without a Docker engine.
#   1. docker/Dockerfile and `make deps` install the same package list
#   2. the Dockerfile's runtime stage installs the runtime half of every
#      -dev package the binaries link (checked with ldd + dpkg on this machine)
#   3. the Dockerfile's and the systemd unit's command lines start the real
#      daemon, which answers /healthz
#   4. make install honours PREFIX and DESTDIR
#   5. the configuration reference in the docs agrees with the parameter table
#      and the daemon's options, and the daemon's hello agrees with it
#   6. the package checks fail on planted faults
# Usage: tests/tap/ops.sh BUILD_DIR    (run by `make test-ops` from the repo root)
set -uo pipefail
BUILD=${1:-build}
PY=/usr/bin/python3
tmp=$(mktemp -d)
DAEMON_LOG=$tmp/oceand.log
. "$(dirname "$0")/lib.sh"

DOCKERFILE=docker/Dockerfile
LIST=scripts/apt-packages.txt

# Docker instructions with continuation lines joined, one per line.
joined() { sed -e ':a' -e '/\\$/N; s/\\\n//; ta' "$DOCKERFILE" | sed 's/[[:space:]]\+/ /g'; }
build_stage()   { joined | awk '/^FROM /{n++} n==1'; }
runtime_stage() { joined | awk '/^FROM /{n++} n==2'; }
# Package names of an `apt-get install` line.
install_args() { sed -n 's/.*apt-get install \(.*\)/\1/p' | sed 's/&&.*//' | tr ' ' '\n' | grep -v '^-' | grep -v '^$'; }

trap 'rm -rf "$tmp"' EXIT

# Each check runs in a subshell: a failure ends its section, the others still run.
check_packages() {
  section "1. one package list for make deps and the Dockerfile"
  grep -q 'scripts/apt-packages.txt' scripts/deps.sh || fail "scripts/deps.sh does not read $LIST"
  [ "$(joined | grep -c '^FROM ')" -eq 2 ] || fail "Dockerfile must have exactly two stages (build, runtime)"
  build_stage | grep -q "^COPY $LIST " || fail "build stage does not COPY $LIST"
  install_run=$(build_stage | grep 'apt-get install' || true)
  [ "$(printf '%s\n' "$install_run" | grep -c .)" -eq 1 ] || fail "build stage must have one apt-get install, fed by the list"
  printf '%s\n' "$install_run" | grep -q "$LIST.*| *xargs apt-get install" || fail "build stage apt-get install is not fed by xargs from $LIST"
  # The build stage names no packages itself: everything comes from the list.
  named=$(printf '%s\n' "$install_run" | sed 's/.*xargs //' | install_args)
  [ -z "$named" ] || fail "build stage installs packages not in the list: $named"
  # Run the Dockerfile's own filter and deps.sh's own filter on the list: same names.
  docker_filter=$(printf '%s\n' "$install_run" | sed -e 's/^RUN //' -e 's/.*&& \(grep.*\)| *xargs.*/\1/')
  deps_filter=$(sed -n 's/^want=\$(\(.*\))$/\1/p' scripts/deps.sh)
  [ -n "$deps_filter" ] || fail "cannot find the want=\$(...) line in scripts/deps.sh"
  from_docker=$(bash -c "$docker_filter" | sort)
  from_deps=$(bash -c "$deps_filter" | tr -s ' \n' '\n' | sort)
  [ -n "$from_docker" ] || fail "the Dockerfile's filter reads no packages from $LIST"
  [ "$from_docker" = "$from_deps" ] || fail "Dockerfile and make deps read different packages:
  $(diff <(echo "$from_docker") <(echo "$from_deps"))"
  build_stage | grep -q '^RUN make' || fail "build stage does not build with make"
  ok "Dockerfile and make deps both install the $(echo "$from_deps" | wc -l) packages of $LIST"
}

check_runtime() {
  section "2. runtime stage = runtime halves of the -dev packages"
  runtime_pkgs=$(runtime_stage | grep 'apt-get install' | install_args | sort -u)
  [ -n "$runtime_pkgs" ] || fail "runtime stage installs nothing"
  # The -dev packages of the list (deps.sh's own filter, as in check_packages).
  dev_pkgs=$(bash -c "$(sed -n 's/^want=\$(\(.*\))$/\1/p' scripts/deps.sh)" | tr -s ' \n' '\n' | grep -- '-dev$')
  [ -n "$dev_pkgs" ] || fail "no -dev packages in $LIST"
  # Runtime packages a -dev package depends on (e.g. libcjson-dev -> libcjson1).
  deps_of() { dpkg-query -W -f='${Depends}\n' "$@" 2>/dev/null | tr ',|' '\n\n' | sed 's/(.*//; s/:any//; s/[[:space:]]//g' | grep -v '^$' | sort -u; }
  dev_runtime=$(deps_of $dev_pkgs)
  for p in $runtime_pkgs; do
    case $p in curl|ca-certificates) continue ;; esac  # tools of the image itself (HEALTHCHECK)
    grep -qx "$p" <<<"$dev_runtime" || fail "runtime package $p is not the runtime half of any -dev package in $LIST"
  done
  # Every shared library the shipped binaries load must come from a runtime
  # package, a dependency of one, or an essential package of Debian itself.
  # dpkg-query answered nothing once in a CI run with three suites beside it (its stderr goes
  # to /dev/null): then every library of a dependency read as missing. Ask again, and say so.
  rt_deps=""
  for try in 1 2 3; do
    rt_deps=$(deps_of $runtime_pkgs)
    [ -n "$rt_deps" ] && break
    sleep 1
  done
  [ -n "$rt_deps" ] || fail "dpkg-query -W gave no Depends for the runtime packages: $(dpkg-query -W $runtime_pkgs 2>&1 | head -3)"
  have=$(printf '%s\n' $runtime_pkgs $rt_deps | sort -u)
  checked=0
  for bin in "$BUILD/oceand" "$BUILD/ocean-tap"; do
    [ -x "$bin" ] || fail "$bin is not built"
    for lib in $(ldd "$bin" | awk '/=> \//{print $3}'); do
      real=$(readlink -f "$lib")
      pkg=$(dpkg -S "$lib" 2>/dev/null || dpkg -S "$real" 2>/dev/null || dpkg -S "${lib#/usr}" 2>/dev/null || dpkg -S "/usr$lib" 2>/dev/null)
      pkg=$(echo "$pkg" | head -1 | cut -d: -f1)
      [ -n "$pkg" ] || fail "$bin loads $lib, which no Debian package owns"
      prio=$(dpkg-query -W -f='${Priority}' "$pkg" 2>/dev/null)
      [ "$prio" = required ] && continue
      if ! grep -qx "$pkg" <<<"$have"; then  # once more before failing: see dpkg-query above
        have=$(printf '%s\n' $runtime_pkgs $(deps_of $runtime_pkgs) | sort -u)
        grep -qx "$pkg" <<<"$have" || fail "$bin needs $pkg ($lib) but the Dockerfile's runtime stage does not install it"
      fi
      checked=$((checked + 1))
    done
  done
  ok "runtime stage ($(echo $runtime_pkgs)) covers the $checked non-essential shared-library loads of oceand and ocean-tap"
}

check_image() {
  section "3. image and unit rules, and their command lines start the daemon"
  rt=$(runtime_stage)
  grep -q '^EXPOSE 8080$' <<<"$rt" || fail "runtime stage must EXPOSE 8080"
  grep -q '^HEALTHCHECK .*curl .*/healthz' <<<"$rt" || fail "HEALTHCHECK must curl /healthz"
  user=$(echo "$rt" | sed -n 's/^USER //p' | tail -1)
  [ -n "$user" ] && [ "$user" != root ] && [ "$user" != 0 ] || fail "runtime stage must switch to a non-root USER"
  grep -q "useradd .*$user" <<<"$rt" || fail "runtime stage does not create user $user"
  cmd_json=$(echo "$rt" | sed -n 's/^CMD //p')
  cmd_args=$($PY -c 'import json,sys; print("\n".join(json.loads(sys.argv[1])))' "$cmd_json") || fail "CMD is not an exec-form JSON array"
  [ "$(grep -A1 -x -- '--bind' <<<"$cmd_args" | tail -n1)" = 0.0.0.0 ] || fail "CMD must bind 0.0.0.0"
  # The build context is the repository: host build output must not leak into the image.
  for d in build web/node_modules; do
    grep -qx "$d" docker/Dockerfile.dockerignore || fail "docker/Dockerfile.dockerignore does not exclude $d"
  done
  grep -q "build: *$" docker/compose.yml && grep -q 'dockerfile: docker/Dockerfile' docker/compose.yml && grep -q '8080:8080' docker/compose.yml \
    || fail "docker/compose.yml must build docker/Dockerfile and publish 8080"

  # Start the real daemon with the image's CMD, paths and port swapped for
  # temporary ones: the flags must exist and /healthz must answer.
  # (tmp and the daemon cleanup are set up before the sections run)
  run_cmdline() { # $1 = label, rest = argv as the image/unit would run it
    local label=$1; shift
    local port; port=$(free_port)
    local args=() prev=
    for a in "$@"; do
      case $prev in
        --port) a=$port ;;
        --bind) a=127.0.0.1 ;;   # 0.0.0.0 in production; tests stay on loopback
        --web-root) a=$BUILD/web ;;
        --state-file) a=$tmp/$label-state.json ;;
      esac
      args+=("$a"); prev=$a
      [ "${#args[@]}" -eq 1 ] && args[0]=$BUILD/oceand
    done
    start_daemon "$port" "${args[@]:1}" || fail "$label: the daemon did not start with: ${args[*]}"
    curl -fsS "http://127.0.0.1:$port/healthz" >/dev/null || fail "$label: /healthz did not answer"
    stop_daemons
    ok "$label command line starts oceand and /healthz answers"
}
mapfile -t argv <<< "$cmd_args"
run_cmdline docker "${argv[@]}"

unit=docker/oceand.service
exec_line=$(sed -n 's/^ExecStart=//p' "$unit")
[ "$(echo "$exec_line" | wc -l)" -eq 1 ] || fail "$unit must have one ExecStart"
grep -q '^WantedBy=multi-user.target' "$unit" || fail "$unit has no [Install] WantedBy"
read -r -a uargv <<< "$exec_line"
run_cmdline systemd "${uargv[@]}"
}

check_install() {
  section "4. make install PREFIX=... DESTDIR=..."
  dest=$tmp/dest prefix=/opt/oceand-test
  make --no-print-directory -s install PREFIX=$prefix DESTDIR="$dest" >"$tmp/install.log" 2>&1 \
    || { cat "$tmp/install.log"; fail "make install failed"; }
  root=$dest$prefix
  for f in bin/oceand bin/ocean-tap; do [ -x "$root/$f" ] || fail "not installed: $prefix/$f"; done
  [ -f "$root/share/oceand/web/index.html" ] || fail "web client not installed in $prefix/share/oceand/web"
  u=$root/lib/systemd/system/oceand.service
  [ -f "$u" ] || fail "unit not installed in $prefix/lib/systemd/system"
  grep -q '@[A-Z]*@' "$u" && fail "placeholders left in the installed unit: $(grep -o '@[A-Z]*@' "$u" | sort -u | tr '\n' ' ')"
  grep -q "^ExecStart=$prefix/bin/oceand .*--web-root $prefix/share/oceand/web" "$u" || fail "installed unit does not run $prefix/bin/oceand with its web root: $(grep ExecStart= "$u")"
  grep -rq "$dest" "$u" && fail "DESTDIR leaked into the installed unit"
  outside=$(find "$dest" -mindepth 1 -maxdepth 1 ! -path "$dest/opt")
  [ -z "$outside" ] || fail "make install wrote outside PREFIX: $outside"
  "$root/bin/ocean-tap" --help >/dev/null || fail "installed ocean-tap does not run"
  if command -v systemd-analyze >/dev/null; then
    # Verify the unit as installed (binary paths pointed at the staged copy).
    sed "s|$prefix|$root|g" "$u" > "$tmp/oceand.service"
    systemd-analyze verify "$tmp/oceand.service" >"$tmp/verify.log" 2>&1 \
      || fail "systemd-analyze verify rejects the installed unit: $(cat "$tmp/verify.log")"
    grep -qi 'unknown\|ignoring' "$tmp/verify.log" && fail "systemd-analyze verify: $(cat "$tmp/verify.log")"
  fi
  make --no-print-directory -s uninstall PREFIX=$prefix DESTDIR="$dest" >/dev/null 2>&1 || fail "make uninstall failed"
  left=$(find "$root" -type f 2>/dev/null)
  [ -z "$left" ] || fail "make uninstall left: $left"
  ok "install into DESTDIR=$dest PREFIX=$prefix: binaries, web client, unit; uninstall removes them"
}

check_reference() {
  section "5. configuration reference = parameter table"
  gen=$BUILD/gen-config-doc
  scripts/gen-config-doc.sh --check --daemon "$BUILD/oceand" "$gen" || fail "configuration reference out of date"
  # The check must be able to fail: change one default in a copy of the doc.
  doc=$(scripts/gen-config-doc.sh --doc-path)
  sed '/<!-- config-reference -->/,/<!-- \/config-reference -->/ s/| `wind_speed` \(.*\)| [0-9.]* |/| `wind_speed` \1| 99999 |/' "$doc" > "$tmp/doc.md"
  cmp -s "$doc" "$tmp/doc.md" && fail "could not plant a wrong default in a copy of $doc"
  scripts/gen-config-doc.sh --check --daemon "$BUILD/oceand" --doc "$tmp/doc.md" "$gen" >/dev/null 2>&1 && fail "the check accepted a wrong default"
  # And the table is the daemon's: the hello schema names the same parameters, ranges and defaults.
  port=$(free_port)
  start_daemon "$port" --port "$port" --state-file none || fail "daemon did not start"
  "$BUILD/ocean-tap" "ws://127.0.0.1:$port" > "$tmp/hello.json" 2>"$tmp/hello.err" || fail "ocean-tap could not read hello: $(cat "$tmp/hello.err")"
  stop_daemons
  "$gen" > "$tmp/ref.md"
  $PY - "$tmp/hello.json" "$tmp/ref.md" <<'EOF' || fail "the daemon's parameters disagree with the reference"
import json, sys
hello = json.load(open(sys.argv[1]))
rows = {}
for line in open(sys.argv[2]):
    cells = [c.strip() for c in line.strip().strip('|').split('|')]
    if len(cells) >= 6 and cells[0].startswith('`'):
        rows[cells[0].strip('`')] = cells
params = hello["params"]
missing = sorted(set(params) ^ set(rows))
if missing:
    sys.exit(f"parameters only in one of hello/reference: {missing}")
for name, value in params.items():
    doc_default = rows[name][5].strip('`')
    if isinstance(value, bool):
        ok = doc_default == str(value).lower()
    elif isinstance(value, str):
        ok = doc_default == value
    else:
        ok = float(doc_default) == float(value)   # no state file: the daemon runs the defaults
    if not ok:
        sys.exit(f"{name}: daemon default {value!r}, reference {doc_default!r}")
print(f"  {len(params)} parameters of the daemon's hello all in the reference")
EOF
  ok "reference agrees with the table; a planted error is caught"
}

# The package checks must be able to fail: plant a fault in a copy of the Dockerfile.
check_planted() {
    section "6. the package checks catch planted faults"
    sed 's/^      libcjson1 \\$//' docker/Dockerfile > "$tmp/Dockerfile.noruntime"
    sed 's/| xargs apt-get install -y --no-install-recommends/| xargs apt-get install -y --no-install-recommends gcc-12/' \
      docker/Dockerfile > "$tmp/Dockerfile.extra"
    cmp -s docker/Dockerfile "$tmp/Dockerfile.noruntime" && fail "could not remove libcjson1 from a copy of the Dockerfile"
    cmp -s docker/Dockerfile "$tmp/Dockerfile.extra" && fail "could not add a package to a copy of the Dockerfile"
    (DOCKERFILE=$tmp/Dockerfile.noruntime; check_runtime) >/dev/null 2>&1 && fail "a runtime stage without libcjson1 passed"
    (DOCKERFILE=$tmp/Dockerfile.extra; check_packages) >/dev/null 2>&1 && fail "a build stage installing a package outside the list passed"
    ok "missing runtime library and a second package list are both caught"
}

failed=()
for c in packages runtime image install reference planted; do
  ( trap stop_daemons EXIT; check_$c ) || failed+=("$c")
done
[ ${#failed[@]} -eq 0 ] || { echo "FAIL: test-ops checks failed: ${failed[*]}" >&2; exit 1; }
finish_ok
