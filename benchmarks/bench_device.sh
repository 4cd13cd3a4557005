#!/usr/bin/env bash
# Issue 30 on a lent CUDA GPU, in one pass that fits a 15-minute lease (docs/benchmarks.md,
# "Training and decoding on a CUDA GPU"). Run from the repository root on the GPU machine, with
#   .whl/    the wheels its image lacks (OpenImageIO, flip-evaluator, platformdirs, click,
#            moderngl, glcontext, PyOpenGL; cp312 manylinux),
#   .gl/     the GL/EGL loader .debs (device README), .scenes/usdwg_teapot/textures/ (the sources).
# 1. the teapot at 1k, `standard`, side by side: CUDA (torch) at the preset's batch, CUDA at 4x the
#    batch and the same steps, and the CPU's fused kernel on the GPU machine's own host;
# 2. the decode cost of the CUDA material against the classic BC pass, fragment and compute stages.
# QUICK=1 swaps every training for `smoke` (a dry run of the script on any machine).
set -u
OUT=${OUT:-/tmp/bench-device}; mkdir -p "$OUT"
DEVICE=${DEVICE:-cuda}
if [[ -d .whl && -z ${NO_WHL:-} ]]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD
fi
if [[ -d .gl && -z ${NO_WHL:-} && $(id -u) == 0 ]]; then
  for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
fi
v=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json; [[ -f $v ]] && export __EGL_VENDOR_LIBRARY_FILENAMES=$v
export PYTHONUNBUFFERED=1 BCFPIPE_SCENES=${BCFPIPE_SCENES:-$PWD/.scenes}
PY=${PY:-python3}
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null
$PY -c "import torch; print('torch', torch.__version__, torch.cuda.is_available())"
# fail fast: a CUDA smoke training, then a GL context
timeout 180 $PY benchmarks/bench_presets.py --set teapot --profile 0.5k --presets smoke --device "$DEVICE" || exit 2
timeout 60 $PY -c "from bcfpipe.verify.glsl import GLRuntime; r = GLRuntime(); print(r.info); r.release()" \
  || echo "no GL context: the decode timing will fail"
if [[ ${QUICK:-0} == 1 ]]; then STD=smoke; BIG=smoke4:20:60:10:4096; else STD=standard; BIG=std-b256:3200:16000:300:65536; fi
B="$PY benchmarks/bench_presets.py --set teapot --profile 1k"
timeout 460 $B --presets $STD --device "$DEVICE" --keep /tmp/keep-cuda > "$OUT/train_cuda.txt" 2>&1 &
timeout 460 $B --presets $BIG --device "$DEVICE" > "$OUT/train_cuda_b256.txt" 2>&1 &
timeout 460 $B --presets $STD --device cpu > "$OUT/train_cpu.txt" 2>&1 &
wait
tail -n 4 "$OUT"/train_*.txt
timeout 120 $PY benchmarks/bench_decode_formats.py /tmp/keep-cuda/$STD --size 1920x1080,2560x1440 --frames 100 \
  --stages fragment,compute 2>&1 | tee "$OUT/decode.txt"
