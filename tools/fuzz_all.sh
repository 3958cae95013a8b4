#!/usr/bin/env bash
# Why: run every cargo-fuzz target of kdmap's parsers and decoders for N executions each, one
# after the other, one job each, seeded from fuzz/seeds and the test fixtures. Not part of CI
# (`.ci/run`); `--smoke` is a short pass (10k runs per target) a CI job could afford.
#
#   tools/fuzz_all.sh [RUNS] [TARGET...]     default 1000000 runs, every target
#   tools/fuzz_all.sh --smoke                10000 runs per target
#
# Needs a nightly toolchain and cargo-fuzz (`rustup toolchain install nightly --profile
# minimal`, `cargo install cargo-fuzz`). Crashes land in fuzz/artifacts/<target>/; the
# corpora grow in fuzz/corpus/<target>/ (neither is committed). Prints one summary line per
# target: executions, exec/s, result.
set -euo pipefail
cd "$(dirname "$0")/.."

runs=1000000
if [[ "${1:-}" == "--smoke" ]]; then
    runs=10000
    shift
elif [[ "${1:-}" =~ ^[0-9]+$ ]]; then
    runs=$1
    shift
fi
targets=("$@")
if [[ ${#targets[@]} -eq 0 ]]; then
    targets=(mitsuba_xml obj ply exr run_config manifest snapshot gltf)
fi

# Longest input per target: a few times the largest seed (EXR decoding is the slowest).
max_len() {
    case $1 in
        mitsuba_xml) echo 8192 ;;
        obj | ply | run_config) echo 4096 ;;
        exr) echo 2048 ;;
        manifest) echo 8192 ;;
        snapshot | gltf) echo 16384 ;;
    esac
}

# Seed a target's corpus from fuzz/seeds and the fixtures (copies; the corpus is not committed).
seed() {
    local t=$1 c=fuzz/corpus/$1
    mkdir -p "$c"
    cp -n fuzz/seeds/"$t"/* "$c"/ 2>/dev/null || true
    case $t in
        mitsuba_xml) for f in tests/fixtures/*/*.xml tests/fixtures/bad/*.xml; do
            cp -n "$f" "$c/$(echo "$f" | tr / _)"; done ;;
        obj) for f in tests/fixtures/*/meshes/*.obj; do
            [[ $(stat -c %s "$f") -le 4096 ]] && cp -n "$f" "$c/$(echo "$f" | tr / _)"; done ;;
        run_config) cp -n configs/*.toml "$c"/ ;;
        gltf) for f in tests/fixtures/*/*.gltf; do
            cp -n "$f" "$c/$(echo "$f" | tr / _)"; done ;;
    esac
}

(cd fuzz && nice -n 10 cargo +nightly fuzz build -O)
for t in "${targets[@]}"; do
    seed "$t"
    log=fuzz/artifacts/$t.log
    mkdir -p fuzz/artifacts/"$t"
    start=$(date +%s.%N)
    set +e
    rm -f fuzz/fuzz-0.log
    (cd fuzz && nice -n 10 cargo +nightly fuzz run -O "$t" corpus/"$t" -- \
        -runs="$runs" -max_len="$(max_len "$t")" -rss_limit_mb=2048 -timeout=10 \
        -jobs=1 -workers=1 -print_final_stats=1) >"$log" 2>&1
    rc=$?
    set -e
    # With -jobs, libFuzzer's one worker logs to fuzz-0.log in its working directory.
    [[ -f fuzz/fuzz-0.log ]] && cat fuzz/fuzz-0.log >>"$log" && rm fuzz/fuzz-0.log
    grep -qE 'ERROR: libFuzzer|deadly signal|SUMMARY: .*Sanitizer|panicked at' "$log" && rc=1
    secs=$(echo "$(date +%s.%N) - $start" | bc)
    execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' || echo 0)
    rate=$(grep -o 'stat::average_exec_per_sec: *[0-9]*' "$log" | grep -o '[0-9]*$' || echo 0)
    result=ok
    [[ $rc -ne 0 ]] && result="FAILED (rc $rc, see $log and fuzz/artifacts/$t/)"
    printf '%-12s %10s execs %8s exec/s %7.0f s  %s\n' "$t" "$execs" "$rate" "$secs" "$result"
done
