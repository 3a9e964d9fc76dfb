#!/usr/bin/env bash
# kin against CasADi on the 5-axis example (issue 36; spec/performance.md, "kin against CasADi").
#
# Builds the comparison from scratch and runs it: CasADi from PyPI into a virtual environment,
# the hand-written evaluator's tables of the example (`five_axis_tables`), CasADi's C code of the
# same model (`five_axis.py`) and kin's own (`kin export c`), built by the system's C compiler
# into one shared library with the flags below, and the `casadi` bench of kin-bench loading it. A measurement on this computer,
# not a test; about 3 minutes once built.
#
#   runtime/bench/casadi/run.sh [--check] [WORK_DIR]     (default: target/casadi)
#
# With --check (CI) nothing is timed: the debug build, CasADi's code built with -O1, and the
# three models' outputs compared with kin's at 1 000 poses — an independent check of kin's
# F-matrices by CasADi's differentiation of the machine's transforms.
#
# CC and CFLAGS choose the compiler and its flags (default: cc, -O3 -march=native
# -fno-semantic-interposition). The last flag lets the compiler inline CasADi's own helpers
# (`casadi_sq`, `casadi_fmax`), which the generated file exports: in a shared library without
# it every use is a call through the procedure linkage table, 122 a pose, and CasADi runs 20–25 %
# slower. The comparison is with CasADi at its best.
set -euo pipefail
root="$(cd "$(dirname "$0")/../../.." && pwd)"
check=""
if [ "${1:-}" = "--check" ]; then
    check=1
    shift
fi
work="${1:-$root/target/casadi}"
mkdir -p "$work"
work="$(cd "$work" && pwd)"
cc="${CC:-cc}"
if [ -n "$check" ]; then
    cflags="${CFLAGS:--O1}"
    profile=()
else
    cflags="${CFLAGS:--O3 -march=native -fno-semantic-interposition}"
    profile=(--release)
fi

if [ ! -x "$work/venv/bin/python" ]; then
    python3 -m venv "$work/venv"
fi
"$work/venv/bin/pip" install --quiet --disable-pip-version-check 'casadi==3.8.*'

cd "$root"
cargo run "${profile[@]}" --quiet -p kin-bench --example five_axis_tables >"$work/tables.json"
(cd "$work" && "$work/venv/bin/python" "$root/runtime/bench/casadi/five_axis.py" tables.json kin5.c)
# kin's own C source of the example, compiled beside CasADi's with the same flags and, as its
# header asks, without contracting a*b + c into fused operations (CasADi's may).
cargo run "${profile[@]}" --quiet --bin kin -- export c examples/milling_5axis.kin \
    -o "$work/milling_5axis.c" >/dev/null
# shellcheck disable=SC2086 # CFLAGS is a list of flags
"$cc" $cflags -fPIC -c -o "$work/kin5.o" "$work/kin5.c"
# shellcheck disable=SC2086
"$cc" $cflags -ffp-contract=off -fPIC -c -o "$work/milling_5axis.o" "$work/milling_5axis.c"
"$cc" -shared -o "$work/libkin5.so" "$work/kin5.o" "$work/milling_5axis.o" -lm
echo "casadi: $("$cc" --version | head -n 1), $cflags" >&2
if [ -n "$check" ]; then
    KIN_CASADI_LIB="$work/libkin5.so" KIN_CASADI_CHECK=1 cargo test --quiet -p kin-bench --bench casadi
else
    KIN_CASADI_LIB="$work/libkin5.so" cargo bench --quiet -p kin-bench --bench casadi
fi
