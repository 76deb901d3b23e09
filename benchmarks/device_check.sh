#!/usr/bin/env bash
# What a lent GPU machine must confirm before template work lands, in as few device calls as
# possible. Run on that machine from the project root, through the wheels' environment:
#
#   bash .whl/gpu-env.sh bash benchmarks/device_check.sh STAGE... 
#
# (prepare here first: `bash ../shared/device/prep-wheels.sh pytest pluggy iniconfig packaging
# hypothesis sortedcontainers attrs pytest-xdist execnet`, and for the cpp stage a copy of the OpenCL headers:
# `mkdir -p .clh && cp -r /usr/include/CL .clh/`; carry .whl and .clh.)
#
# Stages (each writes under $OUT/<stage>/ and appends one line to $OUT/summary.txt):
#   suite   the whole test suite on the NVIDIA device (RBGEN_TEST_DEVICES=nvidia)
#   bench   rbgen bench (BoxBox sizes, piles, pyramids: ms/step, launches, blocking reads, sanity)
#   mesh    benchmarks/midphase.py and benchmarks/terrain.py
#   cpp     benchmarks/cpp_host.py: the C++ host beside the Python World, BoxBox 1,000 / 27,000
#   record  benchmarks/record_overhead.py: a recorded step against a plain one
#   holds   benchmarks/holds.py: BoxBox lattices at the default and substep candidates (issue 24)
#   shock   the shock sweep (issue 24): benchmarks/holds.py at every size, the default (which
#           runs it) against the default without it and the shock candidates, traced to step
#           300 (the window); benchmarks/stacking.py with it at 8 x (2 + 1) and 8 x (3 + 1)
#   envs    benchmarks/many_envs.py: WorldBatch throughput against N (issue 29)
#   cpu     benchmarks/cpu_solve.py on the machine's PoCL CPU device: BoxBox 8,000 and 27,000
#           against the tree in .baseline/ (issue 24's CPU speed; see ccd for .baseline)
#   shockcpu  benchmarks/holds.py on that PoCL device: the CPU default (with the shock sweep)
#           against it without, 8,000 and 27,000 boxes traced to step 300
#   ccd     benchmarks/continuous.py: the tunnelling table, and the cost of continuous collision:
#           BoxBox 8,000 in the branch's head against its branch point (`mkdir -p .baseline
#           .ccdtree && git archive 06bc3af rbgen benchmarks | tar -x -C .baseline && git
#           archive 652f79d rbgen benchmarks | tar -x -C .ccdtree`; carry both)
#   anatomy benchmarks/solve_anatomy.py: where the solve's time goes (a velocity sweep, the push
#           rows, a substep), BoxBox 1,000 and 111,375 (issue 24)
#   barrier benchmarks/device_barrier.py: a device-wide barrier's cost, the floor of a phase
# A record names the commit it measured; the machine's copy of the repository names another,
# so give it: `RBGEN_GIT_COMMIT=<12 digits of HEAD> bash .whl/gpu-env.sh bash ...`.
# The suite runs in 12 processes (pytest-xdist; about 70 s on the H200 machine's 16 cores). Only 8
# files come back from $OUT: the stages pack everything into $OUT/device_check.tgz.
set -uo pipefail
OUT=${OUT:-/tmp/device_check}
mkdir -p "$OUT"
DEVICE=${RBGEN_CHECK_DEVICE:-nvidia}

# The index of the CPU device that compiles (a machine may also have pyopencl's bundled PoCL,
# which cannot: a name such as "portable" matches both).
cpu_index() {
  python3 -c "from rbgen.device import cpu_device, list_devices
d = cpu_device(); print([e.index for e in list_devices() if e.device == d][0])"
}

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
        python3 -m pytest -q -n 12 -p no:cacheprovider --tb=short -rfEsX ;;
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
    cpu)
      cpu=$(cpu_index)
      run_stage cpu8k python3 benchmarks/cpu_solve.py --device "$cpu" --baseline .baseline \
        --n 8000 --rounds 3
      run_stage cpu27k python3 benchmarks/cpu_solve.py --device "$cpu" --baseline .baseline \
        --n 27000 --steps 5 --rounds 3 ;;
    shockcpu)
      cpu=$(cpu_index)
      run_stage shockcpu python3 benchmarks/holds.py --device "$cpu" --sizes 8000 27000 \
        --candidates default no_shock --trace 20 --out "$OUT/shockcpu" ;;
    holds)
      run_stage holds python3 benchmarks/holds.py --device "$DEVICE" --out "$OUT/holds" ;;
    shock)
      run_stage shock_holds python3 benchmarks/holds.py --device "$DEVICE" \
        --candidates default no_shock s8_31 shock_s8_31 shock_s4_31 --trace 10 \
        --out "$OUT/shock_holds"
      run_stage shock_stack21 python3 benchmarks/stacking.py --device "$DEVICE" \
        --options '{"shock_propagation": true}' --out "$OUT/shock_stack21"
      run_stage shock_stack31 python3 benchmarks/stacking.py --device "$DEVICE" \
        --options '{"shock_propagation": true, "iterations": 3}' --out "$OUT/shock_stack31" ;;
    anatomy)
      run_stage anatomy python3 benchmarks/solve_anatomy.py --device "$DEVICE" \
        --out "$OUT/anatomy" ;;
    barrier)
      run_stage barrier python3 benchmarks/device_barrier.py --device "$DEVICE" \
        --out "$OUT/barrier" ;;
    envs)
      run_stage envs python3 benchmarks/many_envs.py --device "$DEVICE" \
        --envs 1,16,256,1024,4096,16384 --out "$OUT/envs" ;;
    ccd)
      run_stage ccd python3 benchmarks/continuous.py --device "$DEVICE" --baseline .baseline \
        --tree .ccdtree \
        --size 8000 --out "$OUT/ccd" ;;
    *)
      echo "device_check: unknown stage '$stage' (suite, bench, mesh, cpp, record, holds, shock, shockcpu, envs, ccd, cpu, anatomy, barrier)" >&2
      exit 2 ;;
  esac
done
tar -czf /tmp/device_check.tgz -C "$OUT" . && mv /tmp/device_check.tgz "$OUT/device_check.tgz"
echo "--- summary ($OUT/summary.txt)"
cat "$OUT/summary.txt"
