#!/usr/bin/env bash
# What a lent GPU machine must confirm before template work lands, in as few device calls as
# possible. Run on that machine from the project root, through the wheels' environment:
#
#   bash .whl/gpu-env.sh bash benchmarks/device_check.sh STAGE... 
#
# (prepare here first: `bash ../shared/device/prep-wheels.sh pytest pluggy iniconfig packaging
# hypothesis sortedcontainers attrs`, and for the cpp stage a copy of the OpenCL headers:
# `mkdir -p .clh && cp -r /usr/include/CL .clh/`; carry .whl and .clh.)
#
# Stages (each writes under $OUT/<stage>/ and appends one line to $OUT/summary.txt):
#   suite   the whole test suite on the NVIDIA device (RBGEN_TEST_DEVICES=nvidia)
#   bench   rbgen bench (BoxBox sizes, piles, pyramids: ms/step, launches, blocking reads, sanity)
#   mesh    benchmarks/midphase.py and benchmarks/terrain.py
#   cpp     benchmarks/cpp_host.py: the C++ host beside the Python World, BoxBox 1,000 / 27,000
#   record  benchmarks/record_overhead.py: a recorded step against a plain one
# The suite alone takes about 4 minutes; a call is limited to 10, so run `suite` alone and the
# others together.
set -uo pipefail
OUT=${OUT:-/tmp/device_check}
mkdir -p "$OUT"
DEVICE=${RBGEN_CHECK_DEVICE:-nvidia}

run_stage() {
  local name=$1
  shift
  mkdir -p "$OUT/$name"
  local start=$SECONDS
  "$@" >"$OUT/$name/log.txt" 2>&1
  local rc=$?
  printf '%-7s rc=%d %4ds  %s\n' "$name" "$rc" $((SECONDS - start)) \
    "$(tail -n 1 "$OUT/$name/log.txt" | cut -c1-100)" | tee -a "$OUT/summary.txt"
}

for stage in "$@"; do
  case $stage in
    suite)
      run_stage suite env RBGEN_TEST_DEVICES="$DEVICE" \
        python3 -m pytest -q -x -p no:cacheprovider --junitxml="$OUT/suite/junit.xml" ;;
    bench)
      run_stage bench python3 -m rbgen bench --device "$DEVICE" --out "$OUT/bench" ;;
    mesh)
      run_stage midphase python3 benchmarks/midphase.py --device "$DEVICE" --out "$OUT/midphase"
      run_stage terrain python3 benchmarks/terrain.py --device "$DEVICE" --out "$OUT/terrain" ;;
    cpp)
      run_stage cpp python3 benchmarks/cpp_host.py --device "$DEVICE" --sizes 1000 27000 \
        --steps 200 --warmup 20 --cl-include "$PWD/.clh" --out "$OUT/cpp" ;;
    record)
      run_stage record python3 benchmarks/record_overhead.py --device "$DEVICE" \
        --out "$OUT/record" ;;
    *)
      echo "device_check: unknown stage '$stage' (suite, bench, mesh, cpp, record)" >&2
      exit 2 ;;
  esac
done
echo "--- summary ($OUT/summary.txt)"
cat "$OUT/summary.txt"
