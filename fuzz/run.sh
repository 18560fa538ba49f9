#!/usr/bin/env bash
# Runs every fuzz target (or those named) for SECONDS each (default 600), one after another,
# with AddressSanitizer, from the committed seed corpora in fuzz/corpus/<target>/.
# Installs cargo-fuzz from crates.io if it is missing. The toolchain here is stable, and
# cargo-fuzz passes nightly-only -Z flags, so RUSTC_BOOTSTRAP=1 lets stable accept them.
# New inputs the fuzzer finds go to target/fuzz-corpus/<target>/ (the committed corpora stay
# small); crashes go to fuzz/artifacts/<target>/ and the script exits non-zero.
#
#   fuzz/run.sh               # every target, 600 s each
#   SECONDS_PER_TARGET=60 fuzz/run.sh ply obj
set -euo pipefail
cd "$(dirname "$0")"
secs="${SECONDS_PER_TARGET:-600}"
if ! cargo fuzz --version >/dev/null 2>&1; then
    cargo install cargo-fuzz --locked
fi
export RUSTC_BOOTSTRAP=1
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
    mapfile -t targets < <(cargo fuzz list)
fi
status=0
for t in "${targets[@]}"; do
    work="../target/fuzz-corpus/$t"
    mkdir -p "$work" "corpus/$t"
    log="../target/fuzz-$t.log"
    echo "== $t: ${secs} s (log $log)"
    if cargo fuzz run "$t" "$work" "corpus/$t" -- -max_total_time="$secs" \
        -rss_limit_mb=4096 -timeout=20 -print_final_stats=1 >"$log" 2>&1; then
        grep -E "^(stat::number_of_executed_units|stat::peak_rss_mb|#[0-9]+.*DONE)" "$log" || true
        echo "   $t: no crash"
    else
        status=1
        tail -n 40 "$log"
        echo "   $t: CRASH (see fuzz/artifacts/$t/)"
    fi
done
exit $status
