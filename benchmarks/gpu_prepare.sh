#!/usr/bin/env bash
# Prepares the one device call of the GPU check (issue #16; docs/REPRODUCE.md "GPU check").
# Run here, in the repository root, with network: fills two git-ignored folders that the call
# carries, then prints the call. The GPU machine has no network and its own python3 (3.12,
# with torch, numpy, scipy, scikit-image, matplotlib, jaxtyping, rich, ninja): what gspi needs
# beyond that travels as wheels.
#   .whl/        gsplat 1.5.3 (pure Python: JIT-compiles its CUDA on first use, for
#                TORCH_CUDA_ARCH_LIST=9.0 = Hopper), hydra-core, omegaconf, antlr4 (built here:
#                4.9.3 has no wheel on PyPI), plyfile, pypng, OpenEXR (cp312 manylinux)
#   .gpu_cache/  the LPIPS/AlexNet weights (eval/lpips_weights.py; GSPI_CACHE points there)
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
PLAT="--python-version 3.12 --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64"
rm -rf .whl && mkdir -p .whl .gpu_cache/lpips
$PY -m pip download -q --no-deps --only-binary=:all: $PLAT -d .whl \
  gsplat==1.5.3 hydra-core==1.3.2 omegaconf==2.3.0 plyfile==1.1 pypng==0.20220715.0 OpenEXR==3.3.2
$PY -m pip wheel -q --no-deps -w .whl antlr4-python3-runtime==4.9.3
$PY -m eval.lpips_weights >/dev/null  # makes sure the weights are in the local cache
W=$($PY -c "from eval.lpips_weights import weights_path; print(weights_path())")
cp "$W" "$W.sha256" .gpu_cache/lpips/ 2>/dev/null || cp "$W" .gpu_cache/lpips/
grep -qx '/.gpu_cache/' .gitignore || echo '/.gpu_cache/' >> .gitignore
du -sh .whl .gpu_cache
cat <<'CALL'
Device call (tool `run`), timeout_s=590, carry [".whl", ".gpu_cache"], command:
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:$PWD || exit; export TORCH_CUDA_ARCH_LIST=9.0 GSPI_CACHE=$PWD/.gpu_cache PYTHONUNBUFFERED=1 OMP_NUM_THREADS=8; python3 -m benchmarks.gpu_check --out $OUT/gpu_check --work /tmp/gpu_check_work --budget-s 480 2>&1 | tail -n 40
CALL
