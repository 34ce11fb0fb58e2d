#!/usr/bin/env bash
# The GPU checks still waiting for a lent GPU machine, in one call (device time is short: one start, one run).
#
# Waiting since 2026-12-05 (the loan was paused after a first call): the twin's cuda_ad_rgb variant
# (bench_gpu_render.py) and `nlips train --device cuda` (bench_train_step.py). NLiPsNet inference on a GPU
# (bench_gpu_infer.py) was re-measured that day and is not repeated here.
#
# Prepare here (the CPU machine, with the `sim` extra), into the git-ignored folder .gpu/ (add `/.gpu/` to
# .git/info/exclude):
#   python benchmarks/bench_gpu_render.py pack --out .gpu/gel.npz                     # the bench press, llvm stats
#   KEEP_VARIANTS="cuda_ad_rgb llvm_ad_rgb scalar_rgb" benchmarks/gpu_bundle.sh .gpu/mitsuba-cp312.tar.xz WHEELS
#   cp -rL CALIB .gpu/calib      # a calibration dataset of ~10 640x480 presses (`nlips calibrate`), ~20 MB
# Then call the device with carry [".gpu"] (the tree ~12 MB + these ~46 MB: under the 64 MiB a call takes) and the
# command `bash benchmarks/gpu_session.sh`, timeout ~500 s (estimated 4-6 min: two render runs within their
# budgets of 170 + 120 s, three epochs of training per device twice). Files back (at most 8): OUT/render-cuda/
# gpu_render.json, OUT/render-llvm/gpu_render.json (the same press on the machine's 16 cores, for comparison),
# OUT/train/train_device.json, OUT/train/net.pt (a GPU-trained model: check `nlips export` and `nlips infer` on it
# here). Everything else goes to stdout (the call returns its last 12,000 characters).
set -u
export PYTHONUNBUFFERED=1
G=${GPU_DATA:-.gpu}
date -u
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
python3 -c "import sys, torch; print(sys.version.split()[0], torch.__version__, torch.cuda.is_available())"

echo "== the twin's cuda_ad_rgb variant, then llvm_ad_rgb on this machine's CPU cores"
mkdir -p /tmp/site "$OUT/render-cuda" "$OUT/render-llvm" "$OUT/train"
if tar -xJf "$G/mitsuba-cp312.tar.xz" -C /tmp/site; then
  for variant in cuda llvm; do
    budget=$([[ $variant == cuda ]] && echo 170 || echo 120)
    PYTHONPATH=/tmp/site:. timeout $((budget + 50)) python3 benchmarks/bench_gpu_render.py run \
      --gel "$G/gel.npz" --out "$OUT/render-$variant" --variant "${variant}_ad_rgb" --budget "$budget" 2>&1 |
      cut -c1-600
  done
else
  echo "gpu_session.sh: $G/mitsuba-cp312.tar.xz: could not be unpacked; render checks skipped"
fi
date -u

echo "== nlips train --device cuda (3 epochs, paper net), then the same run asked on the CPU: reused, names cuda"
T=/tmp/gpu-train
PYTHONPATH=. timeout 200 python3 -m nlipscalib train "$G/calib" --out $T/net.pt --device cuda --epochs 3 --no-onnx \
  --no-progress 2>&1 | tail -5
PYTHONPATH=. python3 -m nlipscalib train "$G/calib" --out $T/net.pt --device cpu --epochs 3 --no-onnx --no-progress \
  2>&1 | tail -3
cp $T/net.pt "$OUT/train/" 2>/dev/null
echo "== epochs per device"
PYTHONPATH=. timeout 240 python3 benchmarks/bench_train_step.py --dataset "$G/calib" --devices cpu,cuda --epochs 3 \
  --rounds 2 --threads 1 --out /tmp/train-device 2>&1 | tail -25
cp /tmp/train-device/train_device.json "$OUT/train/" 2>/dev/null
date -u
