#!/usr/bin/env bash
# Mouth-to-ear delay of a lipcall call on loopback, measured end to end.
#
# Starts a private PulseAudio server with three null sinks (the talker's microphone "mouth", the
# listener's output "ear", the talker's own output), two apps under Xvfb (the listener with
# --listen, the talker with --call to it, each with a settings file of its own), plays a click
# track into the talker's microphone, records what the microphone hears and what the listener
# plays, and pairs the clicks (tools/mouth_to_ear.py): median and spread, and the listener's
# breakdown (jitter buffer, queue, output).
#   tools/mouth_to_ear.sh [CLICKS=60] [LIPCALL=target/debug/lipcall]
# EAR_ARGS adds flags to the listener's command line (EAR_ARGS="--output-margin-ms 20");
# TALKER_FRAME_MS=10 has the talker send Opus in 10 ms frames (its settings file says so).
# Needs pulseaudio, pulseaudio-utils, xvfb, xauth, python3. A busy machine makes the numbers
# pessimistic: compare runs made in the same conditions.
set -euo pipefail
clicks=${1:-60}
lipcall=$(realpath "${2:-target/debug/lipcall}")
here=$(dirname "$(realpath "$0")")
work=$(mktemp -d)
pids=()
cleanup() {
    # xvfb-run's children first: an app whose X server went first never reaches its
    # --quit-after (it quits from its UI loop) and would run on, loading the machine.
    for p in "${pids[@]}"; do pkill -TERM -P "$p" 2>/dev/null || true; done
    for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
    wait 2>/dev/null || true
    rm -rf "$work" 2>/dev/null || true
}
trap cleanup EXIT
export XDG_RUNTIME_DIR=$work/xdg
mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"
export PULSE_SERVER=unix:$work/pulse.sock
pulseaudio --daemonize=no -n --exit-idle-time=-1 --use-pid-file=no --disallow-exit \
    --load="module-native-protocol-unix socket=$work/pulse.sock auth-anonymous=1" \
    --load="module-null-sink sink_name=mouth rate=48000" \
    --load="module-null-sink sink_name=ear rate=48000" \
    --load="module-null-sink sink_name=talker_out rate=48000" >"$work/pulse.log" 2>&1 &
pids+=($!)
for _ in $(seq 100); do pactl info >/dev/null 2>&1 && break; sleep 0.1; done
pactl info >/dev/null
port=$((20000 + RANDOM % 20000))
seconds=$((clicks + 30))
# The listener: plays into "ear"; its microphone (not sent: it only listens) is the talker's
# output's monitor, silent.
PULSE_SINK=ear PULSE_SOURCE=talker_out.monitor xvfb-run -a "$lipcall" --listen 127.0.0.1:$port \
    --no-demo --settings "$work/ear.json" --status "$work/ear.status" --quit-after $seconds ${EAR_ARGS:-} \
    >"$work/ear.log" 2>&1 &
pids+=($!)
sleep 3
# The talker: its microphone is the "mouth" sink's monitor.
if [ -n "${TALKER_FRAME_MS:-}" ]; then
    printf '{"frame_ms": %d}\n' "$TALKER_FRAME_MS" >"$work/talker.json"
fi
PULSE_SINK=talker_out PULSE_SOURCE=mouth.monitor xvfb-run -a "$lipcall" --call 127.0.0.1:$port \
    --no-demo --settings "$work/talker.json" --status "$work/talker.status" \
    --quit-after $seconds >"$work/talker.log" 2>&1 &
pids+=($!)
sleep 5
python3 "$here/mouth_to_ear.py" mouth ear "$clicks" "$work/ear.status" || {
    echo "--- listener log"; tail -5 "$work/ear.log"; echo "--- talker log"; tail -5 "$work/talker.log"
    cat "$work/ear.status" 2>/dev/null
    exit 1
}
