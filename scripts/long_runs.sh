#!/usr/bin/env bash
# Long trainings in chunks that survive the end of a session: each lane is a file of vision-rl command lines run in
# turn, each line again and again in chunks of CHUNK_MIN minutes (SIGTERM saves weights and replay buffer; the same
# line continues the run, given --resume if its trainer asks for it) until it exits 0. Run folders live outside the
# checkout (RUNS, default ~/vision_rl-runs).
#
#   scripts/long_runs.sh start LANE.txt [LANE.txt ...]   start each lane in the background (niced)
#   scripts/long_runs.sh status                          the lanes' last lines
#
# A lane line is the arguments of vision-rl, e.g. `train-overtaking --agent 1 --seed 1 --out ~/vision_rl-runs/ot-s1`.
# Starting a lane again after a machine restart resumes every unfinished line (finished ones exit 0 at once).
set -u
RUNS=${RUNS:-$HOME/vision_rl-runs}
CHUNK_MIN=${CHUNK_MIN:-30}
NICE=${NICE:-19}  # a lower value gives a short screen the cores before the long lanes beside it
PYTHON=${PYTHON:-$(cd "$(dirname "$0")/.." && pwd)/.venv/bin/python}
CODE=${CODE:-$(cd "$(dirname "$0")/.." && pwd)}
LOGS=$RUNS/logs
mkdir -p "$LOGS"

run_lane() {
  local lane=$1 name line rc resume quiet
  name=$(basename "$lane" .txt)
  while IFS= read -r line || [ -n "$line" ]; do
    [ -z "$line" ] && continue
    case $line in \#*) continue ;; esac
    resume=""
    # A command with a progress bar gets --no-progress (a log is no terminal); one without (evaluate-ddpg) nothing.
    quiet=$(cd "$CODE" && "$PYTHON" -m vision_rl.commands.main ${line%% *} --help 2>/dev/null | grep -o -m1 -- --no-progress)
    while true; do
      echo "$(date -Is) start $line $resume" >> "$LOGS/$name.log"
      (cd "$CODE" && eval nice -n "$NICE" timeout -s TERM "${CHUNK_MIN}m" "$PYTHON" -m vision_rl.commands.main $line \
        $resume $quiet) >> "$LOGS/$name.out" 2>> "$LOGS/$name.err"
      rc=$?
      echo "$(date -Is) rc=$rc $line $resume" >> "$LOGS/$name.log"
      [ $rc -eq 0 ] && break
      case $rc in 124|130|143) continue ;; esac  # a chunk ended (timeout's SIGTERM saved the run): go on
      # A trainer that continues a run only when asked (train-ddpg, train-policy) refuses a folder holding one: ask.
      if [ -z "$resume" ] && tail -n 1 "$LOGS/$name.err" | grep -q "holds a run: pass --resume"; then
        resume=--resume; continue
      fi
      echo "$(date -Is) FAILED rc=$rc $line" >> "$LOGS/$name.log"; break
    done
  done < "$lane"
}

case ${1:-} in
  start) shift; for lane in "$@"; do nohup bash -c "$(declare -f run_lane); LOGS=$LOGS CHUNK_MIN=$CHUNK_MIN NICE=$NICE \
           PYTHON=$PYTHON CODE=$CODE run_lane $lane" > /dev/null 2>&1 & done ;;
  status) for log in "$LOGS"/*.log; do echo "$(basename "$log"): $(tail -1 "$log")"; done ;;
  *) sed -n '2,10p' "$0"; exit 2 ;;
esac
