#!/usr/bin/env bash
# tests/run_suites.sh — runs `make test`'s suites in three phases and counts them.
#
#   tests/run_suites.sh LOGDIR "WAITING..." "PAIRED..." "ALONE..."
#
#   WAITING  suites that mostly wait (real daemons on loopback at 30 Hz, NATS
#            restarts: wall time >> CPU time): all at once.
#   PAIRED   single-threaded CPU-bound suites that time nothing (valgrind,
#            fuzzing, the sanitizer builds of the libraries): as many at once
#            as there are cores, so each has a core of its own.
#   ALONE    the rest, one at a time, alone on the machine: suites whose
#            daemons must keep their tick (ASan daemons, the hostile battery,
#            the link lab, SwiftShader).
#
# Every suite runs even if one fails. Each suite of the first two phases
# writes its own log (LOGDIR/NAME.log), printed whole and in the order given;
# the closing lines name the failed suites and count them. Uses $MAKE.
set -u
logs=$1 waiting=$2 paired=$3 alone=$4
make=${MAKE:-make}
pass=0 fail=0 failed=""
rm -rf "$logs" && mkdir -p "$logs"
declare -A pid_of=()
trap 'for p in "${pid_of[@]}"; do kill -TERM -- -"$p" 2>/dev/null; done; exit 130' INT TERM

count() { # NAME RC
    if [ "$2" = 0 ]; then pass=$((pass + 1)); else fail=$((fail + 1)); failed="$failed $1"; fi
}

start() { # NAME: in its own process group (the trap stops its daemons too) and log
    setsid bash -c '"$0" --no-print-directory "$1"; rc=$?; echo "--- $1: exit $rc after $SECONDS s"; exit $rc' \
        "$make" "$1" >"$logs/$1.log" 2>&1 &
    pid_of[$1]=$!
}

finish() { # NAME: wait for it, print its log, count it
    local rc=0
    wait "${pid_of[$1]}" || rc=$?
    echo "=== $1"
    cat "$logs/$1.log"
    unset "pid_of[$1]"
    count "$1" "$rc"
}

# Phase 1: all at once.
echo "=== running concurrently:$waiting (logs in $logs/)"
for t in $waiting; do start "$t"; done
for t in $waiting; do finish "$t"; done

# Phase 2: at most one per core, the next started as soon as one ends (list
# the longest first); logs printed in the order given, each once it and
# those before it have ended.
slots=$(nproc)
echo "=== running $slots at a time:$paired (logs in $logs/)"
queue=($paired) next=0 shown=0
declare -A rc_of=()
while [ "$shown" -lt "${#queue[@]}" ]; do
    while [ "$next" -lt "${#queue[@]}" ] && [ "${#pid_of[@]}" -lt "$slots" ]; do
        start "${queue[$next]}"
        next=$((next + 1))
    done
    rc=0
    wait -n -p ended "${pid_of[@]}" || rc=$?
    for t in "${!pid_of[@]}"; do
        if [ "${pid_of[$t]}" = "$ended" ]; then rc_of[$t]=$rc; unset "pid_of[$t]"; fi
    done
    while [ "$shown" -lt "$next" ] && [ -n "${rc_of[${queue[$shown]}]+x}" ]; do
        t=${queue[$shown]}
        echo "=== $t"
        cat "$logs/$t.log"
        count "$t" "${rc_of[$t]}"
        shown=$((shown + 1))
    done
done

# Phase 3: one at a time.
for t in $alone; do
    echo "=== $t"
    s=$SECONDS rc=0
    "$make" --no-print-directory "$t" || rc=$?
    echo "--- $t: exit $rc after $((SECONDS - s)) s"
    count "$t" "$rc"
done

[ -n "$failed" ] && echo "failed suites:$failed"
echo "$pass passed, $fail failed"
[ "$fail" -eq 0 ]
