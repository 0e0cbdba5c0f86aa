#!/usr/bin/env bash
# The CUDA runs that docs/ records (CI has no GPU): the whole suite on cpu and every CUDA device,
# the determinism tests on CUDA verbosely (reruns bit for bit, CPU against CUDA), and
# `almsdm bench` on the stomach scene as JSON (for `almsdm evaluate --extra-json`).
#   OUT=dir ALMSDM_SHARED_MESHES=../shared/meshes bash scripts/cuda_check.sh
set -uo pipefail
out=${OUT:-cuda_check}
mkdir -p "$out"
python3 -c "import warp as wp; wp.init(); print('CUDA devices:', [d.alias for d in wp.get_cuda_devices()])"
python3 -m pytest -q -p no:cacheprovider -rs 2>&1 | tee "$out/pytest.log" | tail -6
python3 -m pytest -q -p no:cacheprovider -v -k cuda tests/test_determinism.py 2>&1 | tee "$out/determinism.log" | grep -E "PASS|FAIL|SKIP|passed|failed"
python3 -m almsdm_warp.cli.main bench stomach --device cuda:0 --blocks 3 --json "$out/bench_stomach_cuda.json" 2>&1 | tee "$out/bench.log" | tail -25
