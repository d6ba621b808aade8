#!/usr/bin/env bash
# Train runs on a lent GPU machine (the `device` tool), in the background, and bring the finished
# checkpoint folders back. The machine is bare and keeps state only while it stays warm, so:
#   scripts/device_train.sh start QUEUE   install .whl/ (carried wheels), start every line of QUEUE
#                                         (paper_lib.train lines) detached, on cuda, under /tmp/dev
#   scripts/device_train.sh status        steps done per run (from its resume points) and the GPU's load
#   scripts/device_train.sh pack          tar the finished checkpoint folders (15 MiB a tar) under /tmp/dev/tars
#   scripts/device_train.sh fetch I ...   copy tars I ... into $OUT (the tool brings back 8 files a call)
# Runs that cannot finish within the session's device time continue here on the CPU instead:
#   scripts/device_train.sh stop-pack     (device) stop every run, tar its last resume points, split in 15 MiB parts
#   scripts/device_train.sh fetch-parts A B ...   (device) copy parts A B ... (e.g. aa ab) into $OUT
#   scripts/device_train.sh unpack DIR    (here) join the parts in DIR into $PAPER_LIB_RESUME_ROOT for this
#                                         checkout; the same queue lines then resume them on the CPU
# Checkpoints come back as tars of results/<profile>/checkpoints/...; untar them in the repo root, then
# land them as usual (scripts/land_run.sh). Their config.json records device and package versions.
# Exercised so far (session of 2026-11-24, H100 + 16 cores): `start` and `status` (14 Atari runs at once:
# ~22k steps/min each; 5 at once: ~31k). `pack`/`fetch` have not carried a finished run back yet: one
# Atari run needs ~32 min, more than a session's 30 min of device time (see the issue notes).
# .whl/ (cp312 wheels of the packages missing on the device: sb3, sb3-contrib, gymnasium, ale-py, mujoco,
# masksembles, ...) is made here with `pip download --only-binary :all: --python-version 3.12 -d .whl ...`.
set -u
root=/tmp/dev
cmd=${1:?start|status|pack|fetch|stop-pack|fetch-parts|unpack}
case $cmd in
start)
  queue=${2:?queue file}
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit
  mkdir -p "$root/logs"
  cp -r paper_lib params.yaml "$root/"   # a stable copy: later calls replace the working tree
  n=0
  while read -r line; do
    [ -z "$line" ] && continue
    case $line in \#*) continue ;; esac
    args=${line#*-m paper_lib.train }
    n=$((n + 1))
    (cd "$root" && PYTHONPATH=/tmp/site:$root PAPER_LIB_RESUME_ROOT=$root/resume \
       setsid nohup python3 -m paper_lib.train $args --device cuda >"$root/logs/$n.log" 2>&1 </dev/null &)
    echo "started $n: $args"
  done <"$queue"
  ;;
status)
  nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader
  uptime
  PYTHONPATH=/tmp/site python3 - "$root" <<'PY'
import pickle, sys, pathlib
root = pathlib.Path(sys.argv[1])
for state in sorted((root / "resume").rglob("state.pkl")):
    with open(state, "rb") as f:
        s = pickle.load(f)
    print(f"{s['num_timesteps']:>8} steps {s['wall_seconds'] / 60:6.1f} min  {state.parent.relative_to(root / 'resume')}")
for done in sorted(root.glob("results/*/checkpoints/*/*/*/config.json")):
    print("finished", done.parent.relative_to(root))
PY
  grep -l -i "error\|traceback" "$root"/logs/*.log 2>/dev/null | while read -r log; do echo "== $log"; tail -5 "$log"; done
  ;;
pack)
  # greedy tars of at most 15 MiB (the tool brings back files up to 16 MiB, 8 per call)
  mkdir -p "$root/tars" && rm -f "$root"/tars/*.tar
  (cd "$root" && python3 - <<'PY'
import pathlib, subprocess
runs = sorted(pathlib.Path(".").glob("results/*/checkpoints/*/*/seed*"))
groups, size = [[]], 0
for run in runs:
    mb = sum(f.stat().st_size for f in run.rglob("*") if f.is_file()) / 2**20
    if groups[-1] and size + mb > 15:
        groups.append([]); size = 0
    groups[-1].append(str(run)); size += mb
for i, group in enumerate(g for g in groups if g):
    subprocess.run(["tar", "-cf", f"tars/checkpoints_{i + 1}.tar", *group], check=True)
    print(f"tars/checkpoints_{i + 1}.tar:", *group)
PY
  )
  ;;
fetch)  # fetch I [J ...]: copy those tars into $OUT
  shift
  for i in "$@"; do cp "$root/tars/checkpoints_$i.tar" "$OUT/"; done
  ls -la "$OUT"
  ;;
stop-pack)  # a kill loses at most the steps since each run's last resume point (RESUME_EVERY)
  pkill -f "paper_lib.train" ; sleep 3
  mkdir -p "$root/parts" && rm -f "$root"/parts/resume.tar.*
  # resume points live under resume/<absolute checkpoint path>: keep paths from results/ on
  tar -C "$root/resume$root" -cf - results | split -b 15M - "$root/parts/resume.tar."
  ls -la "$root/parts"
  ;;
fetch-parts)
  shift
  for p in "$@"; do cp "$root/parts/resume.tar.$p" "$OUT/"; done
  ls -la "$OUT"
  ;;
unpack)  # unpack DIR: the parts fetched into DIR, in name order
  dir=${2:?folder with resume.tar.* parts}
  dest=${PAPER_LIB_RESUME_ROOT:?set PAPER_LIB_RESUME_ROOT as for the queue}$(pwd)
  mkdir -p "$dest" && cat "$dir"/resume.tar.* | tar -C "$dest" -xf - && find "$dest" -name state.pkl
  ;;
*) echo "unknown command $cmd: use start, status, pack, fetch, stop-pack, fetch-parts or unpack" >&2; exit 2 ;;
esac
