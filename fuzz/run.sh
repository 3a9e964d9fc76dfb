#!/usr/bin/env bash
# Runs one fuzz target for a bounded time: fuzz/run.sh TARGET SECONDS [extra libFuzzer flags]
#
# Targets: kin_source, measurement_csv, fit_json, capi, robot_description, lsp (see fuzz/README.md). Needs cargo-fuzz
# (`cargo install --locked cargo-fuzz`). libFuzzer needs nightly compiler flags; on a stable
# toolchain they are enabled with RUSTC_BOOTSTRAP=1. AddressSanitizer is on (the C ABI takes raw
# pointers); KIN_FUZZ_SANITIZER=none runs without it (about twice as fast, for a toolchain
# that lacks its runtime). Optimised, with debug assertions and overflow checks (fuzz/Cargo.toml).
#
# New inputs go to a scratch corpus (fuzz/target/corpus/TARGET, not kept); the kept corpus
# fuzz/corpus/TARGET and the crash regressions fuzz/regressions/TARGET are read, never written.
# A crash (panic, abort), a hang of more than 10 s on one input, or more than 2 GB of memory
# fails the run (exit code non-zero); libFuzzer writes the input to fuzz/artifacts/TARGET/.
set -euo pipefail
if [ $# -lt 2 ]; then
  echo "usage: fuzz/run.sh TARGET SECONDS [libFuzzer flags…]" >&2
  exit 2
fi
target=$1
seconds=$2
shift 2
cd "$(dirname "$0")"
case "$target" in
  kin_source | measurement_csv | fit_json | capi | robot_description | lsp) ;;
  *)
    echo "unknown target \`$target\` (kin_source, measurement_csv, fit_json, capi, robot_description, lsp)" >&2
    exit 2
    ;;
esac
scratch=target/corpus/$target
mkdir -p "$scratch" "artifacts/$target"
export RUSTC_BOOTSTRAP=1
# Inputs up to 64 KiB: room for a machine file with its params, a few hundred CSV rows, or a
# FIT.json with a covariance matrix (the seeds set the starting size; larger ones are kept).
exec cargo fuzz run --sanitizer "${KIN_FUZZ_SANITIZER:-address}" --release "$target" \
  "$scratch" "corpus/$target" "regressions/$target" -- \
  -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -max_len=65536 \
  -print_final_stats=1 "$@"
