#!/usr/bin/env bash
# Runs every fuzz target (or those named) for SECONDS each; see docs/fuzzing.md.
#   tools/fuzz/run-all.sh SECONDS [TARGET...]
# JOBS=N runs N targets at once (default 1); SANITIZER=address builds with ASan (default none:
# the targets are safe Rust, and uninstrumented code runs several times faster).
# CPU=1 counts SECONDS as the fuzzer's own CPU time rather than wall time, so a run under
# `nice` on a machine busy with other work still fuzzes as long as it says (wall time is then
# capped at 24 x SECONDS).
# New corpus entries go to tools/fuzz/grown/TARGET, crashes to tools/fuzz/artifacts/TARGET,
# logs to tools/fuzz/logs/TARGET.log; a table of runs, executions and findings ends the output.
set -euo pipefail

if [[ $# -lt 1 || ! $1 =~ ^[0-9]+$ ]]; then
    echo "usage: $0 SECONDS [TARGET...]" >&2
    exit 2
fi
seconds=$1
shift
fuzz_dir=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$fuzz_dir/../.." && pwd)
cd "$root"
sanitizer=${SANITIZER:-none}
jobs=${JOBS:-1}
build=(cargo +nightly fuzz build --fuzz-dir tools/fuzz --sanitizer "$sanitizer" --debug-assertions)
if [[ $# -gt 0 ]]; then
    targets=("$@")
else
    mapfile -t targets < <(cargo +nightly fuzz list --fuzz-dir tools/fuzz)
fi
"${build[@]}"
binaries=tools/fuzz/target/$(rustc -vV | sed -n 's/^host: //p')/release
mkdir -p tools/fuzz/logs

run_target() {
    local target=$1
    local dict=()
    [[ -f tools/fuzz/dicts/$target.dict ]] && dict=("-dict=tools/fuzz/dicts/$target.dict")
    mkdir -p "tools/fuzz/grown/$target" "tools/fuzz/corpus/$target" "tools/fuzz/artifacts/$target"
    # -timeout: an input taking 10 s is a hang; the memory limits make a runaway allocation an
    # OOM finding instead of taking the machine down.
    local wall=$seconds
    [[ ${CPU:-0} == 1 ]] && wall=$((seconds * 24))
    "$binaries/$target" "tools/fuzz/grown/$target" "tools/fuzz/corpus/$target" \
        -artifact_prefix="tools/fuzz/artifacts/$target/" \
        -max_total_time="$wall" -timeout=10 -rss_limit_mb=2048 -malloc_limit_mb=2048 \
        -print_final_stats=1 "${dict[@]}" >"tools/fuzz/logs/$target.log" 2>&1 &
    local pid=$!
    local budget=$((seconds * 1000))
    [[ ${CPU:-0} == 1 ]] && budget=$seconds
    stop_after_cpu "$pid" "$budget" &
    wait "$pid" || true
    echo "cpu_seconds: $(cat "tools/fuzz/logs/$target.cpu" 2>/dev/null || echo '?')" \
        >>"tools/fuzz/logs/$target.log"
}

# Interrupts the fuzzer once its user + system time reaches the budget; libFuzzer then prints
# its final stats as it does at -max_total_time. Its CPU time goes to logs/TARGET.cpu.
stop_after_cpu() {
    local pid=$1 budget=$2 tick
    tick=$(getconf CLK_TCK)
    while [[ -r /proc/$pid/stat ]]; do
        local fields used
        read -ra fields <"/proc/$pid/stat" || break
        used=$(((fields[13] + fields[14]) / tick))
        echo "$used" >"tools/fuzz/logs/$target.cpu"
        if [[ $used -ge $budget ]]; then
            kill -INT "$pid" 2>/dev/null || true
            break
        fi
        sleep 10
    done
}

running=0
for target in "${targets[@]}"; do
    run_target "$target" &
    running=$((running + 1))
    if [[ $running -ge $jobs ]]; then
        wait -n
        running=$((running - 1))
    fi
done
wait

printf '%-16s %10s %8s %14s %12s  %s\n' target seconds cpu executions corpus findings
for target in "${targets[@]}"; do
    log=tools/fuzz/logs/$target.log
    runs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' || true)
    took=$(grep -o 'Done [0-9]* runs in [0-9]* second' "$log" | grep -o 'in [0-9]*' | grep -o '[0-9]*' || true)
    units=$(find "tools/fuzz/grown/$target" "tools/fuzz/corpus/$target" -type f | wc -l)
    findings=$(find "tools/fuzz/artifacts/$target" -type f 2>/dev/null | wc -l)
    cpu=$(grep -o 'cpu_seconds: [0-9?]*' "$log" | grep -o '[0-9?]*$' || true)
    printf '%-16s %10s %8s %14s %12s  %s\n' "$target" "${took:-?}" "${cpu:-?}" "${runs:-?}" "$units" "$findings"
done
