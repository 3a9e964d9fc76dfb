#!/usr/bin/env bash
# Instructions and first-level instruction-cache misses per call of kin's evaluation paths on
# the 5-axis example, counted by valgrind's cachegrind (issue 36; spec/performance.md, "Where the
# code lands"). Counts, not times: the same on a loaded machine, so two builds can be compared
# where their timings cannot.
#
#   runtime/bench/cachegrind.sh [PATH ...]
#
# PATH: abi, abi-position, abi-error (the C ABI, β bound), model, model-position, model-error
# (`Model`), hand (the hand-written evaluator, six rows); default all of them. Each runs twice
# under cachegrind — 2 and 12 times the 1 000 poses, after the same setup — and the difference
# over 10 000 calls is what one call costs. I1 sets the simulated instruction cache (default
# 32768,8,64: 32 KiB, 8 ways, 64-byte lines, the first-level cache of AMD's Zen cores and of
# most Intel cores); I1=36864,9,64 adds a way. The simulated cache sees the real addresses, so
# the misses still depend on where a build puts its code — the point of counting them. Needs
# valgrind (apt install valgrind); a few seconds a path once built.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
if ! command -v valgrind >/dev/null; then
    echo "cachegrind.sh: valgrind is not installed (apt install valgrind)" >&2
    exit 1
fi
i1="${I1:-32768,8,64}"
paths=("$@")
if [ ${#paths[@]} -eq 0 ]; then
    paths=(abi model abi-position model-position abi-error model-error hand)
fi
cd "$root"
bin="$(cargo bench --quiet -p kin-bench --bench capi --no-run --message-format=json 2>/dev/null |
    grep '"name":"capi"' | sed -n 's/.*"executable":"\([^"]*\)".*/\1/p' | tail -n 1)"
if [ ! -x "$bin" ]; then
    echo "cachegrind.sh: the capi bench did not build" >&2
    exit 1
fi

# "instructions misses" of the run that executed the most instructions (the bench itself, not
# the helper processes criterion starts).
count() {
    KIN_CAPI_CALLS="$1" KIN_CAPI_REPS="$2" valgrind --tool=cachegrind --cache-sim=yes \
        --I1="$i1" --D1=32768,8,64 --LL=1048576,16,64 --cachegrind-out-file=/dev/null \
        "$bin" --bench 2>&1 |
        awk '/I +refs:/ { gsub(",", "", $NF); refs[$1] = $NF }
             /I1 +misses:/ { gsub(",", "", $NF); miss[$1] = $NF }
             END { best = ""
                   for (p in refs) if (best == "" || refs[p] + 0 > refs[best] + 0) best = p
                   if (best != "") print refs[best], miss[best] }'
}

for path in "${paths[@]}"; do
    case "$path" in
        abi | abi-position | abi-error | model | model-position | model-error | hand) ;;
        *)
            echo "cachegrind.sh: unknown path \`$path\`" >&2
            exit 2
            ;;
    esac
done
echo "per call, 5-axis example (173 coefficients), simulated I1 $i1:"
printf '  %-16s %14s %16s\n' path instructions "I1 misses"
for path in "${paths[@]}"; do
    read -r r2 m2 < <(count "$path" 2)
    read -r r12 m12 < <(count "$path" 12)
    if [ -z "${r2:-}" ] || [ -z "${r12:-}" ]; then
        echo "cachegrind.sh: valgrind gave no count for \`$path\`" >&2
        exit 1
    fi
    awk -v p="$path" -v a="$r2" -v b="$r12" -v c="$m2" -v d="$m12" \
        'BEGIN { m = (d - c) / 10000; if (m < 0.05) m = 0
                 printf "  %-16s %14.0f %16.1f\n", p, (b - a) / 10000, m }'
done
