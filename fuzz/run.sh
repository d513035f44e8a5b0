#!/usr/bin/env bash
# fuzz/run.sh BUILD TARGET SECONDS — replay the regression inputs of one
# libFuzzer target, then fuzz it from the seed corpus for SECONDS into a
# scratch copy (the repo's corpus stays small). Prints one JSON line.
set -euo pipefail
build=$1 t=$2 secs=$3
bin=$build/fuzz/fuzz_$t
mkdir -p "$build/fuzz/work-$t" "$build/fuzz/artifacts"
if compgen -G "fuzz/regressions/$t/*" >/dev/null; then
  "$bin" fuzz/regressions/$t/* 2>"$build/fuzz/regress-$t.log" \
    || { tail -30 "$build/fuzz/regress-$t.log"; echo "fuzz $t: a regression input fails again"; exit 1; }
fi
maxlen=16384; { [ "$t" = frame ] || [ "$t" = grid ]; } && maxlen=65536
# A sea reader's seed is a whole set of files (five NDBC files of three rows: 15-30 KB).
case $t in sea_*) maxlen=65536 ;; esac
# The config loader: an execution costs in proportion to its input (a JSON
# document), and libFuzzer's length control lets inputs grow to max_len.
# All 56 keys of the settings tables set at once (20-character strings) take
# 1.9 KiB, the longest string a setting refuses is 512 bytes and cJSON's
# nesting limit (1000) is hit within 1001 bytes, so 4 KiB loses no path of
# the loader; with 16 KiB inputs grew and the rate halved (docs/reliability.md, "Fuzzing").
[ "$t" = config ] && maxlen=4096
# Shallow allocation stacks: most of the time in JSON targets went to
# recording them; a crash report still has the full stack of the fault.
export ASAN_OPTIONS=${ASAN_OPTIONS:-malloc_context_size=2}
dict=(); [ -f "fuzz/$t.dict" ] && dict=(-dict="fuzz/$t.dict")
if ! "$bin" -max_total_time="$secs" -max_len=$maxlen -timeout=10 -rss_limit_mb=2048 "${dict[@]}" \
     -print_final_stats=1 -artifact_prefix="$build/fuzz/artifacts/$t-" \
     "$build/fuzz/work-$t" "fuzz/corpus/$t" 2>"$build/fuzz/$t.log"; then
  tail -40 "$build/fuzz/$t.log"
  echo "fuzz $t: crash; the input is in $build/fuzz/artifacts/ — add it to fuzz/regressions/$t/"
  exit 1
fi
execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$build/fuzz/$t.log" | grep -o '[0-9]*$')
printf '{"fuzz":"%s","seconds":%s,"execs":%s,"execs_per_s":%s,"crashes":0}\n' \
  "$t" "$secs" "$execs" "$((execs / secs))"
