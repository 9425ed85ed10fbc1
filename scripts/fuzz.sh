#!/usr/bin/env bash
# Fuzzing (cargo-fuzz, libFuzzer; needs a nightly toolchain and `cargo install cargo-fuzz`).
#
#   bash scripts/fuzz.sh [SECONDS] [TARGET...]
#
# Writes the seed corpus (fuzz/examples/make_seeds.rs) into fuzz/corpus/<target>/,
# builds every target with AddressSanitizer (overflow checks and debug
# assertions in lumiprobe itself, see fuzz/Cargo.toml), then runs the
# given targets (default: all) one at a time for SECONDS each (default 300) with
# one worker and a 2 GiB memory limit, and prints executions per target. Logs go
# to fuzz/logs/<target>.log, crashing inputs to fuzz/artifacts/<target>/.
# FUZZ_NO_BUILD=1 reuses the seeds and binaries of an earlier run.
# Replay the crashes that were fixed with `cargo test --test fuzz_regressions`.
set -euo pipefail
cd "$(dirname "$0")/.."

secs=${1:-300}
[ $# -gt 0 ] && shift
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
    mapfile -t targets < <(cargo +nightly fuzz list)
fi

if [ "${FUZZ_NO_BUILD:-}" != 1 ]; then
    cargo +nightly run --quiet --manifest-path fuzz/Cargo.toml --example make_seeds -- fuzz/corpus
    cargo +nightly fuzz build -O
fi
mkdir -p fuzz/logs

summary=()
for t in "${targets[@]}"; do
    log=fuzz/logs/$t.log
    echo "== $t: ${secs}s"
    status=0
    # -jobs=1 -workers=1: a single fuzzing process, its output in fuzz-0.log.
    # Resident memory may not pass 2 GiB. A single allocation may reach 4 GiB:
    # the default image limit (2^28 pixels) allows a 3 GiB float buffer, which
    # the readers allocate zeroed before decoding (untouched pages cost no
    # memory); the targets with smaller limits check a tighter bound themselves.
    # The binary `cargo fuzz run` would start, run directly so that one build
    # serves every target.
    mkdir -p "fuzz/artifacts/$t"
    (cd fuzz/logs && rm -f fuzz-0.log &&
        "../target/x86_64-unknown-linux-gnu/release/$t" "../corpus/$t" \
            -artifact_prefix="../artifacts/$t/" \
            -max_total_time="$secs" -rss_limit_mb=2048 -malloc_limit_mb=4096 -timeout=30 \
            -jobs=1 -workers=1 -print_final_stats=1 >"$t.driver.log" 2>&1) || status=$?
    cat fuzz/logs/fuzz-0.log >"$log" 2>/dev/null || cp "fuzz/logs/$t.driver.log" "$log"
    runs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' | tail -1 || true)
    rate=$(grep -o 'stat::average_exec_per_sec: *[0-9]*' "$log" | grep -o '[0-9]*$' | tail -1 || true)
    took=$(grep -o 'Done [0-9]* runs in [0-9]* second' "$log" | grep -o 'in [0-9]*' | grep -o '[0-9]*' | tail -1 || true)
    # A run that stopped at a finding prints no "Done"; estimate its length.
    if [ -z "$took" ] && [ -n "${runs:-}" ] && [ "${rate:-0}" -gt 0 ]; then
        took="~$((runs / rate))"
    fi
    finding=$(grep -m1 -o 'ERROR: libFuzzer: [a-z-]*\|ERROR: AddressSanitizer: [a-z-]*' "$log" || true)
    summary+=("$(printf '%-14s %7ss %12s execs %8s exec/s  %s' "$t" "${took:-?}" "${runs:-?}" \
        "${rate:-?}" "${finding:-no finding}")")
    echo "${summary[-1]}"
done
echo
echo "target          time        executions   exec/s   result"
printf '%s\n' "${summary[@]}"
