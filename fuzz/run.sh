#!/usr/bin/env bash
# Coverage-guided fuzzing of h4-teleop on stable Rust: libFuzzer (libfuzzer-sys) with rustc's
# stable SanitizerCoverage flags (what cargo-fuzz passes, without the nightly-only -Z
# sanitizer). Usage: fuzz/run.sh [RUNS_PER_TARGET] [TARGET...]  (default 10000000, all);
# MAX_TIME_S=N caps each target's run at N seconds (libFuzzer's -max_total_time).
# Corpus: fuzz/corpus/<target>/ (kept in the repository; new interesting inputs are added
# there); crashes land in fuzz/artifacts/<target>/. Needs a C++ compiler (libFuzzer is C++).
set -euo pipefail
cd "$(dirname "$0")"
runs=${1:-10000000}
shift || true
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
  targets=(wire_decode gate gate_bytes arm_config experiment_config kin_tool)
fi
export RUSTFLAGS="-Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4 \
-Cllvm-args=-sanitizer-coverage-inline-8bit-counters -Cllvm-args=-sanitizer-coverage-pc-table \
-Cllvm-args=-sanitizer-coverage-trace-compares --cfg fuzzing -Cdebug-assertions -Coverflow-checks"
# An explicit --target keeps the flags off build scripts and proc macros (as cargo-fuzz does).
triple=$(rustc -vV | sed -n 's/^host: //p')
cargo build --release --bins --target "$triple"
for t in "${targets[@]}"; do
  mkdir -p "corpus/$t" "artifacts/$t"
  echo "== $t: $runs runs"
  start=$(date +%s)
  ./target/"$triple"/release/"$t" "corpus/$t" -runs="$runs" -max_len=2048 -timeout=10 \
    -artifact_prefix="artifacts/$t/" -print_final_stats=1 \
    ${MAX_TIME_S:+-max_total_time="$MAX_TIME_S"} 2>&1 | tail -n 25 | tee "artifacts/$t.log"
  echo "== $t: $(( $(date +%s) - start )) s"
done
