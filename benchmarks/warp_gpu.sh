#!/bin/sh
# bench_warp.py on a GPU machine that cannot reach a package index, from the repository root.
#
#   sh benchmarks/warp_gpu.sh stage     # keep the wheel pieces carried in .gpu_wheels/N
#   sh benchmarks/warp_gpu.sh install   # stage, join, install (no index), name the GPU
#   sh benchmarks/warp_gpu.sh           # ... then run the benchmark
#
# The pieces come from `python benchmarks/warp_gpu_bundle.py` (folders .gpu_wheels/1..3, one
# per call to the machine, back to back so that it stays warm); they are kept in $STAGE,
# outside the repository's copy. The table goes to stdout and, with the rows as JSON, to
# $OUT (or the current folder).
set -eu
STAGE=${STAGE:-/tmp/wpam_gpu_wheels}
OUT=${OUT:-.}
WARP=warp_lang-1.19.0-py3-none-manylinux_2_28_x86_64.whl
mkdir -p "$STAGE"
for f in .gpu_wheels/*/*; do
    [ -e "$f" ] && cp "$f" "$STAGE/"
done
echo "staged: $(ls "$STAGE" | tr '\n' ' ')"
[ "${1:-}" = stage ] && exit 0
cat "$STAGE/$WARP".part* > "$STAGE/$WARP"
if ! python3 -m zipfile -t "$STAGE/$WARP" > /dev/null 2>&1; then
    echo "warp_gpu.sh: $WARP is incomplete (pieces: $(ls "$STAGE" | grep -c part)); carry" \
         "every .gpu_wheels/N to this machine while it stays warm" >&2
    exit 3
fi
python3 -m pip install -q --no-deps --no-index "$STAGE"/*.whl
nvidia-smi -L || true
[ "${1:-}" = install ] && exit 0
PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} python3 benchmarks/bench_warp.py --devices cuda \
    --worlds 1,16,256,4096,65536 --env-max 256 --seconds 1 --repeats 2 \
    --json "$OUT/bench_warp.json" 2>&1 | grep -v "^Module " | tee "$OUT/bench_warp.txt"
