#!/usr/bin/env bash
# One lease of a lent GPU machine: the CUDA tests, then the GPU benchmarks, each
# logged under $OUT (default ./gpu_out). Steps are named on the command line so that one call
# of the device tool can run the ones that fit its time:
#
#   benchmarks/run_gpu.sh tests bp train          # default: all three
#   benchmarks/run_gpu.sh bp_full fidelity
#   benchmarks/run_gpu.sh record                  # again and again until the record says finished
#
# The device machine has PyTorch but not this project's other wheels; carry them in .whl/
# (docs/results.md, "GPU"). Nothing here asserts a speed: the benchmarks print figures.
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-gpu_out}
mkdir -p "$OUT"
# into the interpreter's own site-packages: tests start subprocesses with their own PYTHONPATH
[ -d .whl ] && { python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir .whl/*.whl || exit 1; }
export PYTHONUNBUFFERED=1 PYTHONPATH="$PWD:${PYTHONPATH:-}"
# the shared meshes and the survey cache, where a call carried them (.gpu/ is git-ignored)
[ -d .gpu/meshes ] && export SHSAS_MESH_DIR=$PWD/.gpu/meshes
[ -d .gpu/cache ] && export SHSAS_CACHE_DIR=$PWD/.gpu/cache
PY=${PY:-python3}
steps=("$@")
[ ${#steps[@]} -eq 0 ] && steps=(tests bp train)

{ nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.sm --format=csv
  $PY -c "import torch, triton; print('torch', torch.__version__, 'triton', triton.__version__)"; } \
  2>&1 | tee "$OUT/machine.txt"

for step in "${steps[@]}"; do
  echo "=== $step $(date -u +%H:%M:%S)"
  case $step in
    tests)  # the gpu-marked tests and every device-parametrised core test, on CUDA
      timeout 420 $PY -m pytest tests/core -m "gpu or not slow" --device cuda -q -n 8 \
        -p no:cacheprovider --timeout 300 2>&1 | tail -40 | tee "$OUT/tests.txt" ;;
    gputests)  # the gpu-marked tests and the core files that touch CUDA, verbose
      timeout 300 $PY -m pytest tests/core -m gpu --device cuda -q -p no:cacheprovider \
        --timeout 200 2>&1 | grep -v DEBUG | tail -60 | tee "$OUT/gputests.txt"
      timeout 300 $PY -m pytest tests/core/neural/test_native.py tests/core/neural/test_occupancy.py \
        tests/core/neural/test_sh.py tests/core/neural/test_train.py tests/core/neural/test_fields.py --device cuda -q \
        -p no:cacheprovider -n 8 --timeout 200 2>&1 | tail -80 | tee "$OUT/coretests.txt" ;;
    bp)  # side by side (reference, eager, compiled, triton), then the AirSAS-scale case for real
      timeout 300 $PY benchmarks/bench_backprojection.py --device cuda --grid 96 --pings 1024 \
        --repeats 5 --full 2>&1 | tee "$OUT/bp.txt" ;;
    fidelity)  # the scoreboard's dense bunny on defaults, on CUDA
      timeout 150 $PY benchmarks/bench_fidelity.py --regimes dense --scenes bunny --device cuda \
        --out /tmp/fidelity 2>&1 | tail -60 | tee "$OUT/fidelity.txt" ;;
    tritontest)
      timeout 60 $PY -m pytest tests/core/imaging/test_backprojection.py -k triton --device cuda -q \
        -p no:cacheprovider 2>&1 | grep -v DEBUG | tail -30 | tee "$OUT/tritontest.txt" ;;
    train_paper)  # the paper batch alone: fast path, then a few eager iterations (~s each)
      timeout 80 $PY benchmarks/bench_train.py --device cuda --cases paper --modes fast --iters 30 \
        --warmup 5 2>&1 | tee "$OUT/train_paper.txt"
      timeout 90 $PY benchmarks/bench_train.py --device cuda --cases paper --modes eager --iters 3 \
        --warmup 1 2>&1 | tee -a "$OUT/train_paper.txt" ;;
    paper)  # the paper's settings on the dense bunny, ${PAPER_ITERS} iterations (not the paper's 50k)
      spec=$($PY -c "import json; from shsas_core.spec.job import PAPER_SETTINGS as p; \
        print(json.dumps({**p, 'iters': int('${PAPER_ITERS:-3000}')}))")
      timeout 170 $PY benchmarks/bench_fidelity.py --regimes dense --scenes bunny --methods shsas \
        --device cuda --dev-spec "$spec" --out /tmp/fidelity 2>&1 | tail -40 | tee "$OUT/paper.txt" ;;
    record)  # the GPU record: paper_batch_ms per backend, the 50k paper fit (resumed call by call:
      # the checkpoints stay in benchmarks/out/gpu on a warm machine), its scores beside the defaults
      timeout 590 $PY benchmarks/bench_gpu.py --device cuda --budget-s "${BUDGET_S:-520}" \
        --out benchmarks/results 2>&1 | tee "$OUT/record.txt"
      cp benchmarks/results/gpu-*.json "$OUT/" 2>/dev/null ;;
    train)
      timeout 300 $PY benchmarks/bench_train.py --device cuda --cases cpu,paper --iters 50 \
        --warmup 10 2>&1 | tee "$OUT/train.txt" ;;
    *) echo "unknown step $step" ;;
  esac
done
